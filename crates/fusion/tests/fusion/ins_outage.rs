//! A dead INS on a real flight: flight-a92f4787 of the UTIL data through
//! the lockstep runner with the `config/util.toml` preset and the default
//! output policy (`[fusion.output]`), its IMU samples removed for
//! `OUTAGE_S` from `OUTAGE_AT_S` (an IMU driver killed, then frozen), while
//! the UWB differences go on.
//!
//! Once the newest INS state is older than `stale_ins_timeout_s`, every
//! UWB fix must still give a valid pose, built on the fix alone and
//! flagged `FLAG_UWB_ONLY` (position and covariance of the fix), so that
//! the valid outputs never stop for longer than a few fix periods; before
//! the outage and once the INS serves again there is none. Data as
//! `divergence` (absent: the test says so and passes, unless `CI` is set).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use crate::common;

use common::{data_dir, load, preset};
use insuwb_data::segment::interpolate_truth;
use insuwb_fusion::output::OutputPolicyConfig;
use insuwb_fusion::runner;
use insuwb_msg::{FilterKind, FusedState};

const FLIGHT: &str = "flight-a92f4787";
const ANCHORS: &str = "anchors-const3.txt";
/// Start of the outage, s of the log (in flight: take-off 2.3 s, landing near 30 s).
const OUTAGE_AT_S: f64 = 15.0;
/// Its length, s.
const OUTAGE_S: f64 = 2.0;

fn secs(t_ns: u64) -> f64 {
    t_ns as f64 * 1e-9
}

#[test]
fn a_dead_ins_leaves_a_uwb_backed_pose_at_the_fix_rate() {
    let Some(dir) = data_dir(FLIGHT) else {
        return;
    };
    let mut p = preset();
    p.fusion.output = Some(OutputPolicyConfig::default());
    let stale_s = OutputPolicyConfig::default().stale_ins_timeout_s;
    let flight = load(&dir, FLIGHT, ANCHORS, &p);
    let outage = OUTAGE_AT_S..OUTAGE_AT_S + OUTAGE_S;
    let imu: Vec<_> = flight
        .imu
        .iter()
        .filter(|s| !outage.contains(&secs(s.header.meas_time_ns)))
        .copied()
        .collect();
    assert!(imu.len() < flight.imu.len());
    let out = runner::run(&imu, &flight.tdoa, &p.fusion, FilterKind::IakfTdoa).unwrap();

    let uwb_only: Vec<&FusedState> = out
        .fused
        .iter()
        .filter(|s| s.header.flags & FusedState::FLAG_UWB_ONLY != 0)
        .collect();
    let times: Vec<f64> = uwb_only
        .iter()
        .map(|s| secs(s.header.meas_time_ns))
        .collect();
    println!(
        "{} UWB-only poses from {:.2?} s to {:.2?} s",
        uwb_only.len(),
        times.first(),
        times.last()
    );
    // Only while the INS is stale: from the stale timeout into the outage
    // to its end (a fix's epoch may lag the tick that found it stale by a
    // fix period).
    assert!(
        times
            .iter()
            .all(|t| *t > OUTAGE_AT_S && *t < OUTAGE_AT_S + OUTAGE_S + 0.2),
        "{times:?}"
    );
    // At the fix rate (10 Hz) over the outage less the stale timeout.
    let expected = (OUTAGE_S - stale_s) * 10.0;
    assert!(
        uwb_only.len() as f64 > 0.8 * expected,
        "{} UWB-only poses, expected about {expected}",
        uwb_only.len()
    );
    let mut errs = Vec::new();
    for s in &uwb_only {
        assert_ne!(s.header.flags & FusedState::FLAG_VALID, 0);
        assert_eq!(
            s.header.flags & (FusedState::FLAG_STALE | FusedState::FLAG_DEGRADED),
            0
        );
        // The fix's position and covariance.
        let fix = out
            .fixes
            .iter()
            .find(|f| f.header.meas_time_ns == s.header.meas_time_ns)
            .expect("the fix it was built on");
        assert_eq!(s.pos_m, fix.pos_m);
        for i in 0..3 {
            for j in 0..3 {
                assert_eq!(s.cov[i][j], fix.pos_cov_m2[i][j]);
            }
            assert!(s.cov[3 + i][3 + i] > 0.0);
        }
        let g = interpolate_truth(&flight.truth, s.header.meas_time_ns).unwrap();
        errs.push((s.pos_m[0] - g.pos_m[0]).hypot(s.pos_m[1] - g.pos_m[1]));
    }
    errs.sort_by(f64::total_cmp);
    let median = errs[errs.len() / 2];
    println!("horizontal error of the UWB-only poses: median {median:.3} m");
    assert!(median < 0.5, "{errs:?}");

    // The valid outputs around the outage are never more than 0.5 s apart
    // (without the UWB-only poses: the whole outage).
    let valid: Vec<f64> = out
        .fused
        .iter()
        .filter(|s| s.header.flags & FusedState::FLAG_VALID != 0)
        .map(|s| secs(s.header.meas_time_ns))
        .filter(|t| (OUTAGE_AT_S - 1.0..OUTAGE_AT_S + OUTAGE_S + 1.0).contains(t))
        .collect();
    let gap = valid.windows(2).map(|w| w[1] - w[0]).fold(0.0, f64::max);
    println!("largest gap between valid outputs around the outage: {gap:.3} s");
    assert!(gap < 0.5, "largest gap {gap} s");
}
