//! `insuwb-runtime-probe`: a second process for the runtime's cross-process
//! tests (not a product binary).
//!
//! Usage: `insuwb-runtime-probe MODE key=value...`, common keys `prefix=`,
//! `root=`, `name=` (stage name), `gen=` (generation; else `INSUWB_GENERATION`),
//! `busy=1` (busy-poll). Modes, all on topic `imu` (ImuSample):
//! - `pub count=N [gap_at=K gap=G] [period_us=P] [wait_subs=1] [linger=1]`:
//!   publishes N samples (skipping G sequence numbers before sample K),
//!   prints `done N`, then with `linger=1` keeps connecting late subscribers
//!   (history) until stdin closes.
//! - `sub expect=N [timeout_ms=T]`: prints `ready`, receives N samples through
//!   the wait loop and prints `stats received=.. gaps=.. restarts=..
//!   p50_ns=.. p99_ns=.. max_ns=..` (one-way latency `receive - pub_time_ns`).
//! - `wait`: holds a subscriber, a publisher and a 10 Hz tick, prints `ready`
//!   and waits until SIGINT/SIGTERM, then prints `shutdown` and exits 0.

use std::collections::HashMap;
use std::io::{BufRead, Write};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use insuwb_msg::{topics, Header, ImuSample};
use insuwb_runtime::{monotonic_ns, RuntimeConfig, Stage, Wake};

type Res<T> = Result<T, Box<dyn std::error::Error>>;

fn say(line: &str) {
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "{line}");
    let _ = out.flush();
}

fn num(args: &HashMap<String, String>, key: &str, default: u64) -> Res<u64> {
    match args.get(key) {
        Some(v) => Ok(v.parse::<u64>().map_err(|e| format!("{key}={v}: {e}"))?),
        None => Ok(default),
    }
}

fn run() -> Res<()> {
    let mut argv = std::env::args().skip(1);
    let mode = argv.next().ok_or("missing MODE")?;
    let args: HashMap<String, String> = argv
        .filter_map(|a| a.split_once('=').map(|(k, v)| (k.to_owned(), v.to_owned())))
        .collect();
    let cfg = RuntimeConfig {
        prefix: args.get("prefix").cloned().ok_or("missing prefix=")?,
        root_path: args.get("root").map(PathBuf::from),
        stage_name: args.get("name").cloned().unwrap_or_else(|| "probe".into()),
        generation: match args.get("gen") {
            Some(g) => Some(g.parse::<u32>()?),
            None => None,
        },
        busy_poll: num(&args, "busy", 0)? == 1,
        ..Default::default()
    };
    let stage = Stage::new(cfg)?;
    match mode.as_str() {
        "pub" => {
            let mut p = stage.publisher::<ImuSample>(topics::IMU)?;
            if num(&args, "wait_subs", 0)? == 1 {
                let mut tries = 0;
                while p.subscriber_count() == 0 && tries < 10_000 {
                    stage.sleep(Duration::from_millis(1))?;
                    tries += 1;
                }
            }
            let count = num(&args, "count", 10)?;
            let gap_at = num(&args, "gap_at", u64::MAX)?;
            let gap = num(&args, "gap", 0)?;
            let period = Duration::from_micros(num(&args, "period_us", 0)?);
            for i in 0..count {
                if i == gap_at {
                    p.skip_seq(gap);
                }
                let s = ImuSample {
                    header: Header::new(0, monotonic_ns()),
                    accel_mps2: [0.0, 0.0, 9.81],
                    gyro_rps: [i as f64, 0.0, 0.0],
                };
                p.publish(s)?;
                if !period.is_zero() {
                    stage.sleep(period)?;
                }
            }
            say(&format!("done {}", p.published()));
            if num(&args, "linger", 0)? == 1 {
                // Keep delivering history to late subscribers until stdin closes.
                let closed = Arc::new(AtomicBool::new(false));
                let flag = Arc::clone(&closed);
                std::thread::spawn(move || {
                    let mut line = String::new();
                    while matches!(std::io::stdin().lock().read_line(&mut line), Ok(n) if n > 0) {
                        line.clear();
                    }
                    flag.store(true, Ordering::Relaxed);
                });
                while !closed.load(Ordering::Relaxed) {
                    p.update_connections()?;
                    stage.sleep(Duration::from_millis(2))?;
                }
            }
        }
        "sub" => {
            let s = stage.subscriber::<ImuSample>(topics::IMU)?;
            let waiter = stage.waiter()?;
            let att = waiter.attach(&s)?;
            let expect = num(&args, "expect", 10)? as usize;
            let timeout = Duration::from_millis(num(&args, "timeout_ms", 20_000)?);
            let mut lat = Vec::with_capacity(expect);
            say("ready");
            while lat.len() < expect {
                match waiter.wait_timeout(timeout)? {
                    Wake::Shutdown => break,
                    Wake::Timeout => return Err("sub: timeout".into()),
                    Wake::Fired(f) => {
                        if f.contains(&att) {
                            while let Some(x) = s.receive()? {
                                let now = monotonic_ns();
                                lat.push(now.saturating_sub(x.header.pub_time_ns));
                            }
                        }
                    }
                }
            }
            lat.sort_unstable();
            let pick = |q: f64| -> u64 {
                let i = ((lat.len() as f64 - 1.0) * q).round() as usize;
                lat.get(i).copied().unwrap_or(0)
            };
            let st = s.stats();
            say(&format!(
                "stats received={} gaps={} restarts={} p50_ns={} p99_ns={} max_ns={}",
                st.received,
                st.seq_gaps,
                st.restarts,
                pick(0.5),
                pick(0.99),
                lat.last().copied().unwrap_or(0)
            ));
        }
        "wait" => {
            let s = stage.subscriber::<ImuSample>(topics::IMU)?;
            let _p = stage.publisher::<ImuSample>(topics::IMU)?;
            let waiter = stage.waiter()?;
            let _a = waiter.attach(&s)?;
            let _t = waiter.attach_interval(Duration::from_millis(100))?;
            say("ready");
            loop {
                if let Wake::Shutdown = waiter.wait()? {
                    break;
                }
            }
            say("shutdown");
        }
        other => return Err(format!("unknown mode {other:?}").into()),
    }
    Ok(())
}

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            if e.downcast_ref::<insuwb_runtime::Shutdown>().is_some() {
                say("shutdown");
                return ExitCode::SUCCESS;
            }
            eprintln!("probe: {e}");
            ExitCode::FAILURE
        }
    }
}
