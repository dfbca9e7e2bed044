//! Each anchor's part of the TDOA error as a Gauss-Markov state: the
//! block-wise propagation and update equal a dense augmented Kalman filter,
//! a biased anchor is found when the position is known, anchors beyond the
//! slots take the least recently heard one's, ranges leave the states alone.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use insuwb_eskf::{process_noise, tdoa_model, transition_matrix, Eskf, EskfConfig, N_STATES};
use nalgebra::{DMatrix, DVector};

use crate::common::Rng;

const LEVEL: [f64; 4] = [1.0, 0.0, 0.0, 0.0];
const HOVER_FORCE: [f64; 3] = [0.0, 0.0, 9.81];
const ANCHORS: [[f64; 3]; 4] = [
    [-4.0, -4.0, 0.2],
    [4.0, -4.0, 3.0],
    [4.0, 4.0, 0.2],
    [-4.0, 4.0, 3.0],
];

/// A configuration whose TDOA update is the plain Kalman update: no robust
/// weighting, no correlation inflation, no yaw hold.
fn plain(sigma_b: f64, tau_b: f64) -> EskfConfig {
    EskfConfig {
        kappa: 1e6,
        hard_gate_sigma: 1e7,
        tdoa_corr_time_s: 0.0,
        tdoa_anchor_sigma_m: sigma_b,
        tdoa_anchor_corr_time_s: tau_b,
        ..EskfConfig::default()
    }
}

/// Steps of a moving, slightly tilted INS through the TDOA updates of
/// every anchor pair, with the same arithmetic done densely on the 15 + 4
/// states: the filter's error state and 15 x 15 covariance match to 1e-9.
#[test]
fn block_filter_equals_the_dense_augmented_filter() {
    let (sigma_b, tau_b) = (0.12, 0.4);
    let cfg = plain(sigma_b, tau_b);
    let mut f = Eskf::new(cfg.clone()).unwrap();
    let n = N_STATES + ANCHORS.len();
    let mut x = DVector::<f64>::zeros(n);
    let mut p = DMatrix::<f64>::zeros(n, n);
    let p0 = Eskf::initial_covariance(&cfg);
    for i in 0..N_STATES {
        for j in 0..N_STATES {
            p[(i, j)] = p0[(i, j)];
        }
    }
    let mut seen = [false; 4];
    let mut slot_of = [usize::MAX; 4];
    let mut next_slot = 0;
    let mut rng = Rng::new(11);
    let quat = [0.999, 0.02, -0.03, 0.01];
    let qn = quat.iter().map(|v| v * v).sum::<f64>().sqrt();
    let quat = quat.map(|v| v / qn);
    let force = [0.3, -0.2, 9.8];
    let dt = 0.002;
    let mut pos = [0.3, -0.4, 1.2];
    for step in 0..60 {
        f.predict(dt, quat, force).unwrap();
        // Dense: Φ on the core, exp(-dt/τ) on the biases.
        let phi_core = transition_matrix(dt, quat, force).unwrap();
        let mut phi = DMatrix::<f64>::identity(n, n);
        for i in 0..N_STATES {
            for j in 0..N_STATES {
                phi[(i, j)] = phi_core[(i, j)];
            }
        }
        let a = (-dt / tau_b).exp();
        for i in N_STATES..n {
            phi[(i, i)] = a;
        }
        x = &phi * &x;
        p = &phi * &p * phi.transpose();
        let q = process_noise(&cfg, dt);
        for i in 0..N_STATES {
            p[(i, i)] += q[i];
        }
        for (k, s) in seen.iter().enumerate() {
            if *s {
                let i = N_STATES + slot_of[k];
                p[(i, i)] += (1.0 - a * a) * sigma_b * sigma_b;
            }
        }
        // One difference per step, cycling over the pairs.
        let (ia, ib) = [(0, 1), (1, 2), (2, 3), (3, 0), (0, 2), (1, 3)][step % 6];
        for k in [ib, ia] {
            if !seen[k] {
                seen[k] = true;
                slot_of[k] = next_slot;
                let i = N_STATES + next_slot;
                p[(i, i)] = sigma_b * sigma_b;
                next_slot += 1;
            }
        }
        pos[0] += 0.01;
        let m = tdoa_model(pos, quat, [0.0; 3], ANCHORS[ia], ANCHORS[ib]).unwrap();
        let z = m.predicted_m + 0.2 * rng.normal();
        f.update_tdoa(pos, quat, [0.0; 3], ANCHORS[ia], ANCHORS[ib], z)
            .unwrap();
        let mut h = DVector::<f64>::zeros(n);
        for i in 0..N_STATES {
            h[i] = m.h[i];
        }
        h[N_STATES + slot_of[ib]] += 1.0;
        h[N_STATES + slot_of[ia]] -= 1.0;
        let v = z - m.predicted_m - h.dot(&x);
        let c = &p * &h;
        let s = h.dot(&c) + cfg.tdoa_sigma_m * cfg.tdoa_sigma_m;
        let k = &c / s;
        x += &k * v;
        p = &p - &k * c.transpose() - &c * k.transpose() + &k * k.transpose() * s;
        for i in 0..N_STATES {
            assert!(
                (f.state()[i] - x[i]).abs() < 1e-9,
                "step {step}: x[{i}] {} vs {}",
                f.state()[i],
                x[i]
            );
            for j in 0..N_STATES {
                assert!(
                    (f.covariance()[(i, j)] - p[(i, j)]).abs() < 1e-9,
                    "step {step}: P[{i}][{j}] {} vs {}",
                    f.covariance()[(i, j)],
                    p[(i, j)]
                );
            }
        }
        // The bias states themselves, in the order the anchors were seen.
        for (slot, (_, b, sd)) in f.anchor_errors().enumerate() {
            let i = N_STATES + slot;
            assert!((b - x[i]).abs() < 1e-9, "step {step}: bias {slot}");
            assert!(
                (sd - p[(i, i)].sqrt()).abs() < 1e-9,
                "step {step}: sigma {slot}"
            );
        }
    }
    // A 3D position update moves the biases through their covariance with
    // the position.
    let fix = [pos[0] + 0.1, pos[1] - 0.05, pos[2]];
    let cov = [[0.04, 0.01, 0.0], [0.01, 0.05, 0.0], [0.0, 0.0, 0.09]];
    f.update_position(pos, quat, [0.0; 3], fix, cov).unwrap();
    let mut hm = DMatrix::<f64>::zeros(3, n);
    for i in 0..3 {
        hm[(i, i)] = -1.0;
    }
    let r = DMatrix::from_fn(3, 3, |i, j| cov[i][j]);
    let v = DVector::from_fn(3, |i, _| fix[i] - pos[i]) - &hm * &x;
    let s = &hm * &p * hm.transpose() + &r;
    let k = &p * hm.transpose() * s.clone().try_inverse().unwrap();
    x += &k * v;
    let i_kh = DMatrix::<f64>::identity(n, n) - &k * &hm;
    p = &i_kh * &p * i_kh.transpose() + &k * r * k.transpose();
    for i in 0..N_STATES {
        assert!((f.state()[i] - x[i]).abs() < 1e-9, "fix: x[{i}]");
        for j in 0..N_STATES {
            assert!(
                (f.covariance()[(i, j)] - p[(i, j)]).abs() < 1e-9,
                "fix: P[{i}][{j}]"
            );
        }
    }
    for (slot, (_, b, sd)) in f.anchor_errors().enumerate() {
        let i = N_STATES + slot;
        assert!((b - x[i]).abs() < 1e-9, "fix: bias {slot}");
        assert!((sd - p[(i, i)].sqrt()).abs() < 1e-9, "fix: sigma {slot}");
    }
}

/// At rest with the position known to 1 cm, anchor 2 reading 0.3 m long
/// on every difference: its bias, relative to the others', is found, and
/// the position is not pulled off by it.
#[test]
fn a_biased_anchor_is_found_when_the_position_is_known() {
    let truth = [0.5, 0.8, 1.0];
    let cfg = EskfConfig {
        init_pos_sigma_m: 0.01,
        ..plain(0.5, 1e4)
    };
    let mut f = Eskf::new(cfg).unwrap();
    let mut rng = Rng::new(3);
    for step in 0..2000 {
        f.predict(0.005, LEVEL, HOVER_FORCE).unwrap();
        let (ia, ib) = [(0, 1), (1, 2), (2, 3), (3, 0), (0, 2), (1, 3)][step % 6];
        let mut z = tdoa_model(truth, LEVEL, [0.0; 3], ANCHORS[ia], ANCHORS[ib])
            .unwrap()
            .predicted_m
            + 0.1 * rng.normal();
        if ib == 2 {
            z += 0.3;
        }
        if ia == 2 {
            z -= 0.3;
        }
        f.update_tdoa(truth, LEVEL, [0.0; 3], ANCHORS[ia], ANCHORS[ib], z)
            .unwrap();
        let c = f.take_correction();
        assert!(
            c.d_pos_m.iter().all(|v| v.abs() < 0.05),
            "step {step}: {c:?}"
        );
    }
    let states: Vec<_> = f.anchor_errors().collect();
    assert_eq!(states.len(), 4);
    let bias_of = |a: [f64; 3]| states.iter().find(|s| s.0 == a).unwrap().1;
    let others = [0, 1, 3].map(|k| bias_of(ANCHORS[k]));
    let rel = bias_of(ANCHORS[2]) - others.iter().sum::<f64>() / 3.0;
    assert!((rel - 0.3).abs() < 0.03, "anchor 2 relative bias {rel}");
}

/// Off by default; two-way ranges take no state; a reset forgets the
/// anchors.
#[test]
fn off_by_default_not_for_ranges_and_cleared_by_a_reset() {
    let mut f = Eskf::new(EskfConfig::default()).unwrap();
    let z = tdoa_model([0.0, 0.0, 1.0], LEVEL, [0.0; 3], ANCHORS[0], ANCHORS[1])
        .unwrap()
        .predicted_m;
    f.update_tdoa([0.0, 0.0, 1.0], LEVEL, [0.0; 3], ANCHORS[0], ANCHORS[1], z)
        .unwrap();
    assert_eq!(f.anchor_errors().count(), 0);
    let mut g = Eskf::new(plain(0.1, 1.0)).unwrap();
    g.update_tdoa([0.0, 0.0, 1.0], LEVEL, [0.0; 3], ANCHORS[0], ANCHORS[1], z)
        .unwrap();
    assert_eq!(g.anchor_errors().count(), 2);
    g.update_range([0.0, 0.0, 1.0], LEVEL, [0.0; 3], ANCHORS[2], 6.0)
        .unwrap();
    assert_eq!(g.anchor_errors().count(), 2);
    g.reset();
    assert_eq!(g.anchor_errors().count(), 0);
}

/// More anchors than slots: the one heard least recently gives its slot
/// to the newcomer, which starts from the prior.
#[test]
fn a_new_anchor_takes_the_least_recently_heard_slot() {
    let mut f = Eskf::new(plain(0.2, 1e4)).unwrap();
    let p = [0.0, 0.0, 1.0];
    let ring: Vec<[f64; 3]> = (0..10)
        .map(|k| {
            let a = f64::from(k) * 0.6;
            [
                6.0 * a.cos(),
                6.0 * a.sin(),
                if k % 2 == 0 { 0.2 } else { 3.0 },
            ]
        })
        .collect();
    // Anchors 0..8 fill the slots, anchor 0 biased so that its state moves.
    for step in 0..400 {
        f.predict(0.005, LEVEL, HOVER_FORCE).unwrap();
        let (ia, ib) = (step % 8, (step + 1) % 8);
        let mut z = tdoa_model(p, LEVEL, [0.0; 3], ring[ia], ring[ib])
            .unwrap()
            .predicted_m;
        z += if ib == 0 {
            0.3
        } else if ia == 0 {
            -0.3
        } else {
            0.0
        };
        f.update_tdoa(p, LEVEL, [0.0; 3], ring[ia], ring[ib], z)
            .unwrap();
        let _ = f.take_correction();
    }
    assert_eq!(f.anchor_errors().count(), 8);
    // Anchors 1..8 heard again, later than anchor 0.
    for k in 1..8 {
        f.predict(0.005, LEVEL, HOVER_FORCE).unwrap();
        let z = tdoa_model(p, LEVEL, [0.0; 3], ring[k], ring[k % 7 + 1])
            .unwrap()
            .predicted_m;
        f.update_tdoa(p, LEVEL, [0.0; 3], ring[k], ring[k % 7 + 1], z)
            .unwrap();
    }
    // Anchor 8 arrives: it takes anchor 0's slot, at the prior.
    f.predict(0.005, LEVEL, HOVER_FORCE).unwrap();
    let z = tdoa_model(p, LEVEL, [0.0; 3], ring[1], ring[8])
        .unwrap()
        .predicted_m;
    f.update_tdoa(p, LEVEL, [0.0; 3], ring[1], ring[8], z)
        .unwrap();
    let states: Vec<_> = f.anchor_errors().collect();
    assert_eq!(states.len(), 8);
    assert!(
        !states.iter().any(|s| s.0 == ring[0]),
        "anchor 0 kept its slot"
    );
    let new = states.iter().find(|s| s.0 == ring[8]).unwrap();
    assert!(
        new.2 > 0.15 && new.2 <= 0.2 + 1e-12,
        "newcomer sigma {}",
        new.2
    );
}
