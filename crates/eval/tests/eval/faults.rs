//! Sensor faults the estimator must survive, in process (the same engine the
//! fusion stage runs): a filter that diverges is found by the windowed NIS
//! monitor and reset from UWB, with the reset flagged.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use insuwb_eval::metrics::TruthTrack;
use insuwb_fusion::runner::{self, RunOutput};
use insuwb_fusion::scenario::ScenarioFile;
use insuwb_msg::{FilterDiag, FilterKind, FusedState};

struct Run {
    out: RunOutput,
    /// Horizontal error of each fused state, with its time (s).
    err: Vec<(f64, f64)>,
}

/// nlos-long with an overconfident KF: an accelerometer bias of 0.02 g that
/// the model is told cannot exist (tiny process noise, tiny initial
/// uncertainty). Its gain collapses and the INS drifts away from UWB:
/// a divergence, not an outlier.
fn diverging_kf(monitor_window: usize) -> Run {
    let mut sc = ScenarioFile::load("nlos-long").unwrap();
    sc.sim.imu.accel_bias_g = 0.02;
    sc.sim.uwb.random_nlos = None;
    let mut cfg = sc.fusion_for_seed(1).unwrap();
    cfg.model.q_vel_m2_per_s3 = 1e-14;
    cfg.model.q_theta_rad2_per_s = 1e-16;
    if let Some(b) = cfg.model.bias_random_walk.as_mut() {
        b.accel_var_m2_per_s4 = 1e-20;
        b.gyro_var_rad2_per_s2 = 1e-20;
    }
    for (i, v) in cfg.setup.p0_diag.iter_mut().enumerate() {
        if i >= 2 {
            *v = 1e-12;
        }
    }
    cfg.engine.monitor.window = monitor_window;
    let sim = insuwb_sim::simulate(&sc.sim, 1).unwrap();
    let out = runner::run(&sim.imu, &sim.tdoa, &cfg, FilterKind::Kf).unwrap();
    let track = TruthTrack::new(&sim.truth, 100_000_000);
    let err = out
        .fused
        .iter()
        .filter_map(|f| {
            let (p, _) = track.at(f.header.meas_time_ns)?;
            let e = (f.pos_m[0] - p[0]).hypot(f.pos_m[1] - p[1]);
            Some((f.header.meas_time_ns as f64 * 1e-9, e))
        })
        .collect();
    Run { out, err }
}

fn max_err_after(r: &Run, t0: f64) -> f64 {
    r.err
        .iter()
        .filter(|(t, _)| *t >= t0)
        .map(|(_, e)| *e)
        .fold(0.0, f64::max)
}

fn count(flags: impl Iterator<Item = u32>, flag: u32) -> usize {
    flags.filter(|f| f & flag != 0).count()
}

#[test]
fn a_diverging_filter_is_reset_from_uwb_and_flagged() {
    // Without the monitor the filter runs away: metres off by the end.
    let off = diverging_kf(0);
    let off_err = max_err_after(&off, 30.0);
    assert_eq!(off.out.fusion.nis_divergences, 0);
    assert!(
        off_err > 3.0,
        "without the monitor: max error {off_err:.2} m"
    );

    let on = diverging_kf(30);
    let c = on.out.fusion;
    assert!(c.nis_divergences >= 1, "{c:?}");
    assert!(c.resets >= 2, "first fix plus at least one reset: {c:?}");
    let flagged_resets = count(
        on.out.fused.iter().map(|f| f.header.flags),
        FusedState::FLAG_RESET,
    );
    assert!(flagged_resets >= 1, "no fused state flagged RESET");
    let flagged_div = count(
        on.out.diag.iter().map(|d| d.header.flags),
        FilterDiag::FLAG_DIVERGENCE,
    );
    assert!(flagged_div >= 1, "no diagnostic flagged DIVERGENCE");
    // The update the monitor fired on is published as not valid, the reset
    // as valid, and the first diagnostic after a reset says so.
    let invalid = on
        .out
        .fused
        .iter()
        .filter(|f| f.header.flags & FusedState::FLAG_VALID == 0)
        .count();
    assert!(invalid >= 1, "no fused state flagged not valid");
    assert!(on
        .out
        .fused
        .iter()
        .filter(|f| f.header.flags & FusedState::FLAG_RESET != 0)
        .all(|f| f.header.flags & FusedState::FLAG_VALID != 0));
    let flagged_reset_diag = count(
        on.out.diag.iter().map(|d| d.header.flags),
        FilterDiag::FLAG_RESET,
    );
    assert!(
        (1..=flagged_resets).contains(&flagged_reset_diag),
        "one RESET diagnostic per reset followed by an update: {flagged_reset_diag} of {flagged_resets}"
    );
    let on_err = max_err_after(&on, 30.0);
    assert!(
        on_err < 0.5 * off_err,
        "with the monitor: max error {on_err:.2} m vs {off_err:.2} m without"
    );
    println!(
        "divergence: {} resets by the NIS monitor; max error after 30 s {on_err:.2} m (without: {off_err:.2} m)",
        c.nis_divergences
    );
}

/// The monitor stays quiet on a healthy run with NLOS bursts (the scenario
/// the demo runs): bursts are shorter than its window.
#[test]
fn nlos_bursts_do_not_trip_the_divergence_monitor() {
    let sc = ScenarioFile::load("nlos-long").unwrap();
    for seed in 1..=5 {
        let cfg = sc.fusion_for_seed(seed).unwrap();
        let sim = insuwb_sim::simulate(&sc.sim, seed).unwrap();
        for kind in [
            FilterKind::Kf,
            FilterKind::Shaf,
            FilterKind::Stf,
            FilterKind::Iakf,
        ] {
            let out = runner::run(&sim.imu, &sim.tdoa, &cfg, kind).unwrap();
            assert_eq!(
                out.fusion.nis_divergences, 0,
                "{kind:?} seed {seed}: {:?}",
                out.fusion
            );
        }
    }
}
