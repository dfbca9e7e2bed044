//! The multirotor model's velocity damping beyond the INS's drag: the
//! error state's mean takes up the difference, so that the INS corrected by
//! it decays at the model's damping.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use insuwb_eskf::{Eskf, EskfConfig, MultirotorDynamics, IDX_VEL};

use crate::common::{HOVER_FORCE, LEVEL};

fn filter(damping: f64, ins_drag: f64) -> Eskf {
    let mut f = Eskf::new(EskfConfig::default()).unwrap();
    assert!(f.set_multirotor(Some(MultirotorDynamics {
        drag_per_s: damping,
        ins_drag_per_s: ins_drag,
        model_noise_mps2_per_rthz: 1.0,
    })));
    f
}

/// Level at 1 m/s east for 0.1 s with damping 1.5 /s over the INS's 0.5 /s:
/// the velocity error grows as `(1 - exp(-1.5 t)) / 1.5 * (1.5 - 0.5) * v`
/// (0.0929 m/s), east only.
#[test]
fn the_error_state_takes_up_the_extra_damping() {
    let mut f = filter(1.5, 0.5);
    let v = [1.0, 0.0, 0.0];
    for _ in 0..100 {
        f.predict_moving(0.001, LEVEL, HOVER_FORCE, v).unwrap();
    }
    let x = f.state();
    let expected = (1.0 - (-1.5f64 * 0.1).exp()) / 1.5;
    assert!(
        (x[IDX_VEL] - expected).abs() < 1e-3,
        "{} vs {expected}",
        x[IDX_VEL]
    );
    assert!(x[IDX_VEL + 1].abs() < 1e-12 && x[IDX_VEL + 2].abs() < 1e-12);
    // Handed over as a correction: the INS's velocity less it is the
    // damped one.
    let c = f.take_correction();
    assert!((c.d_vel_mps[0] - expected).abs() < 1e-3);
}

/// The same damping as the INS's drag, or a vertical velocity (the damping
/// acts in body x/y), leaves the error state at zero.
#[test]
fn no_extra_damping_no_mean() {
    let mut f = filter(0.5, 0.5);
    let mut g = filter(1.5, 0.5);
    for _ in 0..100 {
        f.predict_moving(0.001, LEVEL, HOVER_FORCE, [1.0, -0.5, 0.0])
            .unwrap();
        g.predict_moving(0.001, LEVEL, HOVER_FORCE, [0.0, 0.0, 1.0])
            .unwrap();
    }
    assert!(f.state().iter().all(|v| *v == 0.0));
    assert!(g.state().iter().all(|v| v.abs() < 1e-12));
}

/// A negative or non-finite INS drag is refused.
#[test]
fn a_bad_ins_drag_is_refused() {
    let mut f = Eskf::new(EskfConfig::default()).unwrap();
    for bad in [-0.1, f64::NAN] {
        assert!(!f.set_multirotor(Some(MultirotorDynamics {
            drag_per_s: 1.0,
            ins_drag_per_s: bad,
            model_noise_mps2_per_rthz: 1.0,
        })));
    }
    assert!(f.multirotor().is_none());
}
