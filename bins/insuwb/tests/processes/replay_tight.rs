//! The real-flight default through the processes: a UTIL flight imported
//! with `insuwb import util` (IMU, TDOA, the flow deck's body velocities
//! and its range finder's heights), replayed through the five stages with
//! the tight filter (`iakf_tdoa`, 1 kHz IMU) aided by the flow
//! (`aiding_sources = ["flow"]`: the IMU driver publishes the velocities
//! and heights, the fusion stage fuses them, the logger records them),
//! gives the fused states of `insuwb
//! eval --aiding flow`'s in-process code path, epoch by epoch, within 1 mm,
//! when the fusion stage drops no measurement as late (a busy machine can
//! make it drop a few: then their share and the accuracy are checked).
//!
//! Needs the shared UTIL data (`INSUWB_UTIL_DIR`, else
//! `<workspace>/../shared/data/util`); without them the test says so and
//! passes, unless the environment variable `CI` is set, where it fails.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use crate::common;

use common::{
    assert_same_fused_by_time, f, offline_run_aided, one_at_a_time, run, succeeded,
    undegraded_fused, util_data_dir, uwb_only, Group,
};

#[test]
fn a_real_flight_replayed_with_the_tight_filter_equals_eval() {
    let Some(data) = util_data_dir("cfBolt-log00") else {
        return;
    };
    let _lock = one_at_a_time();
    let tmp = std::env::temp_dir().join(format!("insuwb-test-tight-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir_all(&tmp).unwrap();
    let log = tmp.join("cf.iulog");
    // The preset, with the body velocities waiting for the UWB stream as
    // long as a busy machine can hold the UWB driver at 10x (2 s of
    // recording, 0.2 s of wall time): applied in time order, as in eval.
    let preset = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/util.toml"),
    )
    .unwrap();
    let config = tmp.join("util-wait.toml");
    std::fs::write(
        &config,
        format!("{preset}\n[fusion.aiding]\nwait_s = 2.0\n"),
    )
    .unwrap();
    succeeded(&run(&[
        "import",
        "util",
        data.join("cfBolt-log00").to_str().unwrap(),
        "--anchors",
        data.join("anchors-const3.txt").to_str().unwrap(),
        "--out",
        log.to_str().unwrap(),
        "--config",
        config.to_str().unwrap(),
    ]));
    // Predicting lazily (`eager_lag_s < 0`), as `insuwb eval` does: the
    // eager path drops a measurement that comes later than its lag behind
    // the INS stream, which a busy machine makes happen at 10x
    // (`crates/eval/tests/eager.rs` covers that path).
    let g = Group::with_config(
        "tight",
        &format!(
            "imu = \"replay:{0}\"\nuwb = \"replay:{0}\"\nspeed = 10.0",
            log.display()
        ),
        "filter = \"iakf_tdoa\"\neager_lag_s = -1.0\naiding_sources = [\"flow\"]\n",
        "",
    );
    // 51 s of data at 10x, and the start.
    let report = g.launch(8.0, &[]);
    // A busy machine can hold the UWB driver long enough for the fusion
    // stage's stale policy to move on (counted as late, `dropped_time`):
    // then the runs differ from that epoch on, and only the accuracy and a
    // small share of drops are checked.
    let dropped = f(&report["stages"]["fusion"], "dropped_time");
    let published = f(&report["stages"]["uwb"], "published");
    assert!(dropped < 0.05 * published, "{report}");
    let piped = undegraded_fused(&g.log_dir());
    // The same log through the in-process code path of `insuwb eval`.
    let mut out = offline_run_aided(&log, insuwb_msg::FilterKind::IakfTdoa, true);
    // The flow and the heights reached the fusion stage and the log.
    let records = insuwb_log::read_segments(g.log_dir()).unwrap().records;
    let count = |f: fn(&insuwb_log::Record) -> bool| records.iter().filter(|r| f(r)).count();
    let recorded = count(|r| matches!(r, insuwb_log::Record::BodyVel(_)));
    assert!(recorded > 2000, "{recorded} body velocities recorded");
    let heights = count(|r| matches!(r, insuwb_log::Record::Height(_)));
    assert!(heights > 500, "{heights} heights recorded");
    out.fused.retain(|s| !uwb_only(s));
    assert!(
        out.fused.len() > 400,
        "{} fused in process",
        out.fused.len()
    );

    if dropped > 0.0 {
        eprintln!(
            "{dropped} TDOA differences dropped as late (busy machine): equality not checked"
        );
        let rmse = f(&report, "rmse_horizontal");
        assert!(rmse.is_finite() && rmse < 0.2, "{report}");
    } else {
        assert_same_fused_by_time(&piped, &out.fused);
    }
    let _ = std::fs::remove_dir_all(&tmp);
}
