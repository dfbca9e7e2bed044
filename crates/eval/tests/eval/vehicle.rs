//! The vehicle models on simulated data with a known answer: the simulated
//! robot of the paper's scenario drives with its body x axis along the path
//! (no lateral and no vertical body velocity), through turns.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use insuwb_fusion::runner;
use insuwb_fusion::scenario::ScenarioFile;
use insuwb_msg::{FilterKind, FusedState};
use insuwb_nav::vehicle::VehicleKind;

/// RMS of the fused velocity across the fused heading (m/s), over the
/// states after `from_s`, and the RMS horizontal position error against
/// the simulated truth at the fused states' times (m).
pub(crate) fn lateral_rms(fused: &[FusedState], from_ns: u64) -> f64 {
    let lat: Vec<f64> = fused
        .iter()
        .filter(|s| s.header.meas_time_ns >= from_ns)
        .map(|s| {
            let (sn, cs) = s.yaw_rad.sin_cos();
            -sn * s.vel_mps[0] + cs * s.vel_mps[1]
        })
        .collect();
    assert!(lat.len() > 100, "{} fused states", lat.len());
    (lat.iter().map(|v| v * v).sum::<f64>() / lat.len() as f64).sqrt()
}

/// The ground constraint keeps the lateral velocity at zero through the
/// turns of the path, for the tight filter (pseudo-measurements and the
/// INS's projection) and a loose one (the projection), where the free
/// model lets it wander.
#[test]
fn the_ground_constraint_keeps_lateral_velocity_at_zero_through_turns() {
    let sc = ScenarioFile::load("paper-3.4").unwrap();
    let seed = 3;
    let sim = insuwb_sim::simulate(&sc.sim, seed).unwrap();
    // The path turns through most of the run after the 1 s ramp.
    let from_ns = 2_000_000_000;
    for kind in [FilterKind::IakfTdoa, FilterKind::Kf] {
        let mut rms = Vec::new();
        for vehicle in [VehicleKind::Free, VehicleKind::Ground] {
            let mut cfg = sc.fusion_for_seed(seed).unwrap();
            cfg.vehicle = vehicle;
            // A firm constraint, to see it hold (the default is softer).
            cfg.ground.lateral_sigma_mps = 0.05;
            let out = runner::run(&sim.imu, &sim.tdoa, &cfg, kind).unwrap();
            rms.push(lateral_rms(&out.fused, from_ns));
        }
        let (free, ground) = (rms[0], rms[1]);
        eprintln!("{kind:?}: lateral velocity RMS free {free:.4} m/s, ground {ground:.4} m/s");
        assert!(
            ground < 0.02,
            "{kind:?}: lateral velocity {ground:.4} m/s RMS with the ground model (free {free:.4})"
        );
        assert!(
            ground < 0.6 * free,
            "{kind:?}: ground {ground:.4} m/s against free {free:.4} m/s"
        );
    }
}

/// A multirotor's INS, given the IMU of a hovering vehicle whose
/// accelerometer's horizontal channels carry a 2 m/s^2 vibration bias,
/// stays where the free model runs away (the channels are drag, not
/// acceleration).
#[test]
fn the_multirotor_model_ignores_horizontal_vibration_bias() {
    use insuwb_fusion::ins_engine::InsEngine;
    use insuwb_msg::{Header, ImuSample};
    let mut drift = Vec::new();
    for vehicle in [VehicleKind::Free, VehicleKind::Multirotor] {
        let mut cfg = insuwb_fusion::config::FusionConfig {
            vehicle,
            ..Default::default()
        };
        cfg.ins.init.pos_m = [0.0, 0.0, 1.0];
        let mut ins = InsEngine::new(cfg.ins_engine_config()).unwrap();
        let mut last = None;
        for i in 1..=10_000u64 {
            let s = ImuSample {
                header: Header::new(i, i * 1_000_000),
                accel_mps2: [2.0, -1.5, cfg.ins.ins.gravity_mps2],
                gyro_rps: [0.0; 3],
            };
            if let Some(n) = ins.on_imu(&s) {
                last = Some(n);
            }
        }
        let n = last.unwrap();
        drift.push(n.pos_m[0].hypot(n.pos_m[1]));
    }
    // 10 s at 2.5 m/s^2: 125 m free; the multirotor does not move.
    assert!(drift[0] > 100.0, "free: {:.1} m", drift[0]);
    assert!(drift[1] < 1e-6, "multirotor: {:.3e} m", drift[1]);
}
