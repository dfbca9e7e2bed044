//! Velocity aiding on simulated data with a known answer: the
//! `ground-outage` scenario's wheeled robot, whose wheel odometry reads 5 %
//! fast (`[sim.odometry] scale = 1.05`), with a 10 s UWB outage from 30 s.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use insuwb_eval::run::{evaluate_at, Epochs};
use insuwb_eval::scenario::{dataset_with, monte_carlo_with, ScenarioOptions};
use insuwb_fusion::config::build_estimator;
use insuwb_fusion::runner::{self, merged_aided, Runner, Ties};
use insuwb_fusion::scenario::ScenarioFile;
use insuwb_msg::{BodyVelocity, FilterKind};
use insuwb_nav::vehicle::VehicleKind;

use crate::vehicle::lateral_rms;

const ODOMETRY: u32 = BodyVelocity::SOURCE_ODOMETRY;

/// The filters that use the odometry, loose and tight, find its 5 % scale
/// error from a prior of 1 +- 0.1, on each seed.
#[test]
fn the_odometry_scale_error_is_estimated_by_the_filters_that_use_it() {
    let sc = ScenarioFile::load("ground-outage").unwrap();
    assert_eq!(sc.sim.odometry.as_ref().unwrap().scale, 1.05);
    for kind in [FilterKind::Kf, FilterKind::Iakf, FilterKind::IakfTdoa] {
        let mut sum = 0.0;
        for seed in 1..=5u64 {
            let sim = insuwb_sim::simulate(&sc.sim, seed).unwrap();
            let cfg = sc.fusion_for_seed(seed).unwrap();
            let mut r = Runner::new(&cfg, build_estimator(kind, &cfg).unwrap()).unwrap();
            for input in merged_aided(
                &sim.imu,
                &sim.tdoa,
                &sim.velocity,
                &sim.height,
                Ties::ImuFirst,
            ) {
                r.push(input);
            }
            let [flow, (scale, sigma)] = r.engine_mut().estimator().aiding_scales().unwrap();
            eprintln!("{kind:?} seed {seed}: odometry scale {scale:.4} +- {sigma:.4}");
            assert_eq!(flow, (1.0, 0.1), "no flow: its prior");
            assert!(
                (scale - 1.05).abs() < 0.015,
                "{kind:?} seed {seed}: {scale} +- {sigma}"
            );
            assert!(sigma < 0.01, "{kind:?} seed {seed}: {scale} +- {sigma}");
            sum += scale;
        }
        let mean = sum / 5.0;
        assert!((mean - 1.05).abs() < 0.006, "{kind:?}: mean {mean}");
    }
}

/// With the free vehicle model (no ground constraint), the odometry's
/// lateral zero keeps the loose filters' lateral velocity near zero through
/// the loop's turns and the outage, where UWB alone lets it wander.
#[test]
fn odometry_keeps_the_lateral_velocity_near_zero_through_the_turns() {
    let sc = ScenarioFile::load("ground-outage").unwrap();
    let seed = 2;
    let sim = insuwb_sim::simulate(&sc.sim, seed).unwrap();
    let mut cfg = sc.fusion_for_seed(seed).unwrap();
    cfg.vehicle = VehicleKind::Free;
    // After the start's rest and ramp.
    let from_ns = 5_000_000_000;
    for kind in [FilterKind::Kf, FilterKind::Iakf] {
        let run = |velocity: &[BodyVelocity]| {
            let est = build_estimator(kind, &cfg).unwrap();
            let out = runner::run_aided(&sim.imu, &sim.tdoa, velocity, &[], &cfg, est).unwrap();
            lateral_rms(&out.fused, from_ns)
        };
        let (alone, aided) = (run(&[]), run(&sim.velocity));
        eprintln!(
            "{kind:?}: lateral velocity RMS {alone:.4} m/s UWB alone, {aided:.4} with odometry"
        );
        assert!(aided < 0.02, "{kind:?}: {aided:.4} m/s with odometry");
        assert!(
            aided < 0.5 * alone,
            "{kind:?}: {aided:.4} against {alone:.4} m/s"
        );
    }
}

/// Through the 10 s outage (the truth's times from 30 s to 40 s, the
/// filters' coasting states there), the odometry halves the horizontal
/// error of the loose filters and of the tight one.
#[test]
fn odometry_halves_the_error_through_the_outage() {
    let sc = ScenarioFile::load("ground-outage").unwrap();
    let filters = [FilterKind::Kf, FilterKind::Iakf, FilterKind::IakfTdoa];
    let rows = |sources: Vec<u32>| {
        let opts = ScenarioOptions {
            velocity_sources: sources,
            window_s: Some([30.0, 40.0]),
        };
        monte_carlo_with(&sc, &filters, 10, 1, &opts).unwrap()
    };
    let (alone, aided) = (rows(Vec::new()), rows(vec![ODOMETRY]));
    for kind in filters {
        let get = |rows: &[(String, insuwb_eval::metrics::Metrics)]| {
            let m = &rows.iter().find(|(k, _)| k == kind.name()).unwrap().1;
            // Each run's epochs: 10 s of 100 Hz truth.
            assert!(m.epochs >= 10 * 1000, "{m:?}");
            m.rmse_horizontal
        };
        let (a, b) = (get(&alone), get(&aided));
        eprintln!("{kind:?}: horizontal RMSE through the outage {a:.4} m UWB alone, {b:.4} m with odometry");
        assert!(b < 0.55 * a, "{kind:?}: {b:.4} m against {a:.4} m");
    }
}

/// The scenario's velocities reach the filters only when asked for; a
/// source the scenario does not simulate and a bad window are refused.
#[test]
fn scenario_options_choose_the_velocities_and_the_window() {
    let sc = ScenarioFile::load("ground-outage").unwrap();
    let all = insuwb_eval::scenario::dataset(&sc, 3).unwrap();
    assert_eq!(all.velocity.len(), 3000);
    let none = dataset_with(&sc, 3, &ScenarioOptions::default()).unwrap();
    assert!(none.velocity.is_empty() && none.segment.is_none());
    let opts = ScenarioOptions {
        velocity_sources: vec![ODOMETRY],
        window_s: Some([30.0, 40.5]),
    };
    let odo = dataset_with(&sc, 3, &opts).unwrap();
    assert_eq!(odo.velocity, all.velocity);
    assert_eq!(odo.segment, Some((30_000_000_000, 40_500_000_000)));
    let flow = ScenarioOptions {
        velocity_sources: vec![BodyVelocity::SOURCE_FLOW],
        ..ScenarioOptions::default()
    };
    let e = dataset_with(&sc, 3, &flow).unwrap_err().to_string();
    assert!(e.contains("[sim.flow]"), "{e}");
    let paper = ScenarioFile::load("paper-3.4").unwrap();
    let e = dataset_with(&paper, 1, &opts).unwrap_err().to_string();
    assert!(e.contains("[sim.odometry]"), "{e}");
    for w in [[40.0, 30.0], [-1.0, 3.0], [0.0, f64::NAN]] {
        let bad = ScenarioOptions {
            window_s: Some(w),
            ..ScenarioOptions::default()
        };
        assert!(dataset_with(&sc, 3, &bad).is_err(), "{w:?}");
    }
    // Inside the outage only the filters' coasting states and the INS are
    // there to evaluate; the fix epochs are none.
    let data = dataset_with(&sc, 3, &opts).unwrap();
    let cfg = sc.fusion_for_seed(3).unwrap();
    let rep = evaluate_at(&data, &cfg, &[FilterKind::Kf], Epochs::Truth).unwrap();
    let kf = rep.solutions.iter().find(|s| s.key == "kf").unwrap();
    assert!(kf.metrics.epochs > 1000, "{:?}", kf.metrics);
}
