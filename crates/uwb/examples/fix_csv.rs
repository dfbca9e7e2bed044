//! Multilaterates a CSV stream of TDOA measurements with [`FixBuilder`].
//!
//! Input on stdin, one measurement a line, times non-decreasing:
//! `t_ns,anchor_a,anchor_b,diff_m,ax,ay,az,bx,by,bz` with
//! `diff_m = |p - b| - |p - a|` and the anchor positions in metres.
//! Output on stdout, one fix a line:
//! `t_ns,x,y,z,vx,vy,vz,vel_valid,gdop,n_meas,iterations`; the counters go
//! to stderr. Arguments: `3d` (default) or `2d HEIGHT_M`, then optionally
//! the epoch period in seconds (default 0.1).
//!
//! ```text
//! cargo run -p insuwb-uwb --release --example fix_csv -- 3d 0.1 < tdoa.csv > fixes.csv
//! ```

use std::io::{BufRead, Write};

use insuwb_msg::{Header, UwbFix, UwbTdoa};
use insuwb_uwb::fix::{FixBuilder, FixConfig, FixMode};

fn parse(line: &str) -> Option<UwbTdoa> {
    let f: Vec<&str> = line.trim().split(',').collect();
    let num = |i: usize| f.get(i).and_then(|s| s.trim().parse::<f64>().ok());
    let int = |i: usize| f.get(i).and_then(|s| s.trim().parse::<u64>().ok());
    Some(UwbTdoa {
        header: Header::new(0, int(0)?),
        anchor_a: u32::try_from(int(1)?).ok()?,
        anchor_b: u32::try_from(int(2)?).ok()?,
        diff_m: num(3)?,
        anchor_a_pos_m: [num(4)?, num(5)?, num(6)?],
        anchor_b_pos_m: [num(7)?, num(8)?, num(9)?],
    })
}

fn write_fix(out: &mut impl Write, f: &UwbFix) -> std::io::Result<()> {
    let valid = u8::from(f.header.flags & UwbFix::FLAG_VEL_VALID != 0);
    let [x, y, z] = f.pos_m;
    let [vx, vy, vz] = f.vel_mps;
    writeln!(
        out,
        "{},{x},{y},{z},{vx},{vy},{vz},{valid},{},{},{}",
        f.header.meas_time_ns, f.gdop, f.n_meas, f.iterations
    )
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut cfg = FixConfig {
        mode: FixMode::Mode3d,
        ..FixConfig::default()
    };
    let mut rest = args.iter();
    match rest.next().map(String::as_str) {
        None | Some("3d") => {}
        Some("2d") => {
            let height_m = rest.next().ok_or("2d needs a height")?.parse()?;
            cfg.mode = FixMode::Mode2d { height_m };
        }
        Some(other) => return Err(format!("unknown mode {other}").into()),
    }
    if let Some(p) = rest.next() {
        cfg.period_s = p.parse()?;
    }
    let mut builder = FixBuilder::new(cfg)?;
    let stdout = std::io::stdout();
    let mut out = std::io::BufWriter::new(stdout.lock());
    let mut unparsed = 0u64;
    for line in std::io::stdin().lock().lines() {
        let Some(m) = parse(&line?) else {
            unparsed += 1;
            continue;
        };
        // Dropped measurements are counted in the builder's stats.
        if let Ok(Some(f)) = builder.push(&m) {
            write_fix(&mut out, &f)?;
        }
    }
    if let Some(f) = builder.flush() {
        write_fix(&mut out, &f)?;
    }
    out.flush()?;
    eprintln!("unparsed lines: {unparsed}");
    eprintln!("{:#?}", builder.stats());
    Ok(())
}
