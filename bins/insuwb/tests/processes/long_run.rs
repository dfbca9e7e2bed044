//! A long run at speed `max`: the launcher's and every stage's resident
//! memory stays flat (nothing is kept per sample for the whole run).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use crate::common;

use std::collections::BTreeMap;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{insuwb, one_at_a_time, Group};

/// Anonymous resident memory (heap, stacks; not the shared memory mapped
/// from /dev/shm) of a process, KiB.
fn rss_anon_kib(pid: u32) -> Option<u64> {
    let s = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    s.lines()
        .find_map(|l| l.strip_prefix("RssAnon:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
}

/// The launcher and its stage processes (its children), by role name.
fn group_processes(launcher: u32) -> BTreeMap<String, u32> {
    let mut out: BTreeMap<String, u32> = common::child_processes(launcher)
        .into_iter()
        .map(|(pid, comm)| {
            let name = insuwb_msg::StageRole::from_process_name(&comm)
                .map_or(comm, |r| r.name().to_owned());
            (name, pid)
        })
        .collect();
    out.insert("launcher".to_owned(), launcher);
    out
}

fn sample(launcher: u32) -> BTreeMap<String, u64> {
    group_processes(launcher)
        .into_iter()
        .filter_map(|(name, pid)| rss_anon_kib(pid).map(|kib| (name, kib)))
        .collect()
}

#[test]
fn resident_memory_stays_flat_over_a_long_run_at_full_speed() {
    let _lock = one_at_a_time();
    // The demo scenario stretched to an hour of robot time (its loops and
    // random NLOS go on), played as fast as the group can take it.
    let scenario = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../config/scenarios/nlos-long.toml"),
    )
    .unwrap()
    .replacen("duration_s = 60.0", "duration_s = 3600.0", 1);
    let g = Group::with_config(
        "longrun",
        "imu = \"sim\"\nuwb = \"sim\"\nscenario = \"SCENARIO\"\nseed = 1\nspeed = \"max\"",
        "filter = \"iakf\"\n",
        "",
    );
    let scenario_path = g.dir.join("long.toml");
    std::fs::write(&scenario_path, scenario).unwrap();
    let cfg = g.dir.join("robot.toml");
    let text = std::fs::read_to_string(&cfg)
        .unwrap()
        .replace("SCENARIO", &scenario_path.display().to_string());
    std::fs::write(&cfg, text).unwrap();

    let run_s = 22.0;
    let mut child = Command::new(insuwb())
        .arg("launch")
        .arg(&cfg)
        .args(["--duration", &run_s.to_string(), "--json"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let pid = child.id();
    let t0 = Instant::now();
    // Start: once the group has run a while (buffers, shared memory and the
    // simulated scenario are allocated at start-up); end: shortly before it
    // stops.
    let mut start = BTreeMap::new();
    let mut end = BTreeMap::new();
    while t0.elapsed() < Duration::from_secs_f64(run_s - 4.0) {
        std::thread::sleep(Duration::from_millis(500));
        if child.try_wait().unwrap().is_some() {
            break;
        }
        let s = sample(pid);
        if start.is_empty() && t0.elapsed() >= Duration::from_secs(8) {
            start = s;
        } else if !start.is_empty() {
            end = s;
        }
    }
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "launch failed");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let states = v["rmse_states"].as_f64().unwrap_or(0.0);
    eprintln!(
        "long run {run_s} s at speed max: {states} valid fused states compared with ground truth; RssAnon KiB at 8 s -> end: {}",
        start
            .iter()
            .map(|(n, a)| format!("{n} {a} -> {}", end.get(n).map_or("gone".into(), |b| b.to_string())))
            .collect::<Vec<_>>()
            .join(", ")
    );
    assert_eq!(v["restarts"].as_f64(), Some(0.0), "{v}");
    // The run covers several times its wall time of robot time (real time
    // would give 10 states a second).
    assert!(
        states > 30.0 * run_s,
        "{states} states in {run_s} s at speed max: {v}"
    );
    for name in ["launcher", "imu", "uwb", "ins", "fusion", "logger"] {
        let (Some(a), Some(b)) = (start.get(name), end.get(name)) else {
            panic!("{name}: no memory figures (start {start:?}, end {end:?})");
        };
        // Flat: allocator noise is a few hundred KiB; a vector kept per
        // sample grows by megabytes over this run.
        assert!(
            *b <= a + 2048 + a / 10,
            "{name}: anonymous resident memory grew from {a} KiB to {b} KiB"
        );
    }
}
