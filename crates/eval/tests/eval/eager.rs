//! Eager prediction (the fusion stage in real time) gives the lazy engine's
//! result exactly, in the order samples reach the fusion stage in real time:
//! a UWB fix before the INS state of its own epoch (one hop against two),
//! so the fix waits for that state, and the engine predicts through the
//! states before the fix at once.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use insuwb_fusion::config::{build_estimator, FusionConfig};
use insuwb_fusion::runner::{self, merged, Runner, Ties};
use insuwb_fusion::scenario::ScenarioFile;
use insuwb_msg::{FilterKind, FusedState};

/// The lockstep runner fed in real-time arrival order: at equal times the
/// TDOA of an epoch (and the fix it completes) before the IMU sample.
fn real_time_order(
    cfg: &FusionConfig,
    kind: FilterKind,
    sim: &insuwb_sim::SimOutput,
    warm: bool,
) -> Vec<FusedState> {
    let est = build_estimator(kind, cfg).unwrap();
    let mut r = Runner::new(cfg, est).unwrap();
    for input in merged(&sim.imu, &sim.tdoa, Ties::UwbFirst) {
        if warm {
            // The fusion stage's warm-up, here before every sample.
            r.engine_mut().warm_up();
        }
        r.push(input);
    }
    r.finish().fused
}

#[test]
fn eager_prediction_in_real_time_order_equals_the_lazy_engine() {
    let sc = ScenarioFile::load("nlos-long").unwrap();
    let sim = insuwb_sim::simulate(&sc.sim, 1).unwrap();
    for kind in [FilterKind::Iakf, FilterKind::Kf] {
        let lazy_cfg = sc.fusion_for_seed(1).unwrap();
        assert!(lazy_cfg.engine.eager_lag_s.is_none());
        let lazy = runner::run(&sim.imu, &sim.tdoa, &lazy_cfg, kind)
            .unwrap()
            .fused;
        assert!(lazy.len() > 500, "{kind:?}: {} fused states", lazy.len());
        // The stage's default lag (5 ms), the former one, and none.
        for lag in [0.005, 0.02, 0.0] {
            let mut eager_cfg = lazy_cfg.clone();
            eager_cfg.engine.eager_lag_s = Some(lag);
            let eager = real_time_order(&eager_cfg, kind, &sim, false);
            assert_eq!(lazy.len(), eager.len(), "{kind:?} lag {lag}");
            for (a, b) in lazy.iter().zip(&eager) {
                let at = a.header.meas_time_ns;
                assert_eq!(at, b.header.meas_time_ns, "{kind:?} lag {lag}");
                assert_eq!(a.pos_m, b.pos_m, "{kind:?} lag {lag} at {at}");
                assert_eq!(a.vel_mps, b.vel_mps, "{kind:?} lag {lag} at {at}");
                assert_eq!(a.cov, b.cov, "{kind:?} lag {lag} at {at}");
            }
        }
        // Warming up the update on a scratch copy changes nothing, with
        // position and velocity updates and with position-only ones (the
        // warm-up runs the size the last update had).
        for use_velocity in [true, false] {
            let mut lazy_cfg = lazy_cfg.clone();
            lazy_cfg.loose.use_velocity = use_velocity;
            let lazy = runner::run(&sim.imu, &sim.tdoa, &lazy_cfg, kind)
                .unwrap()
                .fused;
            let mut warm_cfg = lazy_cfg.clone();
            warm_cfg.engine.eager_lag_s = Some(0.005);
            let warm = real_time_order(&warm_cfg, kind, &sim, true);
            let what = format!("{kind:?} warm, velocity {use_velocity}");
            assert!(lazy.len() > 500, "{what}: {} fused states", lazy.len());
            assert_eq!(lazy.len(), warm.len(), "{what}");
            for (a, b) in lazy.iter().zip(&warm) {
                let at = a.header.meas_time_ns;
                assert_eq!(a.pos_m, b.pos_m, "{what} at {at}");
                assert_eq!(a.vel_mps, b.vel_mps, "{what} at {at}");
                assert_eq!(a.cov, b.cov, "{what} at {at}");
            }
        }
    }
}
