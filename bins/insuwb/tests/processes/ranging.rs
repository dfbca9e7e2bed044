//! Two-way ranging through the processes:
//!
//! - `insuwb demo --uwb twr` (the simulator's ranges to the UWB driver) and
//!   `insuwb demo --uwb twr --via-devices` (a DWM1001 tag's `lec` lines on a
//!   pseudo-terminal, read by the device driver) keep the 10 Hz loop, and
//!   the device path keeps the plain demo's accuracy on the same seed;
//! - UTIL's static ranging log, imported with `insuwb import util` and
//!   replayed through the five stages with the tight filter (`[uwb] kind =
//!   "twr"`), gives the fused states of `insuwb eval`'s in-process code
//!   path within 1 mm; the logger records the ranges and the log's kind.
//!
//! The replay needs the shared UTIL data (`INSUWB_UTIL_DIR`, else
//! `<workspace>/../shared/data/util`); without them the test says so and
//! passes, unless the environment variable `CI` is set, where it fails.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::process::Command;

use crate::common;
use common::{
    assert_same_fused_by_time, demo_json, f, insuwb, offline_run, one_at_a_time, run, succeeded,
    undegraded_fused, util_data_dir, Group,
};

/// Runs `insuwb demo --uwb twr` for 9 s with `extra` arguments; returns
/// the JSON report.
fn demo_twr(extra: &[&str]) -> serde_json::Value {
    let mut args = vec!["--uwb", "twr", "--duration", "9"];
    args.extend_from_slice(extra);
    demo_json(&args)
}

#[test]
fn the_ranging_demo_runs_plain_and_through_a_dwm1001() {
    let _lock = one_at_a_time();
    let plain = demo_twr(&[]);
    let devices = demo_twr(&["--via-devices"]);
    let (rmse_plain, rmse_devices) = (f(&plain, "rmse_horizontal"), f(&devices, "rmse_horizontal"));
    eprintln!(
        "ranges, plain: fused {:.3} Hz, fixes {:.2} Hz, rmse {rmse_plain:.4} m; via a DWM1001: fused {:.3} Hz, fixes {:.2} Hz, rmse {rmse_devices:.4} m",
        f(&plain, "fused_rate_hz"),
        f(&plain, "uwb_fix_rate_hz"),
        f(&devices, "fused_rate_hz"),
        f(&devices, "uwb_fix_rate_hz"),
    );
    for r in [&plain, &devices] {
        let rate = f(r, "fused_rate_hz");
        assert!((9.8..=10.2).contains(&rate), "fused rate {rate} Hz: {r}");
        let fixes = f(r, "uwb_fix_rate_hz");
        assert!((9.0..=10.5).contains(&fixes), "fix rate {fixes} Hz: {r}");
        assert_eq!(f(r, "restarts"), 0.0, "{r}");
    }
    // The simulated ranges have 0.1 m of noise and NLOS events.
    assert!(rmse_plain < 0.2, "{plain}");
    assert!(
        rmse_devices <= 1.2 * rmse_plain + 0.01,
        "rmse via a DWM1001 {rmse_devices} m against {rmse_plain} m plain: {devices}"
    );
}

#[test]
fn the_static_ranging_log_replayed_with_the_tight_filter_equals_eval() {
    let Some(data) = util_data_dir("twr-flight-45c1546b") else {
        return;
    };
    let _lock = one_at_a_time();
    let tmp = std::env::temp_dir().join(format!("insuwb-test-twr-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir_all(&tmp).unwrap();
    let log = tmp.join("twr.iulog");
    succeeded(&run(&[
        "import",
        "util",
        data.join("twr-flight-45c1546b").to_str().unwrap(),
        "--anchors",
        data.join("anchors-const3.txt").to_str().unwrap(),
        "--out",
        log.to_str().unwrap(),
    ]));
    // A TDOA robot refuses the ranging log, naming the key to set.
    let tdoa = Group::with_config(
        "twr_refused",
        &format!(
            "imu = \"replay:{0}\"\nuwb = \"replay:{0}\"\nspeed = 10.0",
            log.display()
        ),
        "filter = \"iakf_tdoa\"\n",
        "",
    );
    let out = Command::new(insuwb())
        .arg("launch")
        .arg(tdoa.dir.join("robot.toml"))
        .args(["--duration", "1"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(
        stderr.contains("uwb.kind") && stderr.contains("kind = \"twr\""),
        "{stderr}"
    );
    // Predicting lazily, as `insuwb eval` does (see `replay_tight`).
    let g = Group::with_config(
        "twr",
        &format!(
            "imu = \"replay:{0}\"\nuwb = \"replay:{0}\"\nspeed = 10.0",
            log.display()
        ),
        "filter = \"iakf_tdoa\"\neager_lag_s = -1.0\n",
        "[uwb]\nkind = \"twr\"\n",
    );
    // 73 s of data at 10x, and the start.
    let report = g.launch(10.0, &[]);
    let dropped = f(&report["stages"]["fusion"], "dropped_time");
    let published = f(&report["stages"]["uwb"], "published");
    assert!(published > 5000.0, "{report}");
    assert!(dropped < 0.05 * published, "{report}");
    let recorded = insuwb_log::read_segments(g.log_dir()).unwrap();
    let ranges = recorded
        .records
        .iter()
        .filter(|r| matches!(r, insuwb_log::Record::Range(_)))
        .count();
    assert!(ranges > 5000, "{ranges} ranges recorded");
    let piped = undegraded_fused(&g.log_dir());
    let out = offline_run(&log, insuwb_msg::FilterKind::IakfTdoa);
    assert!(
        out.fused.len() > 600,
        "{} fused in process",
        out.fused.len()
    );
    if dropped > 0.0 {
        eprintln!("{dropped} ranges dropped as late (busy machine): equality not checked");
        let rmse = f(&report, "rmse_horizontal");
        assert!(rmse.is_finite() && rmse < 0.2, "{report}");
    } else {
        assert_same_fused_by_time(&piped, &out.fused);
    }
    let _ = std::fs::remove_dir_all(&tmp);
}
