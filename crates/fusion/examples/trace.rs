//! Prints one CSV row per fused state of one filter on one UTIL flight, with
//! the interpolated ground truth, for looking at a run over time:
//! `cargo run --release -p insuwb-fusion --example trace -- LOG ANCHORS CONFIG.toml [FILTER]`.
//! `FILTER` `ins` prints the INS alone (every tenth state). The columns
//! `tilt_e, tilt_n` are the east and north components of the body z axis
//! (the thrust's direction; times g, the horizontal acceleration a
//! multirotor's model predicts from its attitude), `truth_tilt_*` the
//! motion capture's; `python3 tools/trace_attitude.py` reads them.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::Path;

use insuwb_data::segment::interpolate_truth;
use insuwb_data::util::{load_util_flight, ImportOptions};
use insuwb_fusion::config::FusionConfig;
use insuwb_fusion::runner;
use insuwb_msg::FilterKind;

#[derive(Debug, serde::Deserialize)]
struct Preset {
    #[serde(default)]
    fusion: FusionConfig,
    #[serde(default)]
    import: ImportOptions,
    #[serde(default)]
    #[allow(dead_code)]
    eval: Option<toml::Value>,
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let preset: Preset = toml::from_str(&std::fs::read_to_string(&a[3]).unwrap()).unwrap();
    let flight = load_util_flight(
        Path::new(&a[1]),
        Path::new(&a[2]),
        &insuwb_data::cflog::ParseOptions::default(),
        &preset.import,
    )
    .unwrap();
    let name = a.get(4).map_or("iakf_tdoa", String::as_str);
    if name == "ins" {
        let nav = runner::run_ins_only(&flight.imu, &preset.fusion).unwrap();
        println!("t,x,y,z,vx,vy,vz,tx,ty,tz,tilt_e,tilt_n,truth_tilt_e,truth_tilt_n");
        for n in nav.iter().step_by(10) {
            let Some(g) = interpolate_truth(&flight.truth, n.header.meas_time_ns) else {
                continue;
            };
            let ([te, tn], [ge, gn]) = (thrust_axis(n.quat), thrust_axis(g.quat));
            println!(
                "{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.5},{:.5},{:.5},{:.5}",
                n.header.meas_time_ns as f64 * 1e-9,
                n.pos_m[0], n.pos_m[1], n.pos_m[2], n.vel_mps[0], n.vel_mps[1], n.vel_mps[2],
                g.pos_m[0], g.pos_m[1], g.pos_m[2], te, tn, ge, gn
            );
        }
        return;
    }
    let kind: FilterKind = name.parse().unwrap();
    let out = runner::run(&flight.imu, &flight.tdoa, &preset.fusion, kind).unwrap();
    println!("t,x,y,z,vx,vy,vz,tx,ty,tz,sx,sy,svx,svy,yaw,flags,nees,tyaw,fading,tilt_e,tilt_n,truth_tilt_e,truth_tilt_n");
    let mut di = 0usize;
    for f in &out.fused {
        let t = f.header.meas_time_ns;
        while di + 1 < out.diag.len() && out.diag[di + 1].header.meas_time_ns <= t {
            di += 1;
        }
        let fading = out.diag.get(di).map_or(1.0, |d| d.fading);
        let Some(g) = interpolate_truth(&flight.truth, t) else {
            continue;
        };
        let ([te, tn], [ge, gn]) = (thrust_axis(f.quat), thrust_axis(g.quat));
        let c = f.cov;
        let e = [f.pos_m[0] - g.pos_m[0], f.pos_m[1] - g.pos_m[1]];
        let nees = e[0] * e[0] / c[0][0] + e[1] * e[1] / c[1][1];
        let q = g.quat;
        let tyaw =
            (2.0 * (q[0] * q[3] + q[1] * q[2])).atan2(1.0 - 2.0 * (q[2] * q[2] + q[3] * q[3]));
        println!(
            "{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{},{:.2},{:.4},{:.3},{:.5},{:.5},{:.5},{:.5}",
            t as f64 * 1e-9,
            f.pos_m[0], f.pos_m[1], f.pos_m[2], f.vel_mps[0], f.vel_mps[1], f.vel_mps[2],
            g.pos_m[0], g.pos_m[1], g.pos_m[2],
            c[0][0].sqrt(), c[1][1].sqrt(), c[3][3].sqrt(), c[4][4].sqrt(), f.yaw_rad, f.header.flags, nees, tyaw, fading, te, tn, ge, gn
        );
    }
    eprintln!("{:?}\n{:?}", out.fusion, out.ins);
}

/// East and north components of the body z axis of attitude `q` (`[w, x, y, z]`).
fn thrust_axis(q: [f64; 4]) -> [f64; 2] {
    [
        2.0 * (q[1] * q[3] + q[0] * q[2]),
        2.0 * (q[2] * q[3] - q[0] * q[1]),
    ]
}
