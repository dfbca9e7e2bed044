//! The radio's height state: with the height measured another way, a
//! radio that places the tag 0.5 m low (a range bias along the sine of
//! each anchor's elevation) no longer pulls the horizontal position, the
//! state finds the 0.5 m, and the height is the measured one; without the
//! state the two heights fight and the horizontal pays. Off by default,
//! refused for values that are not finite and positive, off after a
//! reset.

use insuwb_eskf::{tdoa_model, Eskf, EskfConfig, StateVector, IDX_POS};

use crate::common::{Rng, ANCHORS4, HOVER_FORCE, LEVEL};

const ANCHORS: [[f64; 3]; 4] = ANCHORS4;
const TRUTH: [f64; 3] = [1.5, 0.8, 1.0];
/// How far below the vehicle the radio places the tag, m.
const RADIO_LOW_M: f64 = 0.5;

/// 20 s at rest, closed loop from the truth: TDOA differences every 5 ms
/// from a tag `RADIO_LOW_M` below the vehicle (noise 0.05 m), the height
/// (sigma 0.02 m) every 20 ms. The horizontal and the height error at the
/// end, and the radio's height error the filter holds.
fn at_rest(radio_height: bool) -> (f64, f64, Option<(f64, f64)>) {
    let cfg = EskfConfig {
        kappa: 1e6,
        hard_gate_sigma: 1e7,
        tdoa_corr_time_s: 0.0,
        tdoa_sigma_m: 0.05,
        init_pos_sigma_m: 0.05,
        ..EskfConfig::default()
    };
    let mut f = Eskf::new(cfg).unwrap();
    if radio_height {
        assert!(f.enable_radio_height(1.0, 30.0));
    }
    let mut rng = Rng::new(11);
    let mut p = TRUTH;
    let radio = [TRUTH[0], TRUTH[1], TRUTH[2] - RADIO_LOW_M];
    let pairs = [(0, 1), (1, 2), (2, 3), (3, 0), (0, 2), (1, 3)];
    for step in 0..4000 {
        f.predict(0.005, LEVEL, HOVER_FORCE).unwrap();
        let (ia, ib) = pairs[step % pairs.len()];
        let z = tdoa_model(radio, LEVEL, [0.0; 3], ANCHORS[ia], ANCHORS[ib])
            .unwrap()
            .predicted_m
            + 0.05 * rng.normal();
        f.update_tdoa(p, LEVEL, [0.0; 3], ANCHORS[ia], ANCHORS[ib], z)
            .unwrap();
        if step % 4 == 0 {
            let mut h = StateVector::zeros();
            h[IDX_POS + 2] = -1.0;
            let height = TRUTH[2] + 0.02 * rng.normal();
            f.update_pseudo(&h, height - p[2], 0.02 * 0.02).unwrap();
        }
        let c = f.take_correction();
        for (k, d) in c.d_pos_m.iter().enumerate() {
            p[k] -= d;
        }
    }
    (
        (p[0] - TRUTH[0]).hypot(p[1] - TRUTH[1]),
        (p[2] - TRUTH[2]).abs(),
        f.radio_height_error(),
    )
}

#[test]
fn the_radio_height_state_keeps_a_low_radio_off_the_horizontal() {
    let (horizontal, height, radio) = at_rest(true);
    let (radio_m, radio_sigma) = radio.unwrap();
    assert!(horizontal < 0.02, "horizontal error {horizontal} m");
    assert!(height < 0.02, "height error {height} m");
    assert!(
        (radio_m + RADIO_LOW_M).abs() < 0.05,
        "radio height error {radio_m} m (sigma {radio_sigma})"
    );
    // Without it the measured height and the radio's pull against each
    // other, and the horizontal takes what is left.
    let (without, _, none) = at_rest(false);
    assert!(none.is_none());
    assert!(
        without > 0.03 && without > 5.0 * horizontal,
        "horizontal error {without} m without the state, {horizontal} m with it"
    );
}

#[test]
fn off_by_default_refused_when_not_positive_and_off_after_a_reset() {
    let mut f = Eskf::new(EskfConfig::default()).unwrap();
    assert!(f.radio_height_error().is_none());
    for (s, t) in [
        (0.0, 30.0),
        (0.3, 0.0),
        (f64::NAN, 30.0),
        (0.3, f64::INFINITY),
        (-0.1, 1.0),
    ] {
        assert!(!f.enable_radio_height(s, t), "{s} {t}");
        assert!(f.radio_height_error().is_none());
    }
    assert!(f.enable_radio_height(0.3, 30.0));
    let (b, sigma) = f.radio_height_error().unwrap();
    assert_eq!(b, 0.0);
    assert!((sigma - 0.3).abs() < 1e-12, "{sigma}");
    f.reset();
    assert!(f.radio_height_error().is_none());
}
