//! The IMU driver's ROS 2 source against a DDS implementation nobody here
//! wrote: a group whose IMU source is `ros2:/test_imu` runs (stages `imu`
//! and `logger`), and a Python publisher built on the PyPI `cyclonedds`
//! package (`tests/ros2/imu_publisher.py`, `sensor_msgs::msg::dds_::Imu_`
//! on `rt/test_imu`, best effort as ROS IMU drivers publish) sends 300
//! samples at 100 Hz with known values, four of them invalid (a NaN, an
//! infinity, an out-of-range acceleration, a stamp before its
//! predecessor's). The recording must hold exactly the valid samples, with
//! their values, at their stamps mapped to CLOCK_MONOTONIC, in time order;
//! the driver's heartbeat must count the invalid ones as dropped.
//!
//! DDS discovery multicasts, so the test body runs in a private network
//! namespace (`unshare -n`, or `unshare -rn` when not root) with only
//! loopback up, multicast on and 224.0.0.0/4 routed to it: no packet
//! leaves the machine. Where namespaces or the Python environment
//! (`target/pyenv`, installed by `.ci/run`) are missing the test says so
//! and skips, unless `CI` is set: then it fails. Every wait is bounded;
//! the test starts processes, so it holds the one-at-a-time lock. It needs
//! `insuwb-stage-imu` built with its default features (the `ros2:` source).

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use crate::common;

use std::time::Duration;

use common::Group;
use insuwb_log::Record;
use insuwb_msg::{HealthState, ImuSample};

/// Set in the re-executed test process, inside the network namespace.
const INNER: &str = "INSUWB_ROS2_IMU_SOURCE_INNER";
/// This test's name in the binary, module and function (the re-executed
/// process runs it alone, `--exact`).
const TEST: &str =
    "ros2_imu_source::imu_samples_from_a_cyclonedds_publisher_are_driven_like_any_source";
const DOMAIN: u16 = 43;
const TOPIC: &str = "/test_imu";
/// Samples published, and how many of them are invalid (see the script).
const COUNT: usize = 300;
const INVALID: usize = 4;
/// Seconds the group runs: start, discovery, 3 s of samples, margin.
const GROUP_S: f64 = 20.0;
/// Bound of every wait.
const BOUND: Duration = Duration::from_secs(90);

#[test]
fn imu_samples_from_a_cyclonedds_publisher_are_driven_like_any_source() {
    common::cyclonedds_test(INNER, TEST, BOUND, inner);
}

/// What the publisher sent: stamp (CLOCK_REALTIME ns), values, why invalid.
struct Sent {
    stamp_ns: i128,
    accel: [f64; 3],
    gyro: [f64; 3],
    invalid: Option<String>,
}

fn sent(path: &std::path::Path) -> Vec<Sent> {
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    // The invalid values come as strings ("nan", "inf"): NaN here.
    let three = common::json_f64x3;
    v.as_array()
        .unwrap()
        .iter()
        .map(|s| Sent {
            stamp_ns: i128::from(s["stamp_ns"].as_i64().unwrap()),
            accel: three(&s["accel"]),
            gyro: three(&s["gyro"]),
            invalid: s["invalid"].as_str().map(str::to_owned),
        })
        .collect()
}

/// The test body, inside the network namespace.
fn inner() {
    let py = common::cyclonedds_python().expect("the Python environment vanished");
    let g = Group::with_config(
        "ros2imu",
        &format!("imu = \"ros2:{TOPIC}\"\nuwb = \"sim\"\nscenario = \"nlos-long\"\nseed = 1"),
        "filter = \"iakf\"\n",
        &format!("[ros2]\ndomain_id = {DOMAIN}\n"),
    );
    g.set_stages(&["imu", "logger"]);
    // CLOCK_REALTIME - CLOCK_MONOTONIC, as the driver maps the stamps.
    let offset_ns = common::realtime_ns() - i128::from(insuwb_runtime::monotonic_ns());
    let out_json = g.dir.join("published.json");
    let report = common::launch_beside_script(
        &g,
        GROUP_S,
        "imu",
        common::python_script(&py, "tests/ros2/imu_publisher.py")
            .args(["--domain", &DOMAIN.to_string()])
            .args(["--topic", TOPIC])
            .args(["--count", &COUNT.to_string()])
            .args(["--rate", "100"])
            .args(["--match-timeout", "10"])
            .arg("--out")
            .arg(&out_json),
        "[imu]",
        BOUND,
    );

    let sent = sent(&out_json);
    assert_eq!(sent.len(), COUNT);
    let valid: Vec<&Sent> = sent.iter().filter(|s| s.invalid.is_none()).collect();
    assert_eq!(valid.len(), COUNT - INVALID);

    // --- the heartbeat: every message received, the invalid ones dropped ---
    let imu = &report["stages"]["imu"];
    assert!(imu.is_object(), "no imu heartbeat: {report}");
    let n = |k: &str| imu[k].as_u64().unwrap_or_else(|| panic!("{k} in {imu}"));
    assert_eq!(n("received"), COUNT as u64, "{imu}");
    assert_eq!(n("published"), valid.len() as u64, "{imu}");
    // NaN, infinity, out of range; the stamp before its predecessor's.
    assert_eq!(n("dropped_invalid"), 3, "{imu}");
    assert_eq!(n("dropped_time"), 1, "{imu}");
    // Every sample timed by its stamp, none in another frame.
    let counters = &imu["counters"];
    assert_eq!(
        counters["receive_timed"].as_u64(),
        Some(0),
        "receive-timed samples: {imu}"
    );
    assert_eq!(
        counters["other_frame"].as_u64(),
        Some(0),
        "other frames: {imu}"
    );

    // --- the recording: exactly the valid samples, at their stamps ---
    let mut logged: Vec<ImuSample> = Vec::new();
    let mut ok_heartbeat = false;
    for r in common::records(&g.log_dir()) {
        match r {
            Record::Imu(s) => logged.push(s),
            Record::Health(h)
                if insuwb_msg::name_str(&h.stage) == "imu" && h.state() == Ok(HealthState::Ok) =>
            {
                ok_heartbeat = true;
            }
            _ => {}
        }
    }
    assert!(ok_heartbeat, "no imu heartbeat in state OK was logged");
    assert_eq!(logged.len(), valid.len(), "logged IMU samples");
    let close = |a: &[f64; 3], b: &[f64; 3]| a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-9);
    let mut worst_ns = 0i128;
    for (s, w) in logged.iter().zip(&valid) {
        assert!(
            close(&s.accel_mps2, &w.accel),
            "{:?} vs {:?}",
            s.accel_mps2,
            w.accel
        );
        assert!(
            close(&s.gyro_rps, &w.gyro),
            "{:?} vs {:?}",
            s.gyro_rps,
            w.gyro
        );
        // The stamp mapped to CLOCK_MONOTONIC (both offsets measured on
        // this host, microseconds apart), never after the publication.
        let d = i128::from(s.header.meas_time_ns) + offset_ns - w.stamp_ns;
        worst_ns = worst_ns.max(d.abs());
        assert!(
            d.abs() < 2_000_000,
            "measurement time {} is {d} ns from the stamp",
            s.header.meas_time_ns
        );
        assert!(s.header.meas_time_ns <= s.header.pub_time_ns);
    }
    eprintln!(
        "{} samples logged; measurement time within {worst_ns} ns of the stamp",
        logged.len()
    );
    assert!(
        logged
            .windows(2)
            .all(|w| w[0].header.meas_time_ns < w[1].header.meas_time_ns),
        "measurement times do not increase"
    );
    assert!(
        logged
            .windows(2)
            .all(|w| w[1].header.seq == w[0].header.seq + 1),
        "sequence numbers not consecutive"
    );
}
