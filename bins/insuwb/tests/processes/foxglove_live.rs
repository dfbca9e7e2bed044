//! The Foxglove live view against a client nobody here wrote: a group with
//! the `foxglove` stage runs on the simulated demo scenario (10 Hz UWB
//! fixes) with its WebSocket server on a free loopback port, and a Python
//! client built on the PyPI `websockets` and `foxglove-schemas-protobuf`
//! packages from the Foxglove WebSocket protocol's specification
//! (`tests/foxglove/client.py`, subprotocol `foxglove.sdk.v1`) subscribes
//! to every advertised channel and decodes what comes. Its messages are
//! checked against the group's recording: every valid fused state once,
//! by timestamp, position to 1e-6 m, at 10 +/- 1 Hz; the transform and
//! the path; the UWB fixes; the filter diagnostics; the anchors of the
//! scenario; one health entry per stage. After the client's window the
//! stage is killed, and the launcher restarts it like every stage.
//!
//! The stamps are CLOCK_MONOTONIC (`stamp_clock = "monotonic"`), so a
//! message's timestamp is its sample's measurement time to the
//! nanosecond. Where the Python environment (`target/pyenv`, installed by
//! `.ci/run`) is missing the test says so and skips, unless `CI` is set:
//! then it fails. Every wait is bounded; the test starts processes, so it
//! holds the one-at-a-time lock.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use crate::common;

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{f, insuwb, one_at_a_time, run_bounded, skip_or_fail, wait_bounded, Group};
use insuwb_log::Record;
use insuwb_msg::{FilterDiag, FusedState, UwbFix};
use serde_json::Value;

const SIM: &str = "imu = \"sim\"\nuwb = \"sim\"\nscenario = \"nlos-long\"\nseed = 1";
/// Seconds the group runs and the client listens after its first pose.
const GROUP_S: f64 = 22.0;
const LISTEN_S: f64 = 8.0;
/// When the stage gets SIGKILL, s after start.
const KILL_AT_S: f64 = 17.0;
/// Bound of every wait.
const BOUND: Duration = Duration::from_secs(90);
/// The stages of the group, in start order.
const STAGES: [&str; 6] = ["imu", "uwb", "ins", "fusion", "foxglove", "logger"];
/// The channels the view advertises for a source with ground truth.
const TOPICS: [&str; 10] = [
    "/insuwb/pose",
    "/insuwb/tf",
    "/insuwb/path",
    "/insuwb/uwb_fix",
    "/insuwb/anchors",
    "/insuwb/robot",
    "/insuwb/diag",
    "/insuwb/health",
    "/insuwb/truth",
    "/insuwb/error",
];

/// The Python of the virtual environment `.ci/run` makes (`INSUWB_PYENV`
/// or `<workspace>/target/pyenv`), when it has the client's packages.
fn python() -> Option<PathBuf> {
    common::pyenv_python("websockets, foxglove_schemas_protobuf, google.protobuf")
}

#[test]
fn foxglove_channels_reach_a_websocket_client() {
    let _one = one_at_a_time();
    let Some(py) = python() else {
        skip_or_fail("no Python environment with websockets and foxglove-schemas-protobuf (target/pyenv: run .ci/run, or python3 -m venv target/pyenv && target/pyenv/bin/pip install websockets==17.4 foxglove-schemas-protobuf==0.4.0 protobuf==7.36.2)");
        return;
    };
    let port = common::free_port();
    let g = Group::with_config(
        "foxglove",
        SIM,
        "filter = \"iakf\"\n",
        &format!("[foxglove]\nbind = \"127.0.0.1:{port}\"\nstamp_clock = \"monotonic\"\n"),
    );
    // `stages` is a top-level key: before the first table.
    let path = g.dir.join("robot.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let stages: Vec<String> = STAGES.iter().map(|s| format!("\"{s}\"")).collect();
    std::fs::write(&path, format!("stages = [{}]\n{text}", stages.join(", "))).unwrap();
    let mut launcher = Command::new(insuwb())
        .arg("launch")
        .arg(&path)
        .args(["--duration", &GROUP_S.to_string(), "--json"])
        // After the client's window: the launcher restarts the stage like
        // any other, and it heartbeats again before the end.
        .args(["--fault", &format!("foxglove@{KILL_AT_S}")])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    common::wait_for_lock(&g, &mut launcher, BOUND, "foxglove");
    let out_json = g.dir.join("received.json");
    let mut client = Command::new(&py);
    client
        .arg(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/foxglove/client.py"))
        .args(["--url", &format!("ws://127.0.0.1:{port}")])
        .args(["--duration", &LISTEN_S.to_string()])
        .args(["--connect-timeout", "30", "--first-timeout", "30"])
        .arg("--out")
        .arg(&out_json);
    for t in TOPICS {
        client.args(["--expect", t]);
    }
    // The stage's CPU time over the client's window (printed, for the
    // record: a figure of the machine, not a check).
    let stage_pid = common::child_processes(launcher.id())
        .into_iter()
        .find(|(_, comm)| comm == "insuwb-stage-fo")
        .map(|(pid, _)| pid);
    let cpu0 = stage_pid.and_then(common::cpu_ticks);
    let t0 = Instant::now();
    let cl = run_bounded(&mut client, BOUND);
    if let (Some(a), Some(b)) = (cpu0, stage_pid.and_then(common::cpu_ticks)) {
        // USER_HZ is 100 on Linux.
        let share = (b - a) as f64 / 100.0 / t0.elapsed().as_secs_f64() * 100.0;
        eprintln!("foxglove stage CPU while the client listened: {share:.1} % of one core");
    }
    let cl_err = String::from_utf8_lossy(&cl.stderr);
    eprintln!("{}{cl_err}", String::from_utf8_lossy(&cl.stdout));
    wait_bounded(&mut launcher, "insuwb launch", BOUND);
    let out = launcher.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "launch failed:\n{stderr}");
    assert!(!stderr.contains("panicked"), "a stage panicked:\n{stderr}");
    assert!(
        stderr.contains("foxglove: logged"),
        "the live view did not stop cleanly:\n{stderr}"
    );
    for l in stderr.lines().filter(|l| l.contains("foxglove")) {
        eprintln!("{l}");
    }
    assert!(
        cl.status.success(),
        "the WebSocket client failed:\n{cl_err}\n{stderr}"
    );
    let report: Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("no JSON report ({e}):\n{stderr}"));
    common::assert_restarted_once(&report, &stderr, "foxglove", &g);
    let got: Value = serde_json::from_str(&std::fs::read_to_string(&out_json).unwrap()).unwrap();
    check(&got, &Recording::read(&g), &g.name);
}

/// What the group recorded.
struct Recording {
    /// Valid fused states.
    fused: Vec<FusedState>,
    fixes: Vec<UwbFix>,
    diags: Vec<FilterDiag>,
}

impl Recording {
    fn read(g: &Group) -> Self {
        let mut r = Self {
            fused: Vec::new(),
            fixes: Vec::new(),
            diags: Vec::new(),
        };
        for rec in common::records(&g.log_dir()) {
            match rec {
                Record::Fused(s) if s.header.flags & FusedState::FLAG_VALID != 0 => r.fused.push(s),
                Record::Fix(s) => r.fixes.push(s),
                Record::Diag(d) => r.diags.push(d),
                _ => {}
            }
        }
        r
    }
}

fn nums(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap_or_else(|| panic!("not an array: {v}"))
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

fn stamp(v: &Value) -> u64 {
    v["stamp_ns"].as_u64().unwrap()
}

fn close(a: &[f64], b: &[f64], tol: f64) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol)
}

/// insuwb's `[w, x, y, z]`, normalised, as `[x, y, z, w]`.
fn xyzw(q: &[f64; 4]) -> [f64; 4] {
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    [q[1] / n, q[2] / n, q[3] / n, q[0] / n]
}

fn messages<'a>(got: &'a Value, topic: &str) -> &'a Vec<Value> {
    got["messages"][topic]
        .as_array()
        .unwrap_or_else(|| panic!("no messages on {topic}"))
}

fn check(got: &Value, rec: &Recording, group: &str) {
    assert!(!rec.fused.is_empty(), "empty recording");
    assert!(
        got["server_info"]["name"]
            .as_str()
            .is_some_and(|n| n.contains(group)),
        "server name: {}",
        got["server_info"]
    );
    for t in TOPICS {
        let c = &got["channels"][t];
        assert!(f(c, "span_s") >= 1.0, "{t}: {c}");
    }
    // --- the fused pose: every valid state of its span, once, exact ---
    let by_time: BTreeMap<u64, &FusedState> = rec
        .fused
        .iter()
        .map(|s| (s.header.meas_time_ns, s))
        .collect();
    let poses = messages(got, "/insuwb/pose");
    assert!(poses.len() >= 50, "{} poses", poses.len());
    for p in poses {
        assert_eq!(p["frame_id"], "map");
        let s = by_time
            .get(&stamp(p))
            .unwrap_or_else(|| panic!("no valid fused state at {} ns", stamp(p)));
        let pos = nums(&p["position"]);
        assert!(close(&pos, &s.pos_m, 1e-6), "{pos:?} vs {:?}", s.pos_m);
        let q = nums(&p["orientation"]);
        assert!(close(&q, &xyzw(&s.quat), 1e-9), "{q:?} vs {:?}", s.quat);
    }
    let stamps: Vec<u64> = poses.iter().map(stamp).collect();
    assert!(
        stamps.windows(2).all(|w| w[0] < w[1]),
        "poses repeated or out of order"
    );
    let (first, last) = (stamps[0], stamps[stamps.len() - 1]);
    let span = by_time.range(first..=last).count();
    let rate = (stamps.len() - 1) as f64 / ((last - first) as f64 * 1e-9);
    let c = &got["channels"]["/insuwb/pose"];
    let rx_rate = (f(c, "count") - 1.0) / f(c, "span_s");
    eprintln!(
        "pose: {} messages over {:.3} s: {rate:.3} Hz by timestamp, {rx_rate:.3} Hz as received ({span} valid fused states recorded in that span)",
        stamps.len(),
        (last - first) as f64 * 1e-9
    );
    assert!((9.0..=11.0).contains(&rate), "pose rate {rate} Hz");
    assert!(
        (9.0..=11.0).contains(&rx_rate),
        "pose receive rate {rx_rate} Hz"
    );
    assert_eq!(stamps.len(), span, "poses lost or added");
    // --- the transform map -> base_link: the same poses ---
    let tf = messages(got, "/insuwb/tf");
    // One per pose (the window's ends may cut one pair).
    assert!(
        tf.len().abs_diff(poses.len()) <= 2,
        "{} transforms for {} poses",
        tf.len(),
        poses.len()
    );
    for t in tf {
        assert_eq!(
            (t["parent"].as_str(), t["child"].as_str()),
            (Some("map"), Some("base_link"))
        );
        let s = by_time[&stamp(t)];
        assert!(close(&nums(&t["translation"]), &s.pos_m, 1e-6));
    }
    // --- the path: the last fused positions, oldest first, up to 300 ---
    let paths = messages(got, "/insuwb/path");
    let lastp = &paths[paths.len() - 1];
    let pts: Vec<Vec<f64>> = lastp["positions"]
        .as_array()
        .unwrap()
        .iter()
        .map(nums)
        .collect();
    assert!(
        !pts.is_empty() && pts.len() <= 300,
        "{} path poses",
        pts.len()
    );
    let upto: Vec<&&FusedState> = by_time.range(..=stamp(lastp)).map(|(_, s)| s).collect();
    let want = &upto[upto.len().saturating_sub(pts.len())..];
    assert_eq!(want.len(), pts.len(), "a path longer than the recording");
    for (p, s) in pts.iter().zip(want) {
        assert!(close(p, &s.pos_m, 1e-6), "path {p:?} vs {:?}", s.pos_m);
    }
    // --- the UWB fixes, by epoch ---
    let fixes: BTreeMap<u64, &UwbFix> = rec
        .fixes
        .iter()
        .map(|s| (s.header.meas_time_ns, s))
        .collect();
    let fx = messages(got, "/insuwb/uwb_fix");
    assert!(fx.len() >= 50, "{} fixes", fx.len());
    for m in fx {
        let s = fixes
            .get(&stamp(m))
            .unwrap_or_else(|| panic!("no UWB fix at {} ns", stamp(m)));
        assert!(close(&nums(&m["position"]), &s.pos_m, 1e-6));
    }
    // --- the filter diagnostics: fading and outlier weights, by time ---
    let diags: BTreeMap<u64, &FilterDiag> = rec
        .diags
        .iter()
        .map(|d| (d.header.meas_time_ns, d))
        .collect();
    let dg = messages(got, "/insuwb/diag");
    assert!(dg.len() >= 50, "{} diagnostics", dg.len());
    for m in dg {
        let t = m["timestamp"]["sec"].as_u64().unwrap() * 1_000_000_000
            + m["timestamp"]["nsec"].as_u64().unwrap();
        let d = diags
            .get(&t)
            .unwrap_or_else(|| panic!("no filter diagnostics at {t} ns"));
        let n = d.dim as usize;
        assert_eq!(m["filter"], "iakf");
        // Equal up to the last bit JSON parsing may change.
        assert!((f(m, "fading") - d.fading).abs() <= 1e-12 * d.fading.abs().max(1.0));
        assert!(close(&nums(&m["outlier_weight"]), &d.lambda[..n], 1e-12));
        assert!(close(&nums(&m["innovation"]), &d.innovation[..n], 1e-12));
    }
    // --- the anchors: one entity per configured anchor ---
    let scenario = insuwb_fusion::scenario::ScenarioFile::load("nlos-long").unwrap();
    let anchors = &scenario.sim.uwb.anchors;
    assert!(!anchors.is_empty());
    let scenes = messages(got, "/insuwb/anchors");
    let ents = scenes[scenes.len() - 1]["entities"].as_array().unwrap();
    let ids: Vec<&str> = ents.iter().map(|e| e["id"].as_str().unwrap()).collect();
    let mut want_ids: Vec<String> = anchors.iter().map(|a| format!("anchor/{}", a.id)).collect();
    want_ids.sort_by_key(|s| s[7..].parse::<u32>().unwrap());
    assert_eq!(ids, want_ids);
    for a in anchors {
        let e = ents
            .iter()
            .find(|e| e["id"] == format!("anchor/{}", a.id))
            .unwrap();
        assert_eq!(e["frame_id"], "map");
        assert!(close(&nums(&e["spheres"][0]), &a.pos_m, 1e-9));
    }
    let robot = messages(got, "/insuwb/robot");
    assert_eq!(robot[0]["entities"][0]["frame_id"], "base_link");
    // --- ground truth and the position error against it ---
    assert!(!messages(got, "/insuwb/truth").is_empty());
    let errs = messages(got, "/insuwb/error");
    let worst = errs
        .iter()
        .map(|e| f(e, "horizontal_m"))
        .fold(0.0, f64::max);
    eprintln!(
        "error: {} messages, worst horizontal {worst:.3} m",
        errs.len()
    );
    assert!(
        errs.len() >= 50 && worst < 5.0,
        "{} errors, worst {worst} m",
        errs.len()
    );
    // --- health: one entry per stage, each up ---
    let health = messages(got, "/insuwb/health");
    assert!(
        health.len() as f64 >= LISTEN_S - 2.0,
        "{} health",
        health.len()
    );
    for h in health {
        let names: Vec<&str> = h["stages"]
            .as_array()
            .unwrap()
            .iter()
            .map(|s| s["name"].as_str().unwrap())
            .collect();
        assert_eq!(names, STAGES);
    }
    let lasth = health[health.len() - 1]["stages"].as_array().unwrap();
    for s in lasth {
        assert!(f(s, "level") <= 1.0, "{s}");
        assert!(s["pid"].as_u64().unwrap() > 0, "{s}");
        assert!(s["published_rate_hz"].is_number(), "{s}");
    }
    assert!(f(&lasth[3], "published_rate_hz") > 0.0, "{}", lasth[3]);
    assert!(f(&lasth[4], "published") > 0.0, "{}", lasth[4]);
}
