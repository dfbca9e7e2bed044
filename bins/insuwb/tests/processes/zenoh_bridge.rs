//! The Zenoh bridge against a subscriber nobody here wrote: a group with
//! the `zenoh` stage runs on the simulated demo scenario (10 Hz UWB fixes)
//! as robot `r1`, its bridge connecting to a Zenoh peer that a Python
//! script built on the PyPI `eclipse-zenoh` and `rosbags` packages
//! (`tests/zenoh/subscriber.py`, no insuwb code) runs, listening on a free
//! loopback port. The script decodes every pose (ROS 2 CDR of
//! `nav_msgs/msg/Odometry`) and health sample (JSON) it gets; they are
//! checked against the group's recording: every fused state of the
//! bridge's first run once, by stamp, position to 1e-6 m, attitude,
//! covariance, flags, at 10 +/- 1 Hz; one health entry per stage, about
//! once a second. The bridge is killed while the script listens, the
//! launcher restarts it like every stage, and the new bridge reconnects:
//! its poses (attachment `seq` from 0 again) reach the script too.
//!
//! The stamps are CLOCK_MONOTONIC (`stamp_clock = "monotonic"`), so a
//! pose's stamp is its fused state's measurement time to the nanosecond.
//! All traffic is on 127.0.0.1 and nothing is scouted. Where the Python
//! environment (`target/pyenv`, installed by `.ci/run`) is missing the test
//! says so and skips, unless `CI` is set: then it fails. Every wait is
//! bounded; the test starts processes, so it holds the one-at-a-time lock.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use crate::common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::{f, insuwb, one_at_a_time, skip_or_fail, wait_bounded, Group};
use insuwb_log::Record;
use insuwb_msg::FusedState;
use serde_json::Value;

const SIM: &str = "imu = \"sim\"\nuwb = \"sim\"\nscenario = \"nlos-long\"\nseed = 1";
/// Seconds the group runs.
const GROUP_S: f64 = 23.0;
/// Seconds the subscriber listens after its first pose.
const LISTEN_S: f64 = 13.0;
/// When the bridge gets SIGKILL, s after start: while the subscriber
/// listens.
const KILL_AT_S: f64 = 10.0;
/// Bound of every wait.
const BOUND: Duration = Duration::from_secs(120);
/// The robot id.
const ROBOT: &str = "r1";
/// The stages of the group, in start order.
const STAGES: [&str; 6] = ["imu", "uwb", "ins", "fusion", "zenoh", "logger"];

/// The Python of the virtual environment `.ci/run` makes (`INSUWB_PYENV`
/// or `<workspace>/target/pyenv`), when it has the subscriber's packages.
fn python() -> Option<PathBuf> {
    common::pyenv_python("zenoh, rosbags")
}

#[test]
fn poses_and_health_reach_a_python_zenoh_subscriber() {
    let _one = one_at_a_time();
    let Some(py) = python() else {
        skip_or_fail("no Python environment with eclipse-zenoh and rosbags (target/pyenv: run .ci/run, or python3 -m venv target/pyenv && target/pyenv/bin/pip install eclipse-zenoh==1.10.2 rosbags==0.11.9)");
        return;
    };
    let port = common::free_port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let g = Group::with_config(
        "zenoh",
        SIM,
        "filter = \"iakf\"\n",
        &format!(
            "[zenoh]\nrobot = \"{ROBOT}\"\nconnect = [\"{endpoint}\"]\nstamp_clock = \"monotonic\"\n"
        ),
    );
    // `stages` is a top-level key: before the first table.
    let path = g.dir.join("robot.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let stages: Vec<String> = STAGES.iter().map(|s| format!("\"{s}\"")).collect();
    std::fs::write(&path, format!("stages = [{}]\n{text}", stages.join(", "))).unwrap();
    // The subscriber first: its peer listens, the bridge connects to it.
    let out_json = g.dir.join("received.json");
    let mut sub = subscriber(&py, &endpoint, ROBOT, LISTEN_S, &out_json);
    let mut launcher = Command::new(insuwb())
        .arg("launch")
        .arg(&path)
        .args(["--duration", &GROUP_S.to_string(), "--json"])
        // While the subscriber listens: the launcher restarts the bridge
        // like any other stage, and the new one reconnects.
        .args(["--fault", &format!("zenoh@{KILL_AT_S}")])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    common::wait_for_lock(&g, &mut launcher, BOUND, "zenoh");
    // The bridge's CPU time while the subscriber listens (printed, for the
    // record: a figure of the machine, not a check).
    let t0 = Instant::now();
    let stage_pid = (0..100).find_map(|_| {
        let pid = common::child_processes(launcher.id())
            .into_iter()
            .find(|(_, comm)| comm == "insuwb-stage-ze")
            .map(|(pid, _)| pid);
        if pid.is_none() {
            std::thread::sleep(Duration::from_millis(50));
        }
        pid
    });
    let cpu0 = stage_pid.and_then(common::cpu_ticks);
    std::thread::sleep(Duration::from_secs_f64(KILL_AT_S * 0.5));
    if let (Some(a), Some(b)) = (cpu0, stage_pid.and_then(common::cpu_ticks)) {
        // USER_HZ is 100 on Linux.
        let share = (b - a) as f64 / 100.0 / t0.elapsed().as_secs_f64() * 100.0;
        eprintln!("zenoh bridge CPU: {share:.1} % of one core");
    }
    wait_bounded(&mut sub, "the Python subscriber", BOUND);
    let so = sub.wait_with_output().unwrap();
    let sub_err = String::from_utf8_lossy(&so.stderr);
    eprintln!("{}{sub_err}", String::from_utf8_lossy(&so.stdout));
    wait_bounded(&mut launcher, "insuwb launch", BOUND);
    let out = launcher.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "launch failed:\n{stderr}");
    assert!(!stderr.contains("panicked"), "a stage panicked:\n{stderr}");
    assert!(
        stderr.contains("zenoh: put"),
        "the bridge did not stop cleanly:\n{stderr}"
    );
    for l in stderr.lines().filter(|l| l.contains("zenoh")) {
        eprintln!("{l}");
    }
    assert!(
        so.status.success(),
        "the Python subscriber failed:\n{sub_err}\n{stderr}"
    );
    let report: Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("no JSON report ({e}):\n{stderr}"));
    common::assert_restarted_once(&report, &stderr, "zenoh", &g);
    let got: Value = serde_json::from_str(&std::fs::read_to_string(&out_json).unwrap()).unwrap();
    let fused: Vec<FusedState> = common::records(&g.log_dir())
        .into_iter()
        .filter_map(|r| match r {
            Record::Fused(s) => Some(s),
            _ => None,
        })
        .collect();
    check_poses(&got, &fused);
    check_health(&got);
}

/// `insuwb demo --zenoh ENDPOINT --robot d7`: the demo group's bridge
/// reaches the same subscriber as robot `d7`; a bad endpoint or robot id is
/// refused before anything starts.
#[test]
fn the_demo_publishes_as_its_robot_id_to_its_endpoint() {
    let _one = one_at_a_time();
    let out = common::run(&["demo", "--duration", "5", "--zenoh", "udp/127.0.0.1:7447"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--zenoh") && err.contains("udp/127.0.0.1:7447"),
        "{err}"
    );
    let out = common::run(&[
        "demo",
        "--duration",
        "5",
        "--zenoh",
        "tcp/127.0.0.1:7447",
        "--robot",
        "r/1",
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--robot") && err.contains("r/1"), "{err}");
    let Some(py) = python() else {
        skip_or_fail(
            "no Python environment with eclipse-zenoh and rosbags (target/pyenv: run .ci/run)",
        );
        return;
    };
    let endpoint = format!("tcp/127.0.0.1:{}", common::free_port());
    let dir = std::env::temp_dir().join(format!("insuwb-test-zenoh-demo-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out_json = dir.join("received.json");
    let mut sub = subscriber(&py, &endpoint, "d7", 2.0, &out_json);
    let mut demo = Command::new(insuwb())
        .args(["demo", "--duration", "8", "--json", "--zenoh", &endpoint])
        .args(["--robot", "d7"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_bounded(&mut sub, "the Python subscriber", BOUND);
    let so = sub.wait_with_output().unwrap();
    wait_bounded(&mut demo, "insuwb demo", BOUND);
    let out = demo.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "demo failed:\n{stderr}");
    assert!(
        stderr.contains(&format!(
            "Zenoh bridge as robot d7, connecting to {endpoint}"
        )),
        "{stderr}"
    );
    assert!(
        so.status.success(),
        "the Python subscriber failed:\n{}",
        String::from_utf8_lossy(&so.stderr)
    );
    let got: Value = serde_json::from_str(&std::fs::read_to_string(&out_json).unwrap()).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    let poses = got["poses"].as_array().unwrap();
    assert!(poses.len() >= 10, "{} poses", poses.len());
    assert!(poses.iter().all(|p| p["key"] == "insuwb/d7/pose"));
    let health = got["health"].as_array().unwrap();
    assert!(health.iter().all(|h| h["body"]["robot"] == "d7"));
    let report: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(f(&report, "restarts"), 0.0, "{report}");
}

/// The PyPI subscriber (`tests/zenoh/subscriber.py`): its peer listens on
/// `endpoint`, takes `robot`'s samples for `listen_s` after the first pose
/// (waiting up to 60 s for it) and writes them to `out` as JSON.
fn subscriber(py: &Path, endpoint: &str, robot: &str, listen_s: f64, out: &Path) -> Child {
    Command::new(py)
        .arg(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/zenoh/subscriber.py"))
        .args(["--listen", endpoint, "--robot", robot])
        .args(["--duration", &listen_s.to_string()])
        .args(["--first-timeout", "60", "--out"])
        .arg(out)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

fn nums(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap_or_else(|| panic!("not an array: {v}"))
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

fn close(a: &[f64], b: &[f64], tol: f64) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol)
}

/// insuwb's `[w, x, y, z]`, normalised, as `[x, y, z, w]`.
fn xyzw(q: &[f64; 4]) -> [f64; 4] {
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    [q[1] / n, q[2] / n, q[3] / n, q[0] / n]
}

fn u(v: &Value, key: &str) -> u64 {
    v[key]
        .as_u64()
        .unwrap_or_else(|| panic!("no integer '{key}' in {v}"))
}

/// The poses: the first bridge's every fused state once, exact, at 10 Hz;
/// the restarted bridge's after it, its `seq` from 0 again.
fn check_poses(got: &Value, fused: &[FusedState]) {
    assert_eq!(got["errors"], serde_json::json!([]), "decoding failed");
    assert!(!fused.is_empty(), "empty recording");
    // Two fused states of the recording can share a measurement time (a
    // fusion stage restarted under load publishes from its checkpoint
    // again); a pose must be one of them.
    let mut by_time: BTreeMap<u64, Vec<&FusedState>> = BTreeMap::new();
    for s in fused {
        by_time.entry(s.header.meas_time_ns).or_default().push(s);
    }
    let poses = got["poses"].as_array().unwrap();
    // The bridges' runs: a new run starts where `seq` does not follow on.
    let mut runs: Vec<Vec<&Value>> = Vec::new();
    for p in poses {
        let seq = u(&p["attachment"], "seq");
        match runs.last_mut() {
            Some(r) if u(&r[r.len() - 1]["attachment"], "seq") < seq => r.push(p),
            _ => runs.push(vec![p]),
        }
    }
    eprintln!(
        "poses: {} in {} run(s) of {:?}",
        poses.len(),
        runs.len(),
        runs.iter().map(Vec::len).collect::<Vec<_>>()
    );
    assert!(runs.len() >= 2, "no pose from the restarted bridge");
    for p in poses {
        assert_eq!(p["key"], format!("insuwb/{ROBOT}/pose"));
        assert_eq!(p["encoding"], "application/cdr;nav_msgs/msg/Odometry");
        assert_eq!(p["attachment"]["v"], 1);
        assert_eq!(p["frame_id"], "map");
        assert_eq!(p["child_frame_id"], "base_link");
        let t = u(p, "stamp_ns");
        let same_time = by_time
            .get(&t)
            .unwrap_or_else(|| panic!("no fused state at {t} ns"));
        let pos = nums(&p["position"]);
        let s = same_time
            .iter()
            .find(|s| close(&pos, &s.pos_m, 1e-6))
            .unwrap_or_else(|| {
                let at: Vec<_> = same_time.iter().map(|s| s.pos_m).collect();
                panic!("{pos:?} is none of the fused states at {t} ns: {at:?}")
            });
        assert!(close(&nums(&p["orientation"]), &xyzw(&s.quat), 1e-9));
        let var = [s.cov[0][0], s.cov[1][1], s.cov[2][2]];
        assert!(close(&nums(&p["pos_var"]), &var, 1e-12));
        assert_eq!(
            u(&p["attachment"], "flags"),
            u64::from(s.header.flags),
            "flags at {t} ns"
        );
    }
    // The first run: every fused state of its span once, in order, 10 Hz.
    let first = &runs[0];
    let stamps: Vec<u64> = first.iter().map(|p| u(p, "stamp_ns")).collect();
    assert!(
        stamps.windows(2).all(|w| w[0] < w[1]),
        "poses repeated or out of order"
    );
    let (a, b) = (stamps[0], stamps[stamps.len() - 1]);
    let span = by_time.range(a..=b).count();
    assert!(stamps.len() >= 50, "{} poses before the kill", stamps.len());
    assert_eq!(stamps.len(), span, "poses lost or added");
    let rate = (stamps.len() - 1) as f64 / ((b - a) as f64 * 1e-9);
    let rx: Vec<f64> = first.iter().map(|p| f(p, "rx_s")).collect();
    let rx_rate = (rx.len() - 1) as f64 / (rx[rx.len() - 1] - rx[0]);
    eprintln!(
        "first bridge: {} poses, {rate:.3} Hz by stamp, {rx_rate:.3} Hz as received",
        stamps.len()
    );
    assert!((9.0..=11.0).contains(&rate), "pose rate {rate} Hz");
    assert!(
        (9.0..=11.0).contains(&rx_rate),
        "pose receive rate {rx_rate} Hz"
    );
    // Each bridge counts from 0; its first puts can leave before its
    // session has reached the subscriber (Zenoh's peer connection, a few
    // tens of ms), so each run is seen from one of its first poses.
    for (k, run) in runs.iter().enumerate().take(2) {
        let seq = u(&run[0]["attachment"], "seq");
        assert!(seq <= 5, "run {k} is seen from seq {seq}");
    }
}

/// The health: one entry per stage, about once a second, the bridge's own
/// restart counted once the new bridge reports.
fn check_health(got: &Value) {
    let health = got["health"].as_array().unwrap();
    assert!(
        health.len() as f64 >= LISTEN_S - 4.0,
        "{} health samples in {LISTEN_S} s",
        health.len()
    );
    let mut restarted = false;
    for h in health {
        assert_eq!(h["key"], format!("insuwb/{ROBOT}/health"));
        assert_eq!(h["encoding"], "application/json;insuwb/health");
        assert_eq!(h["attachment"]["v"], 1);
        let body = &h["body"];
        assert_eq!(body["version"], 1);
        assert_eq!(body["robot"], ROBOT);
        let st = body["stages"].as_array().unwrap();
        let names: Vec<&str> = st.iter().map(|s| s["stage"].as_str().unwrap()).collect();
        assert_eq!(names, STAGES);
        for s in st {
            let state = s["state"].as_str().unwrap();
            assert!(
                ["ok", "degraded", "disconnected", "stopping", "down"].contains(&state),
                "{s}"
            );
        }
        let z = &st[4];
        if z["state"] == "ok" && u(z, "restarts") == 1 {
            restarted = true;
        }
    }
    // A report of the first bridge after the group is up: every stage up.
    let up = health
        .iter()
        .find(|h| {
            h["body"]["stages"]
                .as_array()
                .unwrap()
                .iter()
                .all(|s| s["pid"].as_u64().unwrap_or(0) > 0 && s["state"] != "down")
        })
        .unwrap_or_else(|| panic!("no health sample with every stage up: {health:?}"));
    let fusion = &up["body"]["stages"][3];
    assert!(fusion["published_rate_hz"].is_number(), "{fusion}");
    assert!(
        restarted,
        "no health sample of the restarted bridge counting its restart"
    );
}
