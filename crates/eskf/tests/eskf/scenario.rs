//! Closed-loop runs on a synthetic 3D scenario: an INS (the test's own
//! strapdown) corrected by the filter from individual TDOA measurements.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::common;

use common::*;
use insuwb_eskf::{Eskf, EskfConfig, LimitMode, TdoaOutcome, IDX_ATT, IDX_POS};
use nalgebra::Vector3;

const DT: f64 = 1e-3;

/// Simulated sensor errors.
#[derive(Clone, Copy)]
struct Sensors {
    accel_bias: Vector3<f64>,
    gyro_bias: Vector3<f64>,
    /// White noise densities (per sqrt(Hz)).
    accel_noise: f64,
    gyro_noise: f64,
    tdoa_sigma_m: f64,
    /// Probability of an NLOS error on a TDOA, and its size (uniform up to).
    nlos_prob: f64,
    nlos_max_m: f64,
}

impl Default for Sensors {
    fn default() -> Self {
        Self {
            accel_bias: Vector3::new(0.1, -0.08, 0.05),
            gyro_bias: Vector3::new(0.004, -0.003, 0.005),
            accel_noise: 0.03,
            gyro_noise: 1e-3,
            tdoa_sigma_m: 0.05,
            nlos_prob: 0.0,
            nlos_max_m: 0.0,
        }
    }
}

/// Result of a run: the final INS, truth, filter, and per-second samples.
struct Run {
    ins: Ins,
    truth: Ins,
    filter: Eskf,
    outcomes: Vec<TdoaOutcome>,
}

/// Runs `seconds` of the scenario. `moving`: the circle, else a hover at
/// the circle's start. The INS starts with `pos_err` and `yaw_err_rad`
/// and zero bias estimates; a TDOA of consecutive anchor pairs arrives
/// every 2 ms (50 Hz per pair) and each correction is applied at once.
#[allow(clippy::too_many_arguments)]
fn run(
    config: EskfConfig,
    sensors: Sensors,
    seconds: f64,
    moving: bool,
    pos_err: Vector3<f64>,
    yaw_err_rad: f64,
    seed: u64,
    mut each_second: impl FnMut(f64, &Eskf, &Ins, &Ins),
) -> Run {
    let circle = Circle::default();
    let truth_at = |t: f64| {
        let mut tr = circle.truth(if moving { t } else { 0.0 });
        if !moving {
            tr.v = Vector3::zeros();
        }
        tr.ba = sensors.accel_bias;
        tr.bg = sensors.gyro_bias;
        tr
    };
    let imu_at = |t: f64| {
        if moving {
            circle.imu(t, DT)
        } else {
            let r = rot(circle.quat(0.0));
            (
                r.transpose() * Vector3::new(0.0, 0.0, G_MPS2),
                Vector3::zeros(),
            )
        }
    };
    let anchors = anchors();
    let mut rng = Rng::new(seed);
    let mut filter = Eskf::new(config).unwrap();
    let t0 = truth_at(0.0);
    let mut ins = Ins {
        p: t0.p + pos_err,
        v: t0.v,
        q: qnorm(qmul(qexp(Vector3::new(0.0, 0.0, yaw_err_rad)), t0.q)),
        ba: Vector3::zeros(),
        bg: Vector3::zeros(),
    };
    let mut outcomes = Vec::new();
    let n = (seconds / DT).round() as usize;
    let mut pair = 0usize;
    for k in 0..n {
        let (f_b, w_b) = imu_at(k as f64 * DT);
        let a_m = f_b + sensors.accel_bias + rng.normal3(sensors.accel_noise / DT.sqrt());
        let w_m = w_b + sensors.gyro_bias + rng.normal3(sensors.gyro_noise / DT.sqrt());
        let s = ins.step(a_m, w_m, DT);
        filter.predict(DT, s.q_mid, s.f_nav.into()).unwrap();
        let t = (k + 1) as f64 * DT;
        if (k + 1) % 2 == 0 {
            let (a, b) = (anchors[pair % 8], anchors[(pair + 1) % 8]);
            pair += 1;
            let truth = truth_at(t);
            let mut z = true_tdoa(&truth, &a, &b) + rng.normal() * sensors.tdoa_sigma_m;
            if rng.uniform() < sensors.nlos_prob {
                z += rng.uniform() * sensors.nlos_max_m;
            }
            let rep = filter
                .update_tdoa(ins.p.into(), ins.q, LEVER_M, a, b, z)
                .unwrap();
            outcomes.push(rep.outcome);
            let c = filter.take_correction();
            ins.apply(&c);
        }
        if (k + 1) % 1000 == 0 {
            each_second(t, &filter, &ins, &truth_at(t));
        }
    }
    Run {
        ins,
        truth: truth_at(seconds),
        filter,
        outcomes,
    }
}

fn sim_config() -> EskfConfig {
    EskfConfig {
        // Matches the simulated white TDOA noise: no time correlation.
        tdoa_sigma_m: 0.05,
        tdoa_corr_time_s: 0.0,
        init_pos_sigma_m: 1.0,
        ..EskfConfig::default()
    }
}

fn yaw_err_deg(ins: &Ins, truth: &Ins) -> f64 {
    wrap(yaw_of(ins.q) - yaw_of(truth.q)).to_degrees()
}

#[test]
fn circling_converges_from_1m_and_30deg_yaw_errors() {
    let mut log = Vec::new();
    let r = run(
        sim_config(),
        Sensors::default(),
        20.0,
        true,
        Vector3::new(0.6, -0.8, 0.0),
        30f64.to_radians(),
        1,
        |t, f, ins, truth| {
            assert_spd(f, &format!("t = {t}"));
            log.push((t, (ins.p - truth.p).norm(), yaw_err_deg(ins, truth)));
        },
    );
    for (t, e, y) in &log {
        println!("t {t:5.1} s  pos err {e:.3} m  yaw err {y:+.2} deg");
    }
    let pos_err = (r.ins.p - r.truth.p).norm();
    let yaw_err = yaw_err_deg(&r.ins, &r.truth);
    assert!(pos_err < 0.05, "position error {pos_err} m after 20 s");
    assert!(yaw_err.abs() < 3.0, "yaw error {yaw_err} deg after 20 s");
    // The filter knows it: yaw sigma small, position sigma a few cm.
    let p = r.filter.covariance();
    assert!(p[(IDX_ATT + 2, IDX_ATT + 2)].sqrt() < 3f64.to_radians());
    assert!(p[(IDX_POS, IDX_POS)].sqrt() < 0.05);
    // The vertical accelerometer bias (0.05 m/s^2) was learnt (the
    // horizontal ones trade off against tilt and are not checked).
    let baz_err = (r.ins.ba.z - r.truth.ba.z).abs();
    assert!(baz_err < 0.02, "vertical accel bias error {baz_err}");
    assert!(!r.filter.needs_reset());
}

/// Hover (no horizontal acceleration) against circling, both with exact
/// initial states. In hover the yaw is unobservable: with a moderate prior
/// (0.5 rad) its variance stays at the prior. With the default 1.8 rad
/// prior the linearised filter extracts some spurious yaw information (the
/// lever-arm term and F are evaluated at estimates that move with a yaw
/// uncertainty far outside the small-angle range, a known EKF
/// inconsistency): sigma falls from 103 deg to about 35 deg, and stays far
/// above what horizontal acceleration gives (under 3 deg).
#[test]
fn yaw_is_observable_only_with_horizontal_acceleration() {
    // Datasheet-level white noise (BMI088: 1.7e-3 m/s^2/sqrt(Hz)): the
    // filter evaluates F at the measured specific force, so unrealistically
    // large low-frequency accelerometer noise would itself act as horizontal
    // "acceleration".
    let sensors = Sensors {
        accel_bias: Vector3::zeros(),
        gyro_bias: Vector3::zeros(),
        accel_noise: 2e-3,
        gyro_noise: 2.4e-4,
        ..Sensors::default()
    };
    let yaw_var = |r: &Run| r.filter.covariance()[(IDX_ATT + 2, IDX_ATT + 2)];
    let tilt_var = |r: &Run| r.filter.covariance()[(IDX_ATT, IDX_ATT)];

    let moderate = EskfConfig {
        init_yaw_sigma_rad: 0.5,
        ..sim_config()
    };
    let hover = run(
        moderate,
        sensors,
        20.0,
        false,
        Vector3::zeros(),
        0.0,
        3,
        |_, _, _, _| {},
    );
    println!(
        "hover, yaw prior 0.5 rad: yaw var {:.3e}, tilt var {:.3e}",
        yaw_var(&hover),
        tilt_var(&hover)
    );
    assert!(
        yaw_var(&hover) > 0.8 * 0.25,
        "yaw variance fell to {} without motion",
        yaw_var(&hover)
    );
    // Tilt is observable at rest (through gravity), up to the accelerometer bias.
    assert!(tilt_var(&hover) < 0.5 * 0.05f64.powi(2));

    let config = sim_config();
    let hover = run(
        config.clone(),
        sensors,
        20.0,
        false,
        Vector3::zeros(),
        0.0,
        3,
        |_, _, _, _| {},
    );
    let sig_hover = yaw_var(&hover).sqrt().to_degrees();
    let circ = run(
        config,
        sensors,
        20.0,
        true,
        Vector3::zeros(),
        0.0,
        3,
        |_, _, _, _| {},
    );
    let sig_circ = yaw_var(&circ).sqrt().to_degrees();
    println!("default yaw prior: hover yaw sigma {sig_hover:.1} deg, circling {sig_circ:.2} deg");
    assert!(sig_hover > 20.0, "hover yaw sigma {sig_hover} deg");
    assert!(sig_circ < 3.0, "circling yaw sigma {sig_circ} deg");
}

/// Converges, then feeds one TDOA with a +2 m NLOS error.
fn spike(config: EskfConfig) -> (insuwb_eskf::TdoaUpdateReport, f64, f64) {
    let sensors = Sensors::default();
    let r = run(
        config,
        sensors,
        5.0,
        true,
        Vector3::zeros(),
        0.0,
        5,
        |_, _, _, _| {},
    );
    let mut f = r.filter;
    let (a, b) = (anchors()[2], anchors()[3]);
    let z_true = true_tdoa(&r.truth, &a, &b);
    let mut clean = f.clone();
    let rep = f
        .update_tdoa(r.ins.p.into(), r.ins.q, LEVER_M, a, b, z_true + 2.0)
        .unwrap();
    let moved = Vector3::from(f.take_correction().d_pos_m).norm();
    // The same measurement with an innovation of exactly kappa sigma.
    let model = insuwb_eskf::tdoa_model(r.ins.p.into(), r.ins.q, LEVER_M, a, b).unwrap();
    let kappa = clean.config().kappa;
    let z_kappa = model.predicted_m + kappa * rep.innovation_var_m2.sqrt();
    clean
        .update_tdoa(r.ins.p.into(), r.ins.q, LEVER_M, a, b, z_kappa)
        .unwrap();
    let moved_kappa = Vector3::from(clean.take_correction().d_pos_m).norm();
    (rep, moved, moved_kappa)
}

#[test]
fn nlos_spike_is_weighted_down_to_kappa_sigma() {
    // Huber, gate wide enough that the spike is down-weighted, not rejected.
    let config = EskfConfig {
        hard_gate_sigma: 1000.0,
        ..sim_config()
    };
    let (rep, moved, moved_kappa) = spike(config);
    println!("{rep:?} moved {moved:.4} m, kappa-sigma measurement moves {moved_kappa:.4} m");
    assert_eq!(rep.outcome, TdoaOutcome::Downweighted);
    assert!(rep.innovation_m > 1.9);
    let s = rep.innovation_var_m2.sqrt();
    assert!((rep.lambda * rep.innovation_m).abs() <= 3.0 * s * (1.0 + 1e-12));
    assert!((rep.lambda - 3.0 * s / rep.innovation_m).abs() < 1e-12);
    // The state moves exactly as for a measurement kappa sigma off.
    assert!((moved - moved_kappa).abs() < 1e-9 * moved_kappa.max(1e-12));
    assert!(moved < 0.05, "a 2 m spike moved the position by {moved} m");

    // InflateR: the same bound on the gain-weighted innovation.
    let (rep, moved_i, _) = spike(EskfConfig {
        limit_mode: LimitMode::InflateR,
        hard_gate_sigma: 1000.0,
        ..sim_config()
    });
    assert_eq!(rep.outcome, TdoaOutcome::Downweighted);
    assert!(
        (rep.lambda * rep.innovation_m).abs() <= 3.0 * rep.innovation_var_m2.sqrt() * (1.0 + 1e-12)
    );
    assert!(
        moved_i < moved,
        "InflateR moved {moved_i} m (Huber {moved})"
    );

    // Default gate: a 2 m spike against a converged filter is rejected.
    let (rep, moved_d, _) = spike(sim_config());
    assert_eq!(rep.outcome, TdoaOutcome::Rejected);
    assert!(rep.rejected);
    assert_eq!(rep.lambda, 0.0);
    assert_eq!(moved_d, 0.0);
}

#[test]
fn covariance_stays_spd_and_finite_over_a_long_run_with_outliers() {
    let sensors = Sensors {
        nlos_prob: 0.15,
        nlos_max_m: 1.5,
        ..Sensors::default()
    };
    // Default configuration (correlation inflation on), 120 s.
    let mut checked = 0;
    let r = run(
        EskfConfig::default(),
        sensors,
        120.0,
        true,
        Vector3::new(0.3, 0.3, 0.0),
        10f64.to_radians(),
        11,
        |t, f, _, _| {
            assert_spd(f, &format!("t = {t}"));
            checked += 1;
        },
    );
    assert_eq!(checked, 120);
    let n_down = r
        .outcomes
        .iter()
        .filter(|o| **o == TdoaOutcome::Downweighted)
        .count();
    println!(
        "final pos err {:.3} m, yaw err {:.2} deg, stats {:?}",
        (r.ins.p - r.truth.p).norm(),
        yaw_err_deg(&r.ins, &r.truth),
        r.filter.stats()
    );
    assert!(n_down > 100, "outliers were not down-weighted ({n_down})");
    assert!((r.ins.p - r.truth.p).norm() < 0.1);
    assert!(!r.filter.needs_reset());
    let p = r.filter.covariance();
    for i in 0..15 {
        assert!(
            p[(i, i)] > 0.0 && p[(i, i)] < 10.0,
            "P[{i}][{i}] = {}",
            p[(i, i)]
        );
    }
}

/// The default yaw prior (1.8 rad) lets the closed loop recover far outside
/// the small-angle range: from 120 deg of yaw error. After 20 s the yaw error
/// is 2.6 deg at the median of seeds 1-30 and at most 12 deg (seed 1); the
/// position is within 3 cm on all of them. Checked on seeds 1-12: the
/// median below 6 deg, every seed below 15 deg and 5 cm.
#[test]
fn circling_converges_from_a_120deg_yaw_error() {
    let mut yaw_errs = Vec::new();
    for seed in 1..=12 {
        let r = run(
            sim_config(),
            Sensors::default(),
            20.0,
            true,
            Vector3::new(0.6, -0.8, 0.0),
            120f64.to_radians(),
            seed,
            |_, _, _, _| {},
        );
        let pos_err = (r.ins.p - r.truth.p).norm();
        let yaw_err = yaw_err_deg(&r.ins, &r.truth);
        println!("seed {seed}: pos err {pos_err:.3} m, yaw err {yaw_err:+.2} deg");
        assert!(pos_err < 0.05, "seed {seed}: position error {pos_err}");
        assert!(yaw_err.abs() < 15.0, "seed {seed}: yaw error {yaw_err}");
        assert!(!r.filter.needs_reset());
        yaw_errs.push(yaw_err.abs());
    }
    yaw_errs.sort_by(f64::total_cmp);
    assert!(yaw_errs[6] < 6.0, "median yaw error: {yaw_errs:?}");
}
