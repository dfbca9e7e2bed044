//! Each anchor's part of the TDOA error as a Gauss-Markov state: the
//! block-wise propagation and update equal a dense augmented Kalman filter
//! (with and without the running mean removed), a biased anchor is found
//! when the position is known and is not taken up once the running mean is
//! removed, a slot's prior is stationary, anchors beyond the slots take the
//! least recently heard one's, ranges leave the states alone.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use insuwb_eskf::{process_noise, tdoa_model, transition_matrix, Eskf, EskfConfig, N_STATES};
use nalgebra::{DMatrix, DVector};

use crate::common::{Rng, ANCHORS4, HOVER_FORCE, LEVEL};

const ANCHORS: [[f64; 3]; 4] = ANCHORS4;

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

/// The same with each anchor's running mean over `hp` removed.
fn high_passed(sigma_b: f64, tau_b: f64, hp: f64) -> EskfConfig {
    EskfConfig {
        tdoa_anchor_highpass_s: hp,
        ..plain(sigma_b, tau_b)
    }
}

#[test]
fn block_filter_equals_the_dense_augmented_filter() {
    block_equals_dense(0.0);
}

#[test]
fn block_filter_equals_the_dense_augmented_filter_with_the_mean_removed() {
    block_equals_dense(1.5);
}

/// Steps of a moving, slightly tilted INS through the TDOA updates of
/// every anchor pair, with the same arithmetic done densely on the 15 + 4
/// states (15 + 8 with each anchor's running mean over `hp`: per anchor
/// `(x, m)` moved by the matrix exponential of `[[-1/τ, 0], [1/T, -1/T]]`,
/// the noise that keeps its stationary covariance, the row `+1` on `x` and
/// `-1` on `m`): the filter's error state and 15 x 15 covariance, and each
/// anchor's `x - m` and its sigma, match to 1e-9.
fn block_equals_dense(hp: f64) {
    let (sigma_b, tau_b) = (0.12, 0.4);
    let cfg = high_passed(sigma_b, tau_b, hp);
    let mut f = Eskf::new(cfg.clone()).unwrap();
    let na = ANCHORS.len();
    let n = N_STATES + 2 * na;
    // Index of anchor slot k's x and m.
    let xi = |k: usize| N_STATES + k;
    let mi = |k: usize| N_STATES + na + k;
    // The stationary covariance of (x, m).
    let v = sigma_b * sigma_b;
    let c = if hp > 0.0 {
        v * tau_b / (tau_b + hp)
    } else {
        0.0
    };
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
        // Each anchor's (x, m) by the exponential of its 2 x 2 dynamics.
        let m2 = if hp > 0.0 {
            (DMatrix::from_row_slice(2, 2, &[-1.0 / tau_b, 0.0, 1.0 / hp, -1.0 / hp]) * dt).exp()
        } else {
            DMatrix::from_row_slice(2, 2, &[(-dt / tau_b).exp(), 0.0, 0.0, 0.0])
        };
        for k in 0..na {
            for (r, ir) in [xi(k), mi(k)].into_iter().enumerate() {
                for (col, ic) in [xi(k), mi(k)].into_iter().enumerate() {
                    phi[(ir, ic)] = m2[(r, col)];
                }
            }
        }
        x = &phi * &x;
        p = &phi * &p * phi.transpose();
        let q = process_noise(&cfg, dt);
        for i in 0..N_STATES {
            p[(i, i)] += q[i];
        }
        let st = DMatrix::from_row_slice(2, 2, &[v, c, c, c]);
        let q2 = &st - &m2 * &st * m2.transpose();
        for (k, s) in seen.iter().enumerate() {
            if *s {
                let idx = [xi(slot_of[k]), mi(slot_of[k])];
                for (r, ir) in idx.into_iter().enumerate() {
                    for (col, ic) in idx.into_iter().enumerate() {
                        p[(ir, ic)] += q2[(r, col)];
                    }
                }
            }
        }
        // One difference per step, cycling over the pairs.
        let (ia, ib) = [(0, 1), (1, 2), (2, 3), (3, 0), (0, 2), (1, 3)][step % 6];
        for k in [ib, ia] {
            if !seen[k] {
                seen[k] = true;
                slot_of[k] = next_slot;
                let (i, j) = (xi(next_slot), mi(next_slot));
                p[(i, i)] = v;
                p[(i, j)] = c;
                p[(j, i)] = c;
                p[(j, j)] = c;
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
        h[xi(slot_of[ib])] += 1.0;
        h[mi(slot_of[ib])] -= 1.0;
        h[xi(slot_of[ia])] -= 1.0;
        h[mi(slot_of[ia])] += 1.0;
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
        // The anchors' errors themselves, in the order they were seen.
        for (slot, (_, b, sd)) in f.anchor_errors().enumerate() {
            let (e, var) = beta(&x, &p, xi(slot), mi(slot));
            assert!((b - e).abs() < 1e-9, "step {step}: bias {slot}");
            assert!((sd - var.sqrt()).abs() < 1e-9, "step {step}: sigma {slot}");
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
        let (e, var) = beta(&x, &p, xi(slot), mi(slot));
        assert!((b - e).abs() < 1e-9, "fix: bias {slot}");
        assert!((sd - var.sqrt()).abs() < 1e-9, "fix: sigma {slot}");
    }
}

/// `x - m` of a dense state and its variance.
fn beta(x: &DVector<f64>, p: &DMatrix<f64>, i: usize, j: usize) -> (f64, f64) {
    (x[i] - x[j], p[(i, i)] - 2.0 * p[(i, j)] + p[(j, j)])
}

/// Without updates a slot stays at its prior, the stationary sigma of `x -
/// m`: `σ sqrt(T / (τ + T))` with the running mean removed, `σ` without.
#[test]
fn a_slot_s_prior_is_stationary() {
    for (hp, want) in [(0.0, 0.2), (0.6, 0.2 * (0.6f64 / 0.8).sqrt())] {
        let mut f = Eskf::new(high_passed(0.2, 0.2, hp)).unwrap();
        let p = [0.0, 0.0, 1.0];
        let z = tdoa_model(p, LEVEL, [0.0; 3], ANCHORS[0], ANCHORS[1])
            .unwrap()
            .predicted_m;
        // A measurement far less certain than the prior takes the slots and
        // leaves them where they start.
        let mut g = Eskf::new(EskfConfig {
            tdoa_sigma_m: 1e4,
            ..high_passed(0.2, 0.2, hp)
        })
        .unwrap();
        g.update_tdoa(p, LEVEL, [0.0; 3], ANCHORS[0], ANCHORS[1], z)
            .unwrap();
        for _ in 0..2000 {
            g.predict(0.005, LEVEL, HOVER_FORCE).unwrap();
        }
        for (_, _, sd) in g.anchor_errors() {
            assert!(
                (sd - want).abs() < 1e-6,
                "hp {hp}: sigma {sd} against {want}"
            );
        }
        assert_eq!(g.anchor_errors().count(), 2);
        f.update_tdoa(p, LEVEL, [0.0; 3], ANCHORS[0], ANCHORS[1], z)
            .unwrap();
        for (_, _, sd) in f.anchor_errors() {
            assert!(sd < want, "hp {hp}: an update lowers it");
        }
    }
}

/// At rest with the position known to 1 cm, anchor 2 reading 0.3 m long
/// on every difference for 10 s under `cfg` (with `init_pos_sigma_m` set
/// to 0.01): anchor 2's error estimate relative to the others' mean, and
/// the largest position correction of any step.
fn biased_anchor_at_rest(cfg: EskfConfig) -> (f64, f64) {
    let truth = [0.5, 0.8, 1.0];
    let cfg = EskfConfig {
        init_pos_sigma_m: 0.01,
        ..cfg
    };
    let mut f = Eskf::new(cfg).unwrap();
    let mut rng = Rng::new(3);
    let mut largest: f64 = 0.0;
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
        largest = c.d_pos_m.iter().fold(largest, |m, v| m.max(v.abs()));
    }
    let states: Vec<_> = f.anchor_errors().collect();
    assert_eq!(states.len(), 4);
    let bias_of = |a: [f64; 3]| states.iter().find(|s| s.0 == a).unwrap().1;
    let others = [0, 1, 3].map(|k| bias_of(ANCHORS[k]));
    (
        bias_of(ANCHORS[2]) - others.iter().sum::<f64>() / 3.0,
        largest,
    )
}

/// The plain state finds anchor 2's offset, relative to the others', and
/// the position is not pulled off by it.
#[test]
fn a_biased_anchor_is_found_when_the_position_is_known() {
    let (rel, largest) = biased_anchor_at_rest(plain(0.5, 1e4));
    assert!((rel - 0.3).abs() < 0.03, "anchor 2 relative bias {rel}");
    assert!(largest < 0.05, "position correction {largest}");
}

/// The state without a lasting part does not take the offset up (its
/// running mean over 0.5 s follows it): its estimate stays near zero.
#[test]
fn a_lasting_offset_is_not_taken_up_once_the_mean_is_removed() {
    let (rel, _) = biased_anchor_at_rest(high_passed(0.5, 1e4, 0.5));
    assert!(rel.abs() < 0.1, "anchor 2 relative error state {rel}");
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
