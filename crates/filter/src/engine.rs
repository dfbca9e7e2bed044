//! Building blocks shared by the four filters: the state and covariance with
//! their IMU-rate prediction, the innovation, the Joseph-form correction, the
//! fading of the measured block, and the simplified Sage-Husa `R` estimator.

use nalgebra::{Cholesky, SMatrix, SVector};

use crate::filter::{PredictError, ResetError, UpdateError, UpdateReport};
use crate::model::{Mat14, Mat4, PaperModel, Vec14, N_MEAS, N_STATES};
use crate::params::{FilterParams, FilterSetup};
use crate::sparse::predict_sparse;

/// State, covariance and measurement noise of one filter.
#[derive(Debug, Clone)]
pub(crate) struct Core {
    pub model: PaperModel,
    /// State: posterior after an update, predicted in between.
    pub x: Vec14,
    /// Covariance: posterior after an update, predicted in between.
    pub p: Mat14,
    /// `Q` accumulated (and propagated) since the last update, so that
    /// `p - q_acc = Phi P_{k-1} Phi^T` over the whole update interval.
    pub q_acc: Mat14,
    pub track_q_acc: bool,
    /// Measurement noise in use (`R_{k-1}` until the next update).
    pub r: Mat4,
    pub r0: Mat4,
    pub updates: u64,
    /// Velocity noise density added to the model's (m^2/s^3), set per
    /// prediction from what the IMU measures ([`crate::ErrorFilter::set_extra_velocity_noise`]).
    pub q_vel_extra: f64,
}

/// What an update knows before any adaptation.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Prior<const M: usize> {
    /// Innovation `v = z - H x-`.
    pub v: SVector<f64, M>,
    /// `S = H P- H^T + R_{k-1}`.
    pub s: SMatrix<f64, M, M>,
    /// `v^T S^-1 v`.
    pub nis: f64,
}

/// Result of a correction, not yet committed.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Posterior<const M: usize> {
    pub x: Vec14,
    pub p: Mat14,
    pub k: SMatrix<f64, N_STATES, M>,
}

/// True when no entry is NaN or infinite. Branch-free, so it vectorises (the
/// early-exit `iter().all(is_finite)` over P and Q_acc cost as much as one
/// sparse propagation): a value is not finite when its exponent bits are
/// all ones.
fn all_finite<const R: usize, const C: usize>(m: &SMatrix<f64, R, C>) -> bool {
    const EXP: u64 = 0x7ff0_0000_0000_0000;
    m.as_slice()
        .iter()
        .fold(0u64, |acc, v| acc | u64::from(v.to_bits() & EXP == EXP))
        == 0
}

fn symmetrise(p: &mut Mat14) {
    for i in 0..N_STATES {
        for j in (i + 1)..N_STATES {
            let v = 0.5 * (p[(i, j)] + p[(j, i)]);
            p[(i, j)] = v;
            p[(j, i)] = v;
        }
    }
}

/// `max(1, tr_n / tr_m)` capped at `cap` (eq. 29); 1 when `tr_m` is not positive.
pub(crate) fn fading_factor(tr_n: f64, tr_m: f64, cap: f64) -> f64 {
    if tr_m.is_nan() || tr_m <= 0.0 {
        return 1.0;
    }
    let f = tr_n / tr_m;
    if f.is_nan() || f <= 1.0 {
        1.0
    } else if f > cap {
        cap
    } else {
        f
    }
}

impl Core {
    pub fn new(model: PaperModel, setup: &FilterSetup, track_q_acc: bool) -> Self {
        Self {
            model,
            x: Vec14::zeros(),
            p: setup.p0(),
            q_acc: Mat14::zeros(),
            track_q_acc,
            r: setup.r0(),
            r0: setup.r0(),
            updates: 0,
            q_vel_extra: 0.0,
        }
    }

    pub fn predict(&mut self, dt_s: f64, a_e_mps2: f64, a_n_mps2: f64) -> Result<(), PredictError> {
        if !(a_e_mps2.is_finite() && a_n_mps2.is_finite()) {
            return Err(PredictError::NonFiniteAccel { a_e_mps2, a_n_mps2 });
        }
        let steps = self.model.steps(dt_s)?;
        let t = self.model.transition(steps.sub_dt_s, a_e_mps2, a_n_mps2);
        let mut q = self.model.process_noise_diag(steps.sub_dt_s);
        for i in [crate::model::idx::VE, crate::model::idx::VN] {
            q[i] += self.q_vel_extra * steps.sub_dt_s;
        }
        let mut x = self.x;
        let mut p = self.p;
        let mut q_acc = self.q_acc;
        for _ in 0..steps.n {
            x = t.apply(&x);
            p = predict_sparse(&p, &t, &q);
            if self.track_q_acc {
                q_acc = predict_sparse(&q_acc, &t, &q);
            }
        }
        if !(all_finite(&x) && all_finite(&p) && all_finite(&q_acc)) {
            return Err(PredictError::NonFiniteResult { dt_s });
        }
        self.x = x;
        self.p = p;
        self.q_acc = q_acc;
        Ok(())
    }

    /// Innovation and its covariance with `R_{k-1}`.
    pub fn prior<const M: usize>(&self, z: &SVector<f64, M>) -> Result<Prior<M>, UpdateError> {
        if let Some((index, &value)) = z.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(UpdateError::NonFiniteMeasurement { index, value });
        }
        let v = z - self.x.fixed_rows::<M>(0);
        let s = self.p.fixed_view::<M, M>(0, 0) + self.r.fixed_view::<M, M>(0, 0);
        let chol = Cholesky::new(s).ok_or(UpdateError::NotPositiveDefinite {
            what: "innovation covariance S = H P- H^T + R",
        })?;
        let nis = v.dot(&chol.solve(&v));
        if !nis.is_finite() {
            return Err(UpdateError::NonFiniteResult);
        }
        Ok(Prior { v, s, nis })
    }

    /// Gain and Joseph-form correction with the given predicted covariance,
    /// (possibly weighted) innovation and measurement noise (the same `R` in
    /// the gain and the Joseph form, erratum 9). Exploits `H = [I_M | 0]`.
    pub fn correct<const M: usize>(
        &self,
        p_pred: &Mat14,
        v: &SVector<f64, M>,
        r: &SMatrix<f64, M, M>,
    ) -> Result<Posterior<M>, UpdateError> {
        let s = p_pred.fixed_view::<M, M>(0, 0) + r;
        let chol = Cholesky::new(s).ok_or(UpdateError::NotPositiveDefinite {
            what: "gain covariance H P- H^T + R",
        })?;
        let hp: SMatrix<f64, M, N_STATES> = p_pred.fixed_rows::<M>(0).into_owned();
        let kt = chol.solve(&hp); // S^-1 H P = K^T
        let k = kt.transpose();
        let x = self.x + k * v;
        let l = p_pred - k * hp; // (I - K H) P
        let mut p = l - l.fixed_columns::<M>(0) * kt + k * r * kt;
        symmetrise(&mut p);
        if !(all_finite(&x) && all_finite(&p)) {
            return Err(UpdateError::NonFiniteResult);
        }
        Ok(Posterior { x, p, k })
    }

    /// The predicted covariance with the measured block (states `0..M`) of
    /// `Phi P_{k-1} Phi^T` scaled by `f` (eq. 28 on the observable block, erratum 15).
    pub fn faded<const M: usize>(&self, f: f64) -> Mat14 {
        let mut p = self.p;
        if f != 1.0 {
            for i in 0..M {
                for j in 0..M {
                    let q = self.q_acc[(i, j)];
                    p[(i, j)] = f * (self.p[(i, j)] - q) + q;
                }
            }
        }
        p
    }

    /// `tr(H (P- - Q_acc) H^T)` and `tr(H Q_acc H^T)` over the measured block.
    pub fn traces<const M: usize>(&self) -> (f64, f64) {
        let mut tr_m = 0.0;
        let mut tr_q = 0.0;
        for i in 0..M {
            tr_m += self.p[(i, i)] - self.q_acc[(i, i)];
            tr_q += self.q_acc[(i, i)];
        }
        (tr_m, tr_q)
    }

    pub fn commit<const M: usize>(&mut self, post: &Posterior<M>, r: Mat4) {
        self.x = post.x;
        self.p = post.p;
        self.r = r;
        self.q_acc = Mat14::zeros();
        self.updates += 1;
    }

    /// A scalar linear measurement `z = h x + n`, `n ~ N(0, r)`, of the
    /// error state (a velocity constraint): Joseph-form update of `x` and
    /// `P`; `R`, the update count and the adaptive estimators' records are
    /// untouched. Returns the NIS.
    pub fn update_scalar(&mut self, h: &Vec14, z: f64, r: f64) -> Result<f64, UpdateError> {
        if !z.is_finite() {
            return Err(UpdateError::NonFiniteMeasurement { index: 0, value: z });
        }
        let c = self.p * h;
        let s = h.dot(&c) + r;
        if !(s.is_finite() && s > 0.0 && r > 0.0) {
            return Err(UpdateError::NotPositiveDefinite {
                what: "constraint innovation variance",
            });
        }
        let v = z - h.dot(&self.x);
        let k = c / s;
        let x = self.x + k * v;
        let kc = k * c.transpose();
        let mut p = self.p + k * k.transpose() * s - kc - kc.transpose();
        symmetrise(&mut p);
        if !(all_finite(&x) && all_finite(&p)) {
            return Err(UpdateError::NonFiniteResult);
        }
        self.x = x;
        self.p = p;
        Ok(v * v / s)
    }

    pub fn take_correction(&mut self) -> Vec14 {
        let x = self.x;
        self.x = Vec14::zeros();
        x
    }

    pub fn reset(&mut self, p0: &Mat14) -> Result<(), ResetError> {
        for i in 0..N_STATES {
            for j in 0..N_STATES {
                let value = p0[(i, j)];
                if !value.is_finite() {
                    return Err(ResetError::NonFinite {
                        row: i,
                        col: j,
                        value,
                    });
                }
            }
            if p0[(i, i)] < 0.0 {
                return Err(ResetError::NegativeDiagonal {
                    index: i,
                    value: p0[(i, i)],
                });
            }
        }
        for i in 0..N_STATES {
            for j in (i + 1)..N_STATES {
                let (a, b) = (p0[(i, j)], p0[(j, i)]);
                if (a - b).abs() > 1e-9 * a.abs().max(b.abs()).max(1e-300) {
                    return Err(ResetError::NotSymmetric { row: i, col: j });
                }
            }
        }
        let mut p = *p0;
        symmetrise(&mut p);
        self.x = Vec14::zeros();
        self.p = p;
        self.q_acc = Mat14::zeros();
        self.r = self.r0;
        self.updates = 0;
        Ok(())
    }

    /// The report of an update.
    pub fn report<const M: usize>(
        prior: &Prior<M>,
        lambda: &SVector<f64, M>,
        r_used: &SMatrix<f64, M, M>,
        fading: f64,
        divergence: bool,
        outlier: bool,
    ) -> UpdateReport {
        let mut rep = UpdateReport {
            dim: M,
            nis: prior.nis,
            fading,
            divergence,
            outlier,
            ..UpdateReport::default()
        };
        for i in 0..M.min(N_MEAS) {
            rep.innovation[i] = prior.v[i];
            rep.innovation_var[i] = prior.s[(i, i)];
            rep.lambda[i] = lambda[i];
            rep.r_diag[i] = r_used[(i, i)];
        }
        rep
    }
}

/// The simplified Sage-Husa estimator of `R` (eq. 22, errata 7-9).
#[derive(Debug, Clone)]
pub(crate) struct SageHusa {
    b: f64,
    warmup: u64,
    r_min: [f64; N_MEAS],
    r_max: [f64; N_MEAS],
    full: bool,
    /// Updates so far (the next update is `k = count + 1`).
    count: u64,
    /// `H K_{k-1}` (4 x 4; columns of components the last update did not measure are zero).
    hk_prev: Mat4,
    /// `H P_{k-1} H^T` (posterior of the last update, `P_0` before the first).
    hph_prev: Mat4,
}

impl SageHusa {
    pub fn new(params: &FilterParams, setup: &FilterSetup) -> Self {
        let mut r_min = [0.0; N_MEAS];
        let mut r_max = [0.0; N_MEAS];
        for (i, &r0) in setup.r0_diag.iter().enumerate() {
            r_min[i] = params.r_min_factor * r0;
            r_max[i] = params.r_max_factor * r0;
        }
        Self {
            b: params.b,
            warmup: u64::from(params.warmup_updates),
            r_min,
            r_max,
            full: params.adapt_full_r,
            count: 0,
            hk_prev: Mat4::zeros(),
            hph_prev: setup.p0().fixed_view::<N_MEAS, N_MEAS>(0, 0).into_owned(),
        }
    }

    /// Writes the update count and `r` (row-major) into `out` (cleared):
    /// what a restarted filter resumes from.
    pub fn snapshot(&self, r: &Mat4, out: &mut Vec<f64>) {
        out.clear();
        #[allow(clippy::cast_precision_loss)]
        out.push(self.count as f64);
        out.extend((0..N_MEAS).flat_map(|i| (0..N_MEAS).map(move |j| r[(i, j)])));
    }

    /// Takes the update count of a [`SageHusa::snapshot`] and returns its
    /// `R`; `None` (nothing changed) when it does not fit: not `1 + 4 x 4`
    /// finite values, a negative count, an asymmetric `R` or a diagonal
    /// outside `[r_min, r_max]`.
    pub fn restore(&mut self, s: &[f64]) -> Option<Mat4> {
        let (&count, rest) = s.split_first()?;
        if rest.len() != N_MEAS * N_MEAS
            || !(0.0..1e18).contains(&count)
            || rest.iter().any(|v| !v.is_finite())
        {
            return None;
        }
        let r = Mat4::from_fn(|i, j| rest.get(i * N_MEAS + j).copied().unwrap_or(f64::NAN));
        let scale = r.abs().max().max(f64::MIN_POSITIVE);
        if (r - r.transpose()).abs().max() > 1e-12 * scale {
            return None;
        }
        for i in 0..N_MEAS {
            let d = r[(i, i)];
            if d < self.r_min[i] * (1.0 - 1e-12) || d > self.r_max[i] * (1.0 + 1e-12) {
                return None;
            }
        }
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        {
            self.count = count.round() as u64;
        }
        Some(r)
    }

    pub fn reset(&mut self, p0: &Mat14) {
        self.count = 0;
        self.hk_prev = Mat4::zeros();
        self.hph_prev = p0.fixed_view::<N_MEAS, N_MEAS>(0, 0).into_owned();
    }

    /// `d_k = (1 - b) / (1 - b^(k+1))` with `k` counting updates from 1 (erratum 8).
    pub fn d(&self, k: u64) -> f64 {
        let e = i32::try_from(k.saturating_add(1)).unwrap_or(i32::MAX);
        (1.0 - self.b) / (1.0 - self.b.powi(e))
    }

    /// `R_k` of eq. 22 for an update of the first `M` components with innovation `v`:
    /// `(1 - d_k) R_{k-1} + d_k [(I - H K_{k-1}) v v^T (I - H K_{k-1})^T + H P_{k-1} H^T]`,
    /// held at `R_{k-1}` during the warm-up, diagonal clamped to `[r_min, r_max]`.
    pub fn estimate<const M: usize>(&self, v: &SVector<f64, M>, r_prev: &Mat4) -> Mat4 {
        let k = self.count + 1;
        if k <= self.warmup {
            return *r_prev;
        }
        let d = self.d(k);
        let e = v - self.hk_prev.fixed_view::<M, M>(0, 0) * v;
        let est = e * e.transpose() + self.hph_prev.fixed_view::<M, M>(0, 0);
        let block = r_prev.fixed_view::<M, M>(0, 0) * (1.0 - d) + est * d;
        let mut r = *r_prev;
        r.fixed_view_mut::<M, M>(0, 0).copy_from(&block);
        if !self.full {
            r = Mat4::from_diagonal(&r.diagonal());
        }
        for i in 0..M.min(N_MEAS) {
            r[(i, i)] = r[(i, i)].max(self.r_min[i]).min(self.r_max[i]);
        }
        if self.full && (!all_finite(&r) || Cholesky::new(r).is_none()) {
            r = Mat4::from_diagonal(&r.diagonal());
        }
        if !all_finite(&r) {
            return *r_prev;
        }
        r
    }

    /// Records the gain and posterior of a committed update.
    pub fn record<const M: usize>(&mut self, k_gain: &SMatrix<f64, N_STATES, M>, p_post: &Mat14) {
        self.count += 1;
        self.hk_prev = Mat4::zeros();
        self.hk_prev
            .fixed_view_mut::<N_MEAS, M>(0, 0)
            .copy_from(&k_gain.fixed_rows::<N_MEAS>(0));
        self.hph_prev = p_post.fixed_view::<N_MEAS, N_MEAS>(0, 0).into_owned();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn all_finite_finds_any_nan_or_infinity() {
        let mut m = Mat14::from_fn(|i, j| (i as f64 - 7.0) * 1e300 + j as f64);
        m[(0, 0)] = f64::MAX;
        m[(1, 1)] = f64::MIN_POSITIVE / 2.0; // subnormal
        m[(2, 2)] = -0.0;
        assert!(all_finite(&m));
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            for (i, j) in [(0, 0), (13, 13), (5, 9), (13, 0)] {
                let mut b = m;
                b[(i, j)] = bad;
                assert!(!all_finite(&b), "{bad} at ({i}, {j})");
            }
        }
        assert!(all_finite(&Vec14::zeros()));
    }
}
