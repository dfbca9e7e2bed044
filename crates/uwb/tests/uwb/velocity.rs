//! Known-answer tests of the regression velocity.
#![allow(clippy::needless_range_loop)] // index loops mirror the formulas

use crate::common;

use common::Gauss;
use insuwb_uwb::velocity::{
    successive_correlation, VelocityConfig, VelocityError, VelocityEstimator,
};

const MS: u64 = 1_000_000;

fn diag(v: f64) -> [[f64; 3]; 3] {
    [[v, 0.0, 0.0], [0.0, v, 0.0], [0.0, 0.0, v]]
}

#[test]
fn constant_velocity_is_recovered_exactly_from_noise_free_fixes() {
    let mut est = VelocityEstimator::new(VelocityConfig::default()).unwrap();
    let v = [0.8, -0.35, 0.05];
    let p0 = [2.0, -1.0, 0.3];
    // Irregular spacing, as fixes from flagged groups and epochs give.
    let mut t_ns = 1_000 * MS;
    let mut last = None;
    for k in 0..25u64 {
        t_ns += [70, 100, 130, 95][(k % 4) as usize] * MS;
        let t = t_ns as f64 * 1e-9;
        let p = [p0[0] + v[0] * t, p0[1] + v[1] * t, p0[2] + v[2] * t];
        last = Some(est.push(t_ns, p, diag(0.01)).unwrap());
    }
    let e = last.unwrap();
    assert!(e.valid);
    assert_eq!(e.n_fixes, 10);
    for k in 0..3 {
        assert!((e.vel_mps[k] - v[k]).abs() < 1e-9, "{:?}", e.vel_mps);
    }
}

#[test]
fn covariance_matches_hand_computation() {
    let cfg = VelocityConfig {
        window_len: 3,
        min_fixes: 3,
        min_span_s: 0.2,
        max_span_s: 1.0,
    };
    let mut est = VelocityEstimator::new(cfg).unwrap();
    // t = 0, 0.1, 0.2 s: tbar = 0.1, S = 0.02, w = (-5, 0, 5).
    // Equal variance 0.01: var(v) = 0.01 / 0.02 = 0.5.
    est.push(0, [0.0; 3], diag(0.01)).unwrap();
    est.push(100 * MS, [0.1, 0.0, 0.0], diag(0.01)).unwrap();
    let e = est.push(200 * MS, [0.2, 0.0, 0.0], diag(0.01)).unwrap();
    assert!(e.valid);
    assert!((e.cov_mps2[0][0] - 0.5).abs() < 1e-9, "{:?}", e.cov_mps2);
    assert!((e.vel_mps[0] - 1.0).abs() < 1e-9);
    assert_eq!(e.mean_time_ns, 100 * MS);
    // Unequal, correlated covariances: Cov(v) = 25 P_1 + 0 P_2 + 25 P_3 for
    // the window t = 0.1, 0.2, 0.3.
    let p3 = [[0.04, 0.01, 0.0], [0.01, 0.02, 0.0], [0.0, 0.0, 0.0]];
    let e = est.push(300 * MS, [0.3, 0.0, 0.0], p3).unwrap();
    let expect = [
        [25.0 * (0.01 + 0.04), 25.0 * 0.01, 0.0],
        [25.0 * 0.01, 25.0 * (0.01 + 0.02), 0.0],
        [0.0, 0.0, 0.25],
    ];
    for (r, x) in e.cov_mps2.iter().zip(expect) {
        for (a, b) in r.iter().zip(x) {
            assert!((a - b).abs() < 1e-9, "{:?}", e.cov_mps2);
        }
    }
}

#[test]
fn validity_needs_enough_fixes_and_span() {
    let cfg = VelocityConfig {
        window_len: 10,
        min_fixes: 4,
        min_span_s: 0.3,
        max_span_s: 1.0,
    };
    let mut est = VelocityEstimator::new(cfg).unwrap();
    let mut valid = Vec::new();
    for k in 0..6u64 {
        valid.push(
            est.push(k * 100 * MS, [k as f64; 3], diag(0.01))
                .unwrap()
                .valid,
        );
    }
    // 4 fixes spanning 0.3 s first at the 4th fix.
    assert_eq!(valid, [false, false, false, true, true, true]);
    // 4 fixes within 0.2 s: enough fixes, too short a span.
    let mut est = VelocityEstimator::new(VelocityConfig::default()).unwrap();
    for k in 0..4u64 {
        let e = est.push(k * 60 * MS, [0.0; 3], diag(0.01)).unwrap();
        assert!(!e.valid && e.vel_mps == [0.0; 3]);
    }
}

#[test]
fn old_fixes_leave_the_window() {
    let mut est = VelocityEstimator::new(VelocityConfig::default()).unwrap();
    for k in 0..10u64 {
        est.push(k * 100 * MS, [0.0; 3], diag(0.01)).unwrap();
    }
    assert_eq!(est.len(), 10);
    // After a 2 s gap only the new fix remains (max_span_s = 1).
    let e = est.push(2_900 * MS, [5.0; 3], diag(0.01)).unwrap();
    assert_eq!((e.n_fixes, e.valid), (1, false));
    // A fix at the same time replaces the newest.
    let e = est.push(2_900 * MS, [6.0; 3], diag(0.01)).unwrap();
    assert_eq!(e.n_fixes, 1);
    assert_eq!(
        est.push(2_800 * MS, [0.0; 3], diag(0.01)),
        Err(VelocityError::TimeBackwards {
            time_ns: 2_800 * MS,
            last_ns: 2_900 * MS
        })
    );
    assert!(matches!(
        est.push(3_000 * MS, [f64::NAN, 0.0, 0.0], diag(0.01)),
        Err(VelocityError::NonFinite { what: "pos_m", .. })
    ));
}

#[test]
fn successive_estimates_are_correlated_as_documented() {
    // Hand values: N=2: c = (-1/2, 1/2), rho = -1/4 / (1/2) = -0.5;
    // N=3: 0; N=4: c = (-1.5, -0.5, 0.5, 1.5), 1.25 / 5 = 0.25; N=10: 57.75 / 82.5 = 0.7.
    for (n, rho) in [(2, -0.5), (3, 0.0), (4, 0.25), (10, 0.7)] {
        assert!((successive_correlation(n) - rho).abs() < 1e-12, "N={n}");
    }
    // Empirically: white fixes, window 10 sliding by one.
    let cfg = VelocityConfig {
        window_len: 10,
        min_fixes: 10,
        min_span_s: 0.0,
        max_span_s: 10.0,
    };
    let mut est = VelocityEstimator::new(cfg).unwrap();
    let mut g = Gauss::new(42);
    let mut vs = Vec::new();
    let mut var_sum = 0.0;
    for k in 0..20_000u64 {
        let e = est
            .push(k * 100 * MS, [0.1 * g.normal(), 0.0, 0.0], diag(0.01))
            .unwrap();
        if e.valid {
            vs.push(e.vel_mps[0]);
            var_sum += e.cov_mps2[0][0];
        }
    }
    let n = vs.len() as f64;
    let m = vs.iter().sum::<f64>() / n;
    let var = vs.iter().map(|v| (v - m).powi(2)).sum::<f64>() / n;
    let cov1 = vs.windows(2).map(|w| (w[0] - m) * (w[1] - m)).sum::<f64>() / (n - 1.0);
    assert!((cov1 / var - 0.7).abs() < 0.03, "rho {}", cov1 / var);
    // And the regression variance is right: 0.01 / (0.01 * 82.5).
    assert!(
        (var / (var_sum / n) - 1.0).abs() < 0.05,
        "var {var} predicted {}",
        var_sum / n
    );
    assert!((var_sum / n - 0.01 / 0.825).abs() < 1e-12);
}

#[test]
fn config_errors_name_the_key() {
    let e = VelocityConfig {
        window_len: 1,
        ..VelocityConfig::default()
    }
    .validate()
    .unwrap_err();
    assert_eq!(
        e.to_string(),
        "velocity.window_len must be in 2..=1024, got 1"
    );
    let e = VelocityConfig {
        min_span_s: 2.0,
        ..VelocityConfig::default()
    }
    .validate()
    .unwrap_err();
    assert_eq!(
        e.to_string(),
        "velocity.min_span_s must be finite, >= 0 and <= velocity.max_span_s, got 2"
    );
    let e = VelocityConfig {
        min_fixes: 11,
        ..VelocityConfig::default()
    }
    .validate()
    .unwrap_err();
    assert!(e.to_string().starts_with("velocity.min_fixes"));
}
