//! Covariance prediction `P' = F P F^T + Q` exploiting the sparsity of the
//! paper's `F` (at most three non-zeros per row), without heap allocation,
//! and the dense reference [`predict_dense`] it is tested and benchmarked against.

use crate::model::{Mat14, Transition14, Vec14, N_STATES};

/// `F M` for a sparse `F` (column by column on the column-major storage).
#[must_use]
pub fn f_mul(t: &Transition14, m: &Mat14) -> Mat14 {
    let mut out = Mat14::zeros();
    for (o, c) in out.data.0.iter_mut().zip(m.data.0.iter()) {
        *o = t.rows(|k| c[k]);
    }
    out
}

/// `M F^T` for a sparse `F` (as `(F M^T)^T`).
#[must_use]
pub fn mul_ft(m: &Mat14, t: &Transition14) -> Mat14 {
    f_mul(t, &m.transpose()).transpose()
}

/// `F P F^T` (no noise), exactly symmetric; `p` must be symmetric.
///
/// Computed as `F (F P)^T`, which equals `F P F^T` for a symmetric `P`, so
/// both products run down the contiguous columns.
#[must_use]
pub fn propagate_sparse(p: &Mat14, t: &Transition14) -> Mat14 {
    let out = f_mul(t, &f_mul(t, p).transpose());
    (out + out.transpose()) * 0.5
}

/// `P' = F P F^T + diag(q_diag)` with the sparse `F`; the result is exactly symmetric.
#[must_use]
pub fn predict_sparse(p: &Mat14, t: &Transition14, q_diag: &Vec14) -> Mat14 {
    let mut out = propagate_sparse(p, t);
    for i in 0..N_STATES {
        out[(i, i)] += q_diag[i];
    }
    out
}

/// Dense reference: `P' = F P F^T + Q` with full 14 x 14 products.
#[must_use]
pub fn predict_dense(p: &Mat14, f: &Mat14, q: &Mat14) -> Mat14 {
    f * p * f.transpose() + q
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{dense, ModelConfig, ModelForm, PaperModel};
    use crate::testutil::Rng;

    fn random_spd(rng: &mut Rng) -> Mat14 {
        let a = Mat14::from_fn(|_, _| rng.normal());
        a * a.transpose() + Mat14::identity() * 0.1
    }

    #[test]
    fn sparse_predict_equals_dense_on_random_p() {
        let mut rng = Rng::new(42);
        for form in [ModelForm::Paper, ModelForm::Physics] {
            let mut cfg = ModelConfig {
                form,
                ..ModelConfig::default()
            };
            cfg.ar_accel_e.m = [-0.5, 0.2, -0.1];
            cfg.ar_accel_n.m = [0.3, -0.1, 0.05];
            cfg.ar_gyro.m = [-0.2, 0.1, 0.02];
            cfg.q_pos_m2_per_s = 0.3;
            cfg.q_vel_m2_per_s3 = 0.2;
            cfg.q_theta_rad2_per_s = 0.1;
            let model = PaperModel::new(cfg).unwrap();
            for _ in 0..50 {
                let p = random_spd(&mut rng);
                let dt = 0.01 + 0.1 * rng.uniform();
                let t = model.transition(dt, 3.0 * rng.normal(), 3.0 * rng.normal());
                let s = predict_sparse(&p, &t, &model.process_noise_diag(dt));
                let d = predict_dense(&p, &dense(&t), &model.process_noise(dt));
                let scale = p.amax();
                for i in 0..14 {
                    for j in 0..14 {
                        let e = (s[(i, j)] - d[(i, j)]).abs() / scale;
                        assert!(e < 1e-12, "{form:?} P'[{i},{j}] differs by {e}");
                    }
                }
                assert_eq!(s, s.transpose());
                let f = dense(&t);
                let fm = f * p;
                let mft = p * f.transpose();
                assert!((f_mul(&t, &p) - fm).amax() < 1e-12 * scale);
                assert!((mul_ft(&p, &t) - mft).amax() < 1e-12 * scale);
            }
        }
    }
}
