//! The ROS 2 bridge's odometry and range finder inputs against a DDS
//! implementation nobody here wrote: a group with stages `imu` (simulated,
//! a scenario without simulated velocities or heights), `logger` and
//! `ros2`, whose `[ros2] odometry_in` is `/wheel/odom` and `height_in`
//! `/flow/range`, runs, and a Python publisher built on the PyPI
//! `cyclonedds` package (`tests/ros2/odometry_publisher.py`,
//! `nav_msgs::msg::dds_::Odometry_` on `rt/wheel/odom` and
//! `sensor_msgs::msg::dds_::Range_` on `rt/flow/range`, reliable as
//! drivers publish) sends 150 messages of each at 50 Hz. The odometry
//! carries known twists and twist covariances (set, unset, unknown), three
//! of them invalid (a NaN velocity, a negative variance, a stamp before its
//! predecessor's); the ranges known distances within the sensor's 0.04-4 m,
//! four of them invalid (+inf, NaN, 4.5 m, a stamp before its
//! predecessor's). The recording must hold exactly the valid ones, as body
//! velocities of source odometry with their velocities and the sigmas of
//! their covariances and as heights of source range finder with their
//! ranges, at their stamps mapped to CLOCK_MONOTONIC, in time order; the
//! bridge's last heartbeat must count the refused ones.
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

use std::time::Duration;

use common::Group;
use insuwb_log::Record;
use insuwb_msg::{BodyVelocity, Height};

/// Set in the re-executed test process, inside the network namespace.
const INNER: &str = "INSUWB_ROS2_ODOMETRY_SOURCE_INNER";
/// This test's name in the binary, module and function (the re-executed
/// process runs it alone, `--exact`).
const TEST: &str = "ros2_odometry_source::odometry_and_ranges_from_a_cyclonedds_publisher_become_body_velocities_and_heights";
const DOMAIN: u16 = 44;
const TOPIC: &str = "/wheel/odom";
const RANGE_TOPIC: &str = "/flow/range";
/// `[ros2] odometry_in_sigma_mps`: the sigma of an axis whose variance is 0
/// (not the default, so that the test sees it is read).
const DEFAULT_SIGMA_MPS: f64 = 0.15;
/// Messages published, and how many of them are invalid (see the script):
/// for their values, for their time.
const COUNT: usize = 150;
const INVALID_VALUES: u64 = 2;
const INVALID_TIME: u64 = 1;
/// Ranges refused for their values (+inf, NaN, beyond 4 m) and their time.
const INVALID_RANGE_VALUES: u64 = 3;
const INVALID_RANGE_TIME: u64 = 1;
/// Seconds the group runs: start, discovery, 3 s of messages, margin.
const GROUP_S: f64 = 16.0;
/// Bound of every wait.
const BOUND: Duration = Duration::from_secs(90);

#[test]
fn odometry_and_ranges_from_a_cyclonedds_publisher_become_body_velocities_and_heights() {
    common::cyclonedds_test(INNER, TEST, BOUND, inner);
}

/// What the publisher sent: stamp (CLOCK_REALTIME ns), linear velocity,
/// variances of the linear axes, why invalid.
struct Sent {
    stamp_ns: i128,
    vel: [f64; 3],
    var: [f64; 3],
    invalid: Option<String>,
}

fn sent(path: &std::path::Path) -> Vec<Sent> {
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    // The invalid value comes as a string ("nan"): NaN here.
    let three = common::json_f64x3;
    v.as_array()
        .unwrap()
        .iter()
        .filter(|s| s.get("vel").is_some())
        .map(|s| Sent {
            stamp_ns: i128::from(s["stamp_ns"].as_i64().unwrap()),
            vel: three(&s["vel"]),
            var: three(&s["var"]),
            invalid: s["invalid"].as_str().map(str::to_owned),
        })
        .collect()
}

/// The ranges the publisher sent: stamp (CLOCK_REALTIME ns), range (NaN or
/// infinite as their strings), whether invalid.
fn sent_ranges(path: &std::path::Path) -> Vec<(i128, f64, bool)> {
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    v.as_array()
        .unwrap()
        .iter()
        .filter_map(|s| {
            let r = s.get("range")?;
            let value = r
                .as_f64()
                .unwrap_or_else(|| r.as_str().unwrap().parse().unwrap());
            Some((
                i128::from(s["stamp_ns"].as_i64().unwrap()),
                value,
                !s["invalid"].is_null(),
            ))
        })
        .collect()
}

/// The sigma a variance stands for: unset (0) the configured one, 1e6 or
/// more not measured (0), else its square root.
fn sigma(var: f64) -> f64 {
    if var == 0.0 {
        DEFAULT_SIGMA_MPS
    } else if var >= 1e6 {
        0.0
    } else {
        var.sqrt()
    }
}

/// The test body, inside the network namespace.
fn inner() {
    let py = common::cyclonedds_python().expect("the Python environment vanished");
    // The default scenario simulates no velocities: every body velocity
    // logged is the bridge's.
    let g = Group::with_config(
        "ros2odom",
        "imu = \"sim\"\nuwb = \"sim\"\nseed = 1",
        "filter = \"iakf\"\naiding_sources = [\"odometry\"]\n",
        &format!(
            "[ros2]\ndomain_id = {DOMAIN}\npublish_imu = false\nodometry_in = \"{TOPIC}\"\n\
             odometry_in_sigma_mps = {DEFAULT_SIGMA_MPS}\nheight_in = \"{RANGE_TOPIC}\"\n"
        ),
    );
    g.set_stages(&["imu", "logger", "ros2"]);
    // CLOCK_REALTIME - CLOCK_MONOTONIC, as the bridge maps the stamps.
    let offset_ns = common::realtime_ns() - i128::from(insuwb_runtime::monotonic_ns());
    let out_json = g.dir.join("published.json");
    let report = common::launch_beside_script(
        &g,
        GROUP_S,
        "ros2",
        common::python_script(&py, "tests/ros2/odometry_publisher.py")
            .args(["--domain", &DOMAIN.to_string()])
            .args(["--topic", TOPIC])
            .args(["--range-topic", RANGE_TOPIC])
            .args(["--count", &COUNT.to_string()])
            .args(["--rate", "50"])
            .args(["--match-timeout", "10"])
            .arg("--out")
            .arg(&out_json),
        "ros2",
        BOUND,
    );

    let sent = sent(&out_json);
    assert_eq!(sent.len(), COUNT);
    let valid: Vec<&Sent> = sent.iter().filter(|s| s.invalid.is_none()).collect();
    assert_eq!(
        valid.len() as u64,
        COUNT as u64 - INVALID_VALUES - INVALID_TIME
    );

    // --- the bridge's last heartbeat: the refused ones counted ---
    let ros2 = &report["stages"]["ros2"];
    assert!(ros2.is_object(), "no ros2 heartbeat: {report}");
    let n = |k: &str| ros2[k].as_u64().unwrap_or_else(|| panic!("{k} in {ros2}"));
    // NaN velocity, negative variance, the three ranges; the stamps before
    // their predecessors' (nothing else of the bridge's is dropped: no
    // fusion, no IMU out).
    assert_eq!(
        n("dropped_invalid"),
        INVALID_VALUES + INVALID_RANGE_VALUES,
        "{ros2}"
    );
    assert_eq!(
        n("dropped_time"),
        INVALID_TIME + INVALID_RANGE_TIME,
        "{ros2}"
    );
    let counters = &ros2["counters"];
    assert_eq!(
        counters["velocities"].as_u64(),
        Some(valid.len() as u64),
        "velocities published: {ros2}"
    );
    assert_eq!(
        counters["velocities_other_frame"].as_u64(),
        Some(0),
        "other frames: {ros2}"
    );
    assert!(n("received") >= 2 * COUNT as u64, "{ros2}");

    // --- the recording: exactly the valid ranges, as heights ---
    let ranges = sent_ranges(&out_json);
    assert_eq!(ranges.len(), COUNT);
    let valid_ranges: Vec<&(i128, f64, bool)> = ranges.iter().filter(|r| !r.2).collect();
    assert_eq!(
        valid_ranges.len() as u64,
        COUNT as u64 - INVALID_RANGE_VALUES - INVALID_RANGE_TIME
    );
    let heights: Vec<Height> = common::records(&g.log_dir())
        .into_iter()
        .filter_map(|r| match r {
            Record::Height(h) => Some(h),
            _ => None,
        })
        .collect();
    assert_eq!(heights.len(), valid_ranges.len(), "logged heights");
    for (h, (stamp_ns, range, _)) in heights.iter().zip(&valid_ranges) {
        assert_eq!(h.source, Height::SOURCE_RANGE_FINDER);
        // Sent as float32.
        assert!((h.range_m - range).abs() < 1e-6, "{} vs {range}", h.range_m);
        let d = i128::from(h.header.meas_time_ns) + offset_ns - stamp_ns;
        assert!(d.abs() < 2_000_000, "height time {d} ns from its stamp");
    }
    assert!(heights
        .windows(2)
        .all(|w| w[0].header.meas_time_ns < w[1].header.meas_time_ns));

    // --- the recording: exactly the valid messages, at their stamps ---
    let logged: Vec<BodyVelocity> = common::records(&g.log_dir())
        .into_iter()
        .filter_map(|r| match r {
            Record::BodyVel(v) => Some(v),
            _ => None,
        })
        .collect();
    assert_eq!(logged.len(), valid.len(), "logged body velocities");
    let close = |a: &[f64; 3], b: &[f64; 3]| a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-9);
    let mut worst_ns = 0i128;
    for (v, w) in logged.iter().zip(&valid) {
        assert_eq!(v.source, BodyVelocity::SOURCE_ODOMETRY);
        assert!(close(&v.vel_mps, &w.vel), "{:?} vs {:?}", v.vel_mps, w.vel);
        let want_sigma = w.var.map(sigma);
        assert!(
            close(&v.sigma_mps, &want_sigma),
            "sigma {:?}, variances {:?}",
            v.sigma_mps,
            w.var
        );
        // The stamp mapped to CLOCK_MONOTONIC (both offsets measured on
        // this host, microseconds apart), never after the publication.
        let d = i128::from(v.header.meas_time_ns) + offset_ns - w.stamp_ns;
        worst_ns = worst_ns.max(d.abs());
        assert!(
            d.abs() < 2_000_000,
            "measurement time {} is {d} ns from the stamp",
            v.header.meas_time_ns
        );
        assert!(v.header.meas_time_ns <= v.header.pub_time_ns);
    }
    eprintln!(
        "{} body velocities logged; measurement time within {worst_ns} ns of the stamp",
        logged.len()
    );
    // Each axis kind was exercised: set, unset (the configured sigma),
    // unknown (not measured).
    let sigmas: Vec<f64> = logged.iter().flat_map(|v| v.sigma_mps).collect();
    assert!(sigmas.contains(&DEFAULT_SIGMA_MPS) && sigmas.contains(&0.0));
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
