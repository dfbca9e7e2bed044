//! The filter's Jacobians against finite differences of the nonlinear models.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::common;

use common::*;
use insuwb_eskf::{
    process_noise, tdoa_model, transition_matrix, Covariance, Eskf, EskfConfig, IDX_ATT, IDX_POS,
    IDX_VEL, N_STATES,
};
use nalgebra::{Matrix3, Vector3};

/// The TDOA of the true state implied by an error `(δp, δθ)` at the INS state:
/// `p_t = p - δp`, `q_t = Exp(-δθ) ⊗ q`.
fn tdoa_of_error(
    p: [f64; 3],
    q: Quat,
    lever: [f64; 3],
    a: [f64; 3],
    b: [f64; 3],
    dp: Vector3<f64>,
    dth: Vector3<f64>,
) -> f64 {
    let q_t = qnorm(qmul(qexp(-dth), q));
    let p_ant = Vector3::from(p) - dp + rot(q_t) * Vector3::from(lever);
    dist(&p_ant, &b) - dist(&p_ant, &a)
}

#[test]
fn tdoa_h_row_matches_finite_differences_with_lever_arm() {
    let p = [0.7, -1.1, 1.4];
    let q = qexp(Vector3::new(0.3, -0.2, 2.1));
    // An exaggerated lever arm so the attitude columns are large.
    let lever = [0.25, -0.15, 0.4];
    let (a, b) = ([-4.0, -4.0, 0.2], [4.0, 4.0, 3.1]);
    let m = tdoa_model(p, q, lever, a, b).unwrap();
    let z0 = tdoa_of_error(p, q, lever, a, b, Vector3::zeros(), Vector3::zeros());
    assert!((m.predicted_m - z0).abs() < 1e-12);
    let eps = 1e-6;
    let mut max_att: f64 = 0.0;
    for i in 0..3 {
        let e = Vector3::ith(i, eps);
        let dpos = (tdoa_of_error(p, q, lever, a, b, e, Vector3::zeros())
            - tdoa_of_error(p, q, lever, a, b, -e, Vector3::zeros()))
            / (2.0 * eps);
        let datt = (tdoa_of_error(p, q, lever, a, b, Vector3::zeros(), e)
            - tdoa_of_error(p, q, lever, a, b, Vector3::zeros(), -e))
            / (2.0 * eps);
        assert!(
            (m.h[IDX_POS + i] - dpos).abs() < 1e-6,
            "dp{i}: {} vs {dpos}",
            m.h[IDX_POS + i]
        );
        assert!(
            (m.h[IDX_ATT + i] - datt).abs() < 1e-6,
            "dθ{i}: {} vs {datt}",
            m.h[IDX_ATT + i]
        );
        max_att = max_att.max(datt.abs());
    }
    // The attitude columns are not trivially zero, and nothing else is set.
    assert!(
        max_att > 0.05,
        "lever-arm term too small to test: {max_att}"
    );
    for j in (IDX_VEL..IDX_VEL + 3).chain(9..15) {
        assert_eq!(m.h[j], 0.0);
    }
}

/// A nominal run with rotation on all axes and varying specific force.
fn imu_at(t: f64) -> (Vector3<f64>, Vector3<f64>) {
    (
        Vector3::new(
            1.0 + 0.5 * (3.0 * t).sin(),
            -0.7 * (2.0 * t).cos(),
            G_MPS2 + 0.3 * (5.0 * t).sin(),
        ),
        Vector3::new(0.4 * (2.0 * t).sin(), 0.6, -0.5 * (1.5 * t).cos()),
    )
}

fn perturbed(ins: &Ins, dx: &[f64; 15]) -> Ins {
    let v3 = |i: usize| Vector3::new(dx[i], dx[i + 1], dx[i + 2]);
    Ins {
        p: ins.p - v3(0),
        v: ins.v - v3(3),
        q: qnorm(qmul(qexp(-v3(6)), ins.q)),
        ba: ins.ba + v3(9),
        bg: ins.bg + v3(12),
    }
}

fn propagate(mut ins: Ins, n: usize, dt: f64) -> Ins {
    for k in 0..n {
        let (a, w) = imu_at((k as f64 + 0.5) * dt);
        ins.step(a, w, dt);
    }
    ins
}

/// Nonlinear error propagation (two strapdowns from a perturbed start)
/// against the product of the filter's `Φ_k = I + F_k dt`.
///
/// Tolerance: the strapdown integrates position trapezoidally and velocity
/// at mid-step, while `Φ` is first order, so the two linearisations differ
/// by O(dt^2 |F|^2) per step, O(T dt |F|^2) over the run: with T = 0.5 s,
/// dt = 1e-4 s and |F| ~ g = 9.81 that is about 5e-3 at most (2.4e-4
/// measured; the bound used is 2e-3); central differences with eps = 1e-6 add O(eps^2). A wrong
/// sign or a transposed rotation anywhere in F changes entries by O(1)
/// (e.g. g T^2 / 2 = 1.2 for δp <- δθ), which the negative control shows.
#[test]
fn transition_matches_nonlinear_error_propagation() {
    let dt = 1e-4;
    let n = 5000;
    let ins0 = Ins {
        p: Vector3::new(1.0, 2.0, 1.5),
        v: Vector3::new(0.5, -0.3, 0.1),
        q: qexp(Vector3::new(0.2, -0.1, 0.7)),
        ba: Vector3::new(0.05, -0.02, 0.1),
        bg: Vector3::new(0.01, 0.02, -0.01),
    };
    let mut phi = Covariance::identity();
    let mut phi_wrong = Covariance::identity();
    let mut ins = ins0;
    for k in 0..n {
        let (a, w) = imu_at((k as f64 + 0.5) * dt);
        let s = ins.step(a, w, dt);
        let step = transition_matrix(dt, s.q_mid, s.f_nav.into()).unwrap();
        phi = step * phi;
        // Negative control: the velocity <- attitude block with the wrong sign.
        let mut wrong = step;
        let blk = wrong.fixed_view::<3, 3>(IDX_VEL, IDX_ATT).into_owned();
        wrong
            .fixed_view_mut::<3, 3>(IDX_VEL, IDX_ATT)
            .copy_from(&(-blk));
        phi_wrong = wrong * phi_wrong;
    }
    let ins_n = ins;
    let eps = 1e-6;
    let mut num = Covariance::zeros();
    for j in 0..N_STATES {
        let mut dx = [0.0; 15];
        dx[j] = eps;
        let plus = propagate(perturbed(&ins0, &dx), n, dt);
        dx[j] = -eps;
        let minus = propagate(perturbed(&ins0, &dx), n, dt);
        let ep = ins_n.error_against(&plus);
        let em = ins_n.error_against(&minus);
        for i in 0..N_STATES {
            num[(i, j)] = (ep[i] - em[i]) / (2.0 * eps);
        }
    }
    let err = (phi - num).abs().max();
    let err_wrong = (phi_wrong - num).abs().max();
    println!("max |Φ - Φ_num| = {err:.3e}, wrong-sign control {err_wrong:.3e}");
    assert!(
        err < 2e-3,
        "Φ differs from the finite-difference linearisation by {err}"
    );
    assert!(
        err_wrong > 0.5,
        "negative control not detected: {err_wrong}"
    );
    // The blocks that carry the physics are exercised (not trivially I).
    assert!(num.fixed_view::<3, 3>(IDX_POS, IDX_ATT).abs().max() > 0.5);
    assert!(num.fixed_view::<3, 3>(IDX_ATT, 12).abs().max() > 0.3);
}

#[test]
fn predict_equals_dense_phi_p_phi_t_plus_q() {
    let config = EskfConfig::default();
    let mut f = Eskf::new(config.clone()).unwrap();
    let mut rng = Rng::new(7);
    let a = Covariance::from_fn(|_, _| rng.normal());
    let p0 = a * a.transpose() * 0.1 + Covariance::identity() * 0.01;
    f.reset_with_covariance(&p0).unwrap();
    let q = qexp(Vector3::new(0.1, -0.3, 1.2));
    let fnav = [0.9, -0.4, 9.7];
    let dt = 0.02;
    f.predict(dt, q, fnav).unwrap();
    let phi = transition_matrix(dt, q, fnav).unwrap();
    let expect =
        phi * p0 * phi.transpose() + Covariance::from_diagonal(&process_noise(&config, dt));
    let err = (f.covariance() - expect).abs().max();
    assert!(
        err < 1e-12 * expect.abs().max(),
        "sparse predict differs by {err}"
    );
    // Known-answer spot checks of Φ: δv <- δθ is -[f x] dt, δv <- δb_a is C dt.
    let fx = Matrix3::new(0.0, -9.7, -0.4, 9.7, 0.0, -0.9, 0.4, 0.9, 0.0);
    assert!(
        (phi.fixed_view::<3, 3>(IDX_VEL, IDX_ATT) + fx * dt)
            .abs()
            .max()
            < 1e-15
    );
    assert!(
        (phi.fixed_view::<3, 3>(IDX_VEL, 9) - rot(q) * dt)
            .abs()
            .max()
            < 1e-15
    );
    assert!(
        (phi.fixed_view::<3, 3>(IDX_ATT, 12) - rot(q) * dt)
            .abs()
            .max()
            < 1e-15
    );
    assert!(
        (phi.fixed_view::<3, 3>(IDX_POS, IDX_VEL) - Matrix3::identity() * dt)
            .abs()
            .max()
            < 1e-15
    );
    assert_eq!(
        phi.fixed_view::<3, 3>(IDX_ATT, IDX_ATT),
        Matrix3::identity()
    );
}

/// The covariance reset Jacobian used by `take_correction`, `I - [â/2 x]`,
/// against finite differences of the exact error after the INS applies
/// `q <- Exp(-â) ⊗ q`: `δθ⁺ = Log(Exp(-â) Exp(δθ))`, at `δθ = â`. The exact
/// Jacobian differs from the first-order one by O(|â|^2 / 12) = 1e-4 here;
/// the opposite sign would differ by |â| = 0.037.
#[test]
fn reset_jacobian_matches_finite_differences() {
    let a_hat = Vector3::new(0.02, -0.01, 0.03);
    let post = |d: Vector3<f64>| qlog(qmul(qexp(-a_hat), qexp(d)));
    let eps = 1e-6;
    let mut num = Matrix3::zeros();
    for j in 0..3 {
        let e = Vector3::ith(j, eps);
        num.set_column(j, &((post(a_hat + e) - post(a_hat - e)) / (2.0 * eps)));
    }
    let g = Matrix3::identity() - insuwb_eskf::skew(&(a_hat * 0.5));
    let err = (g - num).abs().max();
    assert!(err < 3e-4, "reset Jacobian off by {err}");
    let wrong = Matrix3::identity() + insuwb_eskf::skew(&(a_hat * 0.5));
    assert!((wrong - num).abs().max() > 1e-2);
}
