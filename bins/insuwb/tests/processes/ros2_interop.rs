//! The ROS 2 bridge against a DDS implementation nobody here wrote: a group
//! with the `ros2` stage runs on the simulated demo scenario (10 Hz UWB
//! fixes), and a Python subscriber built on the PyPI `cyclonedds` package
//! (`tests/ros2/subscriber.py`, ROS 2 type names such as
//! `nav_msgs::msg::dds_::Odometry_` on `rt/insuwb/odom`) receives the
//! odometry, `/tf`, `/tf_static` (as a late joiner), the IMU and
//! `/diagnostics`; the samples are checked against the group's recording
//! (position to 1e-6 m, covariance layout, frames, stamps, rate). After
//! the subscriber's window the bridge is killed, and the launcher restarts
//! it like every stage.
//!
//! DDS discovery multicasts, so the test body runs in a private network
//! namespace (`unshare -n`, or `unshare -rn` when not root) with only
//! loopback up, multicast on and 224.0.0.0/4 routed to it: no packet
//! leaves the machine. Where namespaces or the Python environment
//! (`target/pyenv`, installed by `.ci/run`) are missing the test says so
//! and skips, unless `CI` is set: then it fails. Every wait is bounded;
//! the test starts processes, so it holds the one-at-a-time lock.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use common::{insuwb, run_bounded, wait_bounded, Group};
use insuwb_log::Record;
use insuwb_msg::{FusedState, ImuSample};

/// Set in the re-executed test process, inside the network namespace.
const INNER: &str = "INSUWB_ROS2_INTEROP_INNER";
/// This test's name in the binary, module and function (the re-executed
/// process runs it alone, `--exact`).
const TEST: &str = "ros2_interop::ros2_topics_reach_a_cyclonedds_subscriber";
const SIM: &str = "imu = \"sim\"\nuwb = \"sim\"\nscenario = \"nlos-long\"\nseed = 1";
const DOMAIN: u16 = 42;
const LEVER_ARM: [f64; 3] = [0.1, -0.2, 0.3];
/// Seconds the group runs and the subscriber listens after its first odometry.
const GROUP_S: f64 = 22.0;
const LISTEN_S: f64 = 8.0;
/// When the bridge gets SIGKILL, s after start.
const KILL_AT_S: f64 = 17.0;
/// Bound of every wait.
const BOUND: Duration = Duration::from_secs(90);

#[test]
fn ros2_topics_reach_a_cyclonedds_subscriber() {
    common::cyclonedds_test(INNER, TEST, BOUND, inner);
}

/// The test body, inside the network namespace.
fn inner() {
    let py = common::cyclonedds_python().expect("the Python environment vanished");
    let g = Group::with_config(
        "ros2",
        SIM,
        "filter = \"iakf\"\n",
        &format!(
            "[ros2]\ndomain_id = {DOMAIN}\nantenna_lever_arm_m = [{}, {}, {}]\n",
            LEVER_ARM[0], LEVER_ARM[1], LEVER_ARM[2]
        ),
    );
    // `stages` is a top-level key: before the first table.
    let path = g.dir.join("robot.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    std::fs::write(
        &path,
        format!("stages = [\"imu\", \"uwb\", \"ins\", \"fusion\", \"ros2\", \"logger\"]\n{text}"),
    )
    .unwrap();
    // CLOCK_REALTIME - CLOCK_MONOTONIC, as the bridge stamps.
    let offset_ns = common::realtime_ns() - i128::from(insuwb_runtime::monotonic_ns());
    let mut launcher = Command::new(insuwb())
        .arg("launch")
        .arg(&path)
        .args(["--duration", &GROUP_S.to_string(), "--json"])
        // After the subscriber's window: the launcher restarts the bridge
        // like any stage, and it heartbeats again before the end.
        .args(["--fault", &format!("ros2@{KILL_AT_S}")])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    common::wait_for_lock(&g, &mut launcher, BOUND, "ros2");
    let out_json = g.dir.join("received.json");
    let sub = run_bounded(
        Command::new(&py)
            .arg(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/ros2/subscriber.py"))
            .args(["--domain", &DOMAIN.to_string()])
            .args(["--duration", &LISTEN_S.to_string()])
            .args(["--first-timeout", "30"])
            .arg("--out")
            .arg(&out_json),
        BOUND,
    );
    let sub_err = String::from_utf8_lossy(&sub.stderr);
    eprintln!("{}{sub_err}", String::from_utf8_lossy(&sub.stdout));
    wait_bounded(&mut launcher, "insuwb launch", BOUND);
    let out = launcher.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "launch failed:\n{stderr}");
    // The bridge's own lines (start, what it published, write failures).
    for l in stderr.lines().filter(|l| l.contains("ros2")) {
        eprintln!("{l}");
    }
    assert!(
        sub.status.success(),
        "the cyclonedds subscriber failed:\n{sub_err}\n{stderr}"
    );
    let report: serde_json::Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("no JSON report ({e}):\n{stderr}"));
    common::assert_restarted_once(&report, &stderr, "ros2", &g);
    let got: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out_json).unwrap()).unwrap();
    let (fused, imu) = recording(&g.log_dir());
    check(&got, &fused, &imu, offset_ns, &g.name);
}

/// The recording's valid fused states and IMU samples.
fn recording(log: &Path) -> (Vec<FusedState>, Vec<ImuSample>) {
    let mut fused = Vec::new();
    let mut imu = Vec::new();
    for r in common::records(log) {
        match r {
            Record::Fused(s) if s.header.flags & FusedState::FLAG_VALID != 0 => fused.push(s),
            Record::Imu(s) => imu.push(s),
            _ => {}
        }
    }
    (fused, imu)
}

fn nums(v: &serde_json::Value) -> Vec<f64> {
    v.as_array()
        .unwrap_or_else(|| panic!("not an array: {v}"))
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

fn stamp(v: &serde_json::Value) -> i128 {
    i128::from(v["stamp_ns"].as_i64().unwrap())
}

/// The sample whose CLOCK_MONOTONIC time + `offset_ns` is nearest to
/// `stamp_ns`, and how far it is.
fn nearest<T>(xs: &[T], t: impl Fn(&T) -> u64, stamp_ns: i128, offset_ns: i128) -> (&T, i128) {
    let i = xs.partition_point(|x| i128::from(t(x)) + offset_ns < stamp_ns);
    [i.saturating_sub(1), i.min(xs.len() - 1)]
        .into_iter()
        .map(|j| (&xs[j], (i128::from(t(&xs[j])) + offset_ns - stamp_ns).abs()))
        .min_by_key(|(_, d)| *d)
        .unwrap()
}

fn check(
    got: &serde_json::Value,
    fused: &[FusedState],
    imu: &[ImuSample],
    offset_ns: i128,
    group: &str,
) {
    assert!(!fused.is_empty() && !imu.is_empty(), "empty recording");
    // --- odometry ---
    let odom = got["odom"].as_array().unwrap();
    assert!(odom.len() >= 50, "{} odometry messages", odom.len());
    let mut stamp_minus_meas = Vec::new();
    let mut matched = Vec::new();
    for o in odom {
        assert_eq!(o["frame_id"], "map");
        assert_eq!(o["child_frame_id"], "base_link");
        let (s, d) = nearest(fused, |s| s.header.meas_time_ns, stamp(o), offset_ns);
        assert!(
            d < 5_000_000,
            "no fused state within 5 ms of odometry stamp {}: {d} ns",
            stamp(o)
        );
        stamp_minus_meas.push(stamp(o) - i128::from(s.header.meas_time_ns));
        matched.push(s.header.meas_time_ns);
        let p = nums(&o["position"]);
        assert!(
            p.iter().zip(&s.pos_m).all(|(a, b)| (a - b).abs() <= 1e-6),
            "position {p:?} vs {:?}",
            s.pos_m
        );
        let q = nums(&o["orientation"]);
        let n = s.quat.iter().map(|v| v * v).sum::<f64>().sqrt();
        let want = [s.quat[1] / n, s.quat[2] / n, s.quat[3] / n, s.quat[0] / n];
        assert!(
            q.iter().zip(&want).all(|(a, b)| (a - b).abs() <= 1e-9),
            "quaternion (x y z w) {q:?} vs {want:?}"
        );
        let c = nums(&o["pose_covariance"]);
        assert_eq!(c.len(), 36);
        for i in 0..6 {
            for j in 0..6 {
                let want = match (i < 3 && j < 3, i == j) {
                    (true, _) => s.cov[i][j],
                    (false, true) => 1e6,
                    (false, false) => 0.0,
                };
                assert!(
                    (c[i * 6 + j] - want).abs() <= 1e-12 * want.abs().max(1.0),
                    "pose covariance ({i}, {j}) = {} vs {want}",
                    c[i * 6 + j]
                );
            }
        }
        // The twist is in the body frame: same speed as the ENU velocity.
        let v = nums(&o["linear"]);
        let speed = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        let speed_enu = s.vel_mps.iter().map(|x| x * x).sum::<f64>().sqrt();
        assert!(
            (speed - speed_enu).abs() <= 1e-9,
            "speed {speed} vs {speed_enu}"
        );
        let tc = nums(&o["twist_covariance"]);
        let trace: f64 = (0..3).map(|i| tc[i * 7]).sum();
        let trace_enu: f64 = (3..6).map(|i| s.cov[i][i]).sum();
        assert!(
            (trace - trace_enu).abs() <= 1e-9 * trace_enu.max(1.0),
            "twist covariance trace"
        );
        assert_eq!(
            &tc[21..],
            &[1e6, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1e6, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1e6]
        );
    }
    // Stamps: the header time in CLOCK_REALTIME by one offset (its
    // re-measurements move it by microseconds).
    let (lo, hi) = (
        stamp_minus_meas.iter().min().unwrap(),
        stamp_minus_meas.iter().max().unwrap(),
    );
    assert!(
        hi - lo < 1_000_000,
        "stamp - measurement time varies by {} ns",
        hi - lo
    );
    assert!(
        (lo - offset_ns).abs() < 5_000_000,
        "stamp offset {lo} vs {offset_ns}"
    );
    let first = stamp(&odom[0]);
    let last = stamp(&odom[odom.len() - 1]);
    let rate = (odom.len() - 1) as f64 / ((last - first) as f64 * 1e-9);
    // Every valid fused state of that span arrived, once, in order.
    assert!(
        matched.windows(2).all(|w| w[0] < w[1]),
        "odometry repeated or out of order"
    );
    let span = fused
        .iter()
        .filter(|s| (matched[0]..=matched[matched.len() - 1]).contains(&s.header.meas_time_ns))
        .count();
    eprintln!(
        "odometry: {} messages over {:.3} s: {rate:.3} Hz ({span} valid fused states recorded in that span)",
        odom.len(),
        (last - first) as f64 * 1e-9
    );
    assert!((9.8..=10.2).contains(&rate), "odometry rate {rate} Hz");
    assert_eq!(odom.len(), span, "odometry lost or added");
    assert!(
        odom.windows(2).all(|w| stamp(&w[0]) < stamp(&w[1])),
        "odometry out of order"
    );
    // --- /tf: map -> base_link, the odometry's pose ---
    let tf = got["tf"].as_array().unwrap();
    assert!(
        tf.len() * 10 >= odom.len() * 9,
        "{} tf for {} odometry",
        tf.len(),
        odom.len()
    );
    for m in tf {
        let t = &m.as_array().unwrap()[0];
        assert_eq!(
            (t["frame_id"].as_str(), t["child_frame_id"].as_str()),
            (Some("map"), Some("base_link"))
        );
        let (s, d) = nearest(fused, |s| s.header.meas_time_ns, stamp(t), offset_ns);
        assert!(d < 5_000_000);
        let p = nums(&t["translation"]);
        assert!(
            p.iter().zip(&s.pos_m).all(|(a, b)| (a - b).abs() <= 1e-6),
            "tf translation {p:?} vs {:?}",
            s.pos_m
        );
    }
    // --- /tf_static, received by a late joiner: the antenna ---
    let statics = got["tf_static"].as_array().unwrap();
    assert!(
        !statics.is_empty(),
        "the late joiner got no /tf_static (transient-local)"
    );
    let t = &statics[0].as_array().unwrap()[0];
    assert_eq!(
        (t["frame_id"].as_str(), t["child_frame_id"].as_str()),
        (Some("base_link"), Some("uwb_antenna"))
    );
    assert_eq!(nums(&t["translation"]), LEVER_ARM);
    assert_eq!(nums(&t["rotation"]), [0.0, 0.0, 0.0, 1.0]);
    // --- IMU: every sample, exactly ---
    let imu_msgs = got["imu"].as_array().unwrap();
    let imu_first = stamp(&imu_msgs[0]);
    let imu_last = stamp(&imu_msgs[imu_msgs.len() - 1]);
    let imu_rate = (imu_msgs.len() - 1) as f64 / ((imu_last - imu_first) as f64 * 1e-9);
    eprintln!("imu: {} messages, {imu_rate:.2} Hz", imu_msgs.len());
    assert!((98.0..=102.0).contains(&imu_rate), "IMU rate {imu_rate} Hz");
    for m in imu_msgs {
        assert_eq!(m["frame_id"], "base_link");
        assert_eq!(nums(&m["orientation_covariance"])[0], -1.0);
        let (s, d) = nearest(imu, |s| s.header.meas_time_ns, stamp(m), offset_ns);
        assert!(d < 2_000_000, "no IMU sample within 2 ms");
        // Equal up to the last bit JSON parsing may change.
        let close = |a: &[f64], b: &[f64; 3]| {
            a.iter()
                .zip(b)
                .all(|(x, y)| (x - y).abs() <= 1e-14 * y.abs().max(1.0))
        };
        let (acc, gyro) = (
            nums(&m["linear_acceleration"]),
            nums(&m["angular_velocity"]),
        );
        assert!(close(&acc, &s.accel_mps2), "{acc:?} vs {:?}", s.accel_mps2);
        assert!(close(&gyro, &s.gyro_rps), "{gyro:?} vs {:?}", s.gyro_rps);
    }
    // --- /diagnostics at 1 Hz, one status per stage ---
    let diags = got["diagnostics"].as_array().unwrap();
    assert!(
        diags.len() as f64 >= LISTEN_S - 2.0,
        "{} diagnostics in {LISTEN_S} s",
        diags.len()
    );
    let want = ["imu", "uwb", "ins", "fusion", "ros2", "logger"].map(|s| format!("insuwb/{s}"));
    for d in diags {
        let status = d["status"].as_array().unwrap();
        let names: Vec<&str> = status.iter().map(|s| s["name"].as_str().unwrap()).collect();
        assert_eq!(names, want);
    }
    let last = diags[diags.len() - 1]["status"].as_array().unwrap();
    for s in last {
        assert_eq!(s["hardware_id"], group);
        assert!(s["level"].as_u64().unwrap() <= 1, "{s}");
        assert!(s["values"]["published"].is_string(), "{s}");
    }
    let ros2 = &last[4];
    let published: u64 = ros2["values"]["published"]
        .as_str()
        .unwrap()
        .parse()
        .unwrap();
    assert!(published > 0, "{ros2}");
    let stamps: Vec<i128> = diags.iter().map(stamp).collect();
    for w in stamps.windows(2) {
        let dt = (w[1] - w[0]) as f64 * 1e-9;
        assert!((0.8..=1.2).contains(&dt), "diagnostics period {dt} s");
    }
}
