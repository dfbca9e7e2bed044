//! Sensor faults through the real process group: UWB silent for 10 s (INS
//! coasting, flagged degraded, with a growing covariance, then a clean
//! recovery) and the IMU driver frozen (fusion flags its outputs stale,
//! publishes no valid pose built on a stale INS state and, from the UWB
//! fixes, valid poses flagged UWB-only until the INS serves again).
//!
//! The tests start processes and measure time: one at a time (a lock).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use insuwb_eval::metrics::TruthTrack;
use insuwb_log::Record;
use insuwb_msg::{FusedState, GroundTruth};

use crate::common;
use common::{f, one_at_a_time as lock, records, Group};

/// Fused states and ground truth of a recording, time-sorted, and the
/// recording's start (the first truth sample: the scenario's time zero).
fn fused_and_truth(g: &Group) -> (Vec<FusedState>, Vec<GroundTruth>, u64) {
    let mut fused = Vec::new();
    let mut truth = Vec::new();
    for r in records(&g.log_dir()) {
        match r {
            Record::Fused(s) => fused.push(s),
            Record::Truth(t) => truth.push(t),
            _ => {}
        }
    }
    fused.sort_by_key(|s| s.header.meas_time_ns);
    truth.sort_by_key(|t| t.header.meas_time_ns);
    truth.dedup_by_key(|t| t.header.meas_time_ns);
    let t0 = truth.first().map(|t| t.header.meas_time_ns).unwrap();
    (fused, truth, t0)
}

fn flagged(s: &FusedState, flag: u32) -> bool {
    s.header.flags & flag != 0
}

/// Horizontal RMS error of `states` against truth.
fn rms(states: &[&FusedState], track: &TruthTrack<'_>) -> f64 {
    let e2: Vec<f64> = states
        .iter()
        .filter_map(|s| {
            let (p, _) = track.at(s.header.meas_time_ns)?;
            Some((s.pos_m[0] - p[0]).powi(2) + (s.pos_m[1] - p[1]).powi(2))
        })
        .collect();
    assert!(!e2.is_empty());
    (e2.iter().sum::<f64>() / e2.len() as f64).sqrt()
}

#[test]
fn uwb_lost_for_10_s_coasts_degraded_with_growing_covariance_then_recovers() {
    let _lock = lock();
    // nlos-long without its random NLOS events, 30 s, no UWB from 10 s to 20 s.
    let base = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../config/scenarios/nlos-long.toml"
    );
    let mut sc: toml::Table = toml::from_str(&std::fs::read_to_string(base).unwrap()).unwrap();
    let sim = sc["sim"].as_table_mut().unwrap();
    sim.insert("duration_s".into(), 30.0.into());
    let uwb = sim["uwb"].as_table_mut().unwrap();
    uwb.remove("random_nlos");
    let mut dropout = toml::Table::new();
    dropout.insert("start_s".into(), 10.0.into());
    dropout.insert("duration_s".into(), 10.0.into());
    uwb.insert("dropouts".into(), vec![toml::Value::Table(dropout)].into());
    let scenario =
        std::env::temp_dir().join(format!("insuwb-test-outage-{}.toml", std::process::id()));
    std::fs::write(&scenario, toml::to_string(&sc).unwrap()).unwrap();
    let g = Group::with_config(
        "uwblost",
        &format!(
            "imu = \"sim\"\nuwb = \"sim\"\nscenario = \"{}\"\nseed = 2",
            scenario.display()
        ),
        "filter = \"iakf\"",
        "",
    );
    // The group takes up to 2 s to start and align its epoch: 28 s of wall
    // time cover the recovery window (22-24 s of data).
    let r = g.launch(28.0, &[]);
    let _ = std::fs::remove_file(&scenario);
    assert_eq!(f(&r, "restarts"), 0.0, "{r}");

    let (fused, truth, t0) = fused_and_truth(&g);
    let track = TruthTrack::new(&truth, 100_000_000);
    let at = |s: f64| t0 + (s * 1e9) as u64;
    let window = |a: f64, b: f64| -> Vec<&FusedState> {
        fused
            .iter()
            .filter(|s| (at(a)..at(b)).contains(&s.header.meas_time_ns))
            .collect()
    };
    // Nominal: the updates of the 6 s before the outage.
    let before: Vec<&FusedState> = window(4.0, 10.0)
        .into_iter()
        .filter(|s| !flagged(s, FusedState::FLAG_DEGRADED))
        .collect();
    // 60 at 10 Hz; half is a margin a busy machine keeps (a fix that
    // reaches the fusion stage too late is dropped by design).
    assert!(
        before.len() >= 30,
        "{} updates before the outage",
        before.len()
    );
    let nominal = rms(&before, &track);

    // The outage: INS-only states at about 10 Hz (on the fusion stage's
    // timer: a busy machine delays some), every one flagged degraded.
    let during = window(10.5, 19.9);
    assert!(
        during.len() >= 47,
        "{} outputs while UWB is silent (~94 at 10 Hz)",
        during.len()
    );
    let updates = during
        .iter()
        .filter(|s| !flagged(s, FusedState::FLAG_DEGRADED))
        .count();
    assert_eq!(updates, 0, "states not flagged degraded without UWB");
    // ... whose covariance grows.
    let var = |s: &FusedState| s.cov[0][0] + s.cov[1][1];
    let shrinks = during
        .windows(2)
        .filter(|w| var(w[1]) < 0.999 * var(w[0]))
        .count();
    assert_eq!(shrinks, 0, "the coasting covariance shrank");
    let (first, last) = (var(during[0]), var(during[during.len() - 1]));
    assert!(
        last > 3.0 * first,
        "position variance {first:.2e} -> {last:.2e} m^2 over the outage"
    );
    let coast_err = rms(&window(19.0, 19.9), &track);

    // Recovery: UWB back at 20 s; from 22 s on the error is under 2x nominal.
    let after: Vec<&FusedState> = window(22.0, 24.0)
        .into_iter()
        .filter(|s| !flagged(s, FusedState::FLAG_DEGRADED))
        .collect();
    assert!(
        after.len() >= 10,
        "{} updates after the outage (20 at 10 Hz)",
        after.len()
    );
    let recovered = rms(&after, &track);
    eprintln!(
        "UWB lost 10 s: nominal {nominal:.3} m, end of coasting {coast_err:.3} m, \
         22-24 s {recovered:.3} m; position variance {first:.2e} -> {last:.2e} m^2"
    );
    assert!(
        recovered < 2.0 * nominal,
        "after the outage {recovered:.3} m vs nominal {nominal:.3} m"
    );
}

#[test]
fn imu_frozen_flags_outputs_stale_and_no_valid_pose_rests_on_a_stale_ins() {
    let _lock = lock();
    // The watchdog's timeout at 1.5 s (the robot default is 0.5 s): the
    // freeze then lasts long enough for a dozen UWB fixes after the stale
    // timeout, whatever else the machine is doing.
    let g = Group::with_config(
        "imufrozen",
        "imu = \"sim\"\nuwb = \"sim\"\nscenario = \"nlos-long\"\nseed = 4",
        "filter = \"iakf\"\n",
        "[launch]\nheartbeat_timeout_ms = 1500\n",
    );
    // SIGSTOP: the IMU driver is alive but silent until the launcher's
    // heartbeat watchdog kills and restarts it.
    let r = g.launch(11.0, &["imu@4:STOP"]);
    assert!(f(&r, "restarts") >= 1.0, "{r}");
    let (fused, _, t0) = fused_and_truth(&g);
    let stale: Vec<&FusedState> = fused
        .iter()
        .filter(|s| flagged(s, FusedState::FLAG_STALE))
        .collect();
    assert!(!stale.is_empty(), "no output flagged stale");
    assert!(
        stale.iter().all(|s| !flagged(s, FusedState::FLAG_VALID)),
        "a stale output is flagged valid"
    );
    // The stage's stale timeout is 0.25 s, checked on a 50 ms tick.
    let limit_ns = 350_000_000;
    let bad: Vec<(u64, u64)> = fused
        .iter()
        .filter(|s| flagged(s, FusedState::FLAG_VALID) && !flagged(s, FusedState::FLAG_UWB_ONLY))
        .map(|s| {
            (
                s.header.seq,
                s.header.pub_time_ns.saturating_sub(s.ins_pub_time_ns),
            )
        })
        .filter(|(_, age)| *age > limit_ns)
        .collect();
    assert!(
        bad.is_empty(),
        "valid outputs on an old INS state (seq, age ns): {bad:?}"
    );
    // Meanwhile each UWB fix gave a valid pose on the fix alone (10 Hz
    // fixes over the freeze less the stale timeout: about 12).
    let uwb_only: Vec<&FusedState> = fused
        .iter()
        .filter(|s| flagged(s, FusedState::FLAG_UWB_ONLY))
        .collect();
    assert!(uwb_only.len() >= 3, "{} UWB-only poses", uwb_only.len());
    assert!(uwb_only
        .iter()
        .all(|s| flagged(s, FusedState::FLAG_VALID) && !flagged(s, FusedState::FLAG_STALE)));
    // Valid output resumes after the restart.
    let resumed = fused
        .iter()
        .filter(|s| {
            s.header.meas_time_ns > t0 + 6_000_000_000 && flagged(s, FusedState::FLAG_VALID)
        })
        .count();
    assert!(resumed >= 10, "{resumed} valid outputs after the restart");
    eprintln!(
        "IMU frozen at 4 s: {} stale outputs, {} UWB-only, {resumed} valid after the restart",
        stale.len(),
        uwb_only.len()
    );
}
