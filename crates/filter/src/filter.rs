//! The four error-state filters of Table 1 behind one object-safe trait,
//! [`ErrorFilter`]: [`Kf`] (plain), [`Shaf`] (simplified Sage-Husa, eqs.
//! 16-22), [`Stf`] (Zhou's strong tracking filter) and [`Iakf`] (section 3.3),
//! and [`build`], which makes any of them from a [`FilterKind`].
//!
//! Common design:
//! - `predict` runs at the IMU rate (erratum 6; see [`crate::model`] for how
//!   an interval maps onto AR steps), `update` at the UWB rate with
//!   `z = [P_ins - P_uwb; V_ins - V_uwb]` (eq. 15), `update_pos` with the
//!   position part only (a fix without a valid velocity).
//! - The correction is the Joseph form with the `R` of the gain (erratum 9),
//!   exploiting `H = [I | 0]`; the innovation covariance is solved by
//!   Cholesky: when it is not positive definite the update is refused with an
//!   error and the filter is unchanged. Every result is checked finite before
//!   it is committed, so a NaN never enters the state.
//! - Fading (STF, IAKF): predictions run at the IMU rate, several per update,
//!   so `F P_{k-1} F^T` of eqs. 28 and 31 (erratum 15) is taken over the whole
//!   interval: the filters also propagate the accumulated process noise
//!   `Q_acc` (`Q_acc <- F Q_acc F^T + Q`, zeroed at each update), so
//!   `Phi P_{k-1} Phi^T = P- - Q_acc` exactly. The fading factor scales that
//!   part on the measured block only (states `0..4`, or `0..2` for
//!   `update_pos`: the block `H` sees, where the covariance matching of eqs.
//!   29-31 is done; the unobservable heading and AR states are left alone),
//!   and is capped at [`FilterParams::fading_cap`].
//! - No heap allocation after construction: fixed-size nalgebra types only.

use insuwb_msg::{FilterDiag, FilterKind, Header};
use nalgebra::{SMatrix, SVector};
use thiserror::Error;

use crate::engine::{fading_factor, Core, Prior, SageHusa};
use crate::model::{Mat14, Mat4, PaperModel, StepError, Vec14, N_MEAS};
use crate::params::{
    FilterParams, FilterParamsError, FilterSetup, FilterSetupError, LimitMode, OutlierForm,
};

/// What one update did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct UpdateReport {
    /// Number of measurement components (4, or 2 for a position-only update);
    /// entries of the arrays beyond it are zero.
    pub dim: usize,
    /// Innovation `v = z - H x-` (before any outlier weighting).
    pub innovation: [f64; 4],
    /// Diagonal of `S = H P- H^T + R_{k-1}` (before fading and adaptation).
    pub innovation_var: [f64; 4],
    /// Outlier weight per component (1: accepted as is).
    pub lambda: [f64; 4],
    /// Diagonal of the `R` used in the gain (after adaptation, or inflation).
    pub r_diag: [f64; 4],
    /// Normalised innovation squared `v^T S^-1 v` with the `S` above.
    pub nis: f64,
    /// Fading factor applied (1: none).
    pub fading: f64,
    /// The divergence test fired (IAKF).
    pub divergence: bool,
    /// At least one component was weighted as an outlier (IAKF).
    pub outlier: bool,
}

impl UpdateReport {
    /// The report as a [`FilterDiag`] sample with the given header (flags added).
    #[must_use]
    pub fn to_diag(&self, mut header: Header, kind: FilterKind) -> FilterDiag {
        if self.divergence {
            header.flags |= FilterDiag::FLAG_DIVERGENCE;
        }
        if self.outlier {
            header.flags |= FilterDiag::FLAG_OUTLIER;
        }
        let mut d = FilterDiag {
            header,
            nis: self.nis,
            fading: self.fading,
            dim: u32::try_from(self.dim).unwrap_or(0),
            filter_kind: kind as u32,
            ..FilterDiag::default()
        };
        for i in 0..4 {
            d.innovation[i] = self.innovation[i];
            d.innovation_var[i] = self.innovation_var[i];
            d.lambda[i] = self.lambda[i];
            d.r_diag[i] = self.r_diag[i];
        }
        d
    }
}

/// Why a predict was refused; the filter is unchanged.
#[derive(Debug, Clone, Copy, PartialEq, Error)]
pub enum PredictError {
    /// The interval does not map onto AR steps.
    #[error(transparent)]
    Step(#[from] StepError),
    /// An acceleration input is NaN or infinite.
    #[error("predict acceleration is not finite: a_e = {a_e_mps2}, a_n = {a_n_mps2}")]
    NonFiniteAccel {
        /// East acceleration, m/s^2.
        a_e_mps2: f64,
        /// North acceleration, m/s^2.
        a_n_mps2: f64,
    },
    /// The prediction overflowed (absurd inputs).
    #[error("prediction over {dt_s} s produced a non-finite covariance")]
    NonFiniteResult {
        /// The interval, s.
        dt_s: f64,
    },
}

/// Why an update was refused; the filter is unchanged.
#[derive(Debug, Clone, Copy, PartialEq, Error)]
pub enum UpdateError {
    /// A measurement component is NaN or infinite.
    #[error("measurement component {index} is not finite: {value}")]
    NonFiniteMeasurement {
        /// Component index.
        index: usize,
        /// Its value.
        value: f64,
    },
    /// A covariance to invert is not positive definite.
    #[error("{what} is not positive definite; update skipped")]
    NotPositiveDefinite {
        /// Which matrix.
        what: &'static str,
    },
    /// The update produced a non-finite state or covariance.
    #[error("update produced a non-finite state or covariance; update skipped")]
    NonFiniteResult,
}

/// Why a reset was refused; the filter is unchanged.
#[derive(Debug, Clone, Copy, PartialEq, Error)]
pub enum ResetError {
    /// An entry of `P_0` is NaN or infinite.
    #[error("reset P0[{row},{col}] is not finite: {value}")]
    NonFinite {
        /// Row.
        row: usize,
        /// Column.
        col: usize,
        /// Its value.
        value: f64,
    },
    /// A diagonal entry of `P_0` is negative.
    #[error("reset P0[{index},{index}] is negative: {value}")]
    NegativeDiagonal {
        /// Index.
        index: usize,
        /// Its value.
        value: f64,
    },
    /// `P_0` is not symmetric.
    #[error("reset P0 is not symmetric at [{row},{col}]")]
    NotSymmetric {
        /// Row.
        row: usize,
        /// Column.
        col: usize,
    },
}

/// Why a filter could not be built.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum BuildError {
    /// The parameters do not validate.
    #[error(transparent)]
    Params(#[from] FilterParamsError),
    /// The setup does not validate.
    #[error(transparent)]
    Setup(#[from] FilterSetupError),
    /// This crate does not implement that kind.
    #[error("filter kind {kind:?} is not provided by insuwb-filter")]
    UnsupportedKind {
        /// The kind asked for.
        kind: FilterKind,
    },
}

/// An error-state filter on the paper's 14-state model (object safe: hold it
/// as `Box<dyn ErrorFilter>`).
pub trait ErrorFilter: core::fmt::Debug + Send {
    /// Which filter this is.
    fn kind(&self) -> FilterKind;
    /// The model it filters with.
    fn model(&self) -> &PaperModel;
    /// Predicts over `dt_s` (normally one IMU sample) at the ENU kinematic
    /// acceleration (used by the physics form's heading coupling).
    ///
    /// # Errors
    /// [`PredictError`]; the filter is then unchanged.
    fn predict(&mut self, dt_s: f64, a_e_mps2: f64, a_n_mps2: f64) -> Result<(), PredictError>;
    /// Updates with `z = [P_ins - P_uwb; V_ins - V_uwb]` (ENU, m and m/s).
    ///
    /// # Errors
    /// [`UpdateError`]; the filter is then unchanged.
    fn update(&mut self, z: &SVector<f64, 4>) -> Result<UpdateReport, UpdateError>;
    /// Updates with the position part `z = P_ins - P_uwb` only (uses the
    /// position block of `R`).
    ///
    /// # Errors
    /// [`UpdateError`]; the filter is then unchanged.
    fn update_pos(&mut self, z: &SVector<f64, 2>) -> Result<UpdateReport, UpdateError>;
    /// Updates with a scalar linear measurement `z = h x + n` of the error
    /// state, `n ~ N(0, r)` (a vehicle's velocity constraint): a plain
    /// Kalman update for every filter, outside their adaptive estimators
    /// (`R`, fading and the update count are untouched). Returns the NIS.
    ///
    /// # Errors
    /// [`UpdateError`]; the filter is then unchanged.
    fn update_constraint(&mut self, h: &Vec14, z: f64, r: f64) -> Result<f64, UpdateError>;
    /// The error state.
    fn state(&self) -> &Vec14;
    /// Its covariance.
    fn covariance(&self) -> &Mat14;
    /// The measurement noise now in use (`R_0` for the KF and the STF).
    fn r(&self) -> &Mat4;
    /// Updates since construction or the last reset.
    fn updates(&self) -> u64;
    /// Closed loop: returns the error state and sets it to zero (`P` unchanged).
    fn take_correction(&mut self) -> Vec14;
    /// Restarts from `x = 0`, `P = p0`, `R = R_0` and restarts the adaptive
    /// estimators (warm-up included).
    ///
    /// # Errors
    /// [`ResetError`] when `p0` is not finite, symmetric, with a non-negative
    /// diagonal; the filter is then unchanged.
    fn reset(&mut self, p0: &Mat14) -> Result<(), ResetError>;
    /// Sets a velocity noise density (m^2/s^3) added to the model's
    /// `q_vel_m2_per_s3` in the predictions that follow (e.g. from the
    /// vibration the IMU measures); a value that is not finite and
    /// non-negative is taken as 0.
    fn set_extra_velocity_noise(&mut self, q_m2_per_s3: f64);
    /// A copy of this filter on the heap (a scratch filter for
    /// [`ErrorFilter::copy_to`]; allocates, so made once).
    fn clone_boxed(&self) -> Box<dyn ErrorFilter>;
    /// Copies this filter's whole state into `dst` when it is a filter of
    /// the same type (false otherwise, `dst` unchanged). Allocates nothing:
    /// the filters hold fixed-size data only.
    fn copy_to(&self, dst: &mut dyn ErrorFilter) -> bool;
    /// `self` as `Any`, for [`ErrorFilter::copy_to`].
    fn as_any_mut(&mut self) -> &mut dyn core::any::Any;
    /// The adaptive estimator's state a restarted filter resumes from (for
    /// checkpoints), written into `out` (cleared): the Sage-Husa update
    /// count and `R`, row-major, for the SHAF and the IAKF; left empty by
    /// the filters whose `R` is fixed.
    fn adaptive_state(&self, out: &mut Vec<f64>) {
        out.clear();
    }
    /// Restores an [`ErrorFilter::adaptive_state`] after
    /// [`ErrorFilter::reset`] (whose `P` the estimator's memory of `H P
    /// H^T` keeps); false, the filter unchanged, when it does not fit this
    /// filter or its bounds on `R`.
    fn restore_adaptive_state(&mut self, _state: &[f64]) -> bool {
        false
    }
}

/// [`ErrorFilter::adaptive_state`] and its restore for a filter with a
/// Sage-Husa estimator in `sh`.
macro_rules! sage_husa_state_methods {
    () => {
        fn adaptive_state(&self, out: &mut Vec<f64>) {
            self.sh.snapshot(&self.core.r, out);
        }
        fn restore_adaptive_state(&mut self, state: &[f64]) -> bool {
            match self.sh.restore(state) {
                Some(r) => {
                    self.core.r = r;
                    true
                }
                None => false,
            }
        }
    };
}

macro_rules! common_filter_methods {
    () => {
        fn model(&self) -> &PaperModel {
            &self.core.model
        }
        fn predict(&mut self, dt_s: f64, a_e_mps2: f64, a_n_mps2: f64) -> Result<(), PredictError> {
            self.core.predict(dt_s, a_e_mps2, a_n_mps2)
        }
        fn update(&mut self, z: &SVector<f64, 4>) -> Result<UpdateReport, UpdateError> {
            self.update_m::<4>(z)
        }
        fn update_pos(&mut self, z: &SVector<f64, 2>) -> Result<UpdateReport, UpdateError> {
            self.update_m::<2>(z)
        }
        fn update_constraint(&mut self, h: &Vec14, z: f64, r: f64) -> Result<f64, UpdateError> {
            self.core.update_scalar(h, z, r)
        }
        fn state(&self) -> &Vec14 {
            &self.core.x
        }
        fn covariance(&self) -> &Mat14 {
            &self.core.p
        }
        fn r(&self) -> &Mat4 {
            &self.core.r
        }
        fn updates(&self) -> u64 {
            self.core.updates
        }
        fn take_correction(&mut self) -> Vec14 {
            self.core.take_correction()
        }
        fn set_extra_velocity_noise(&mut self, q_m2_per_s3: f64) {
            self.core.q_vel_extra = if q_m2_per_s3.is_finite() && q_m2_per_s3 >= 0.0 {
                q_m2_per_s3
            } else {
                0.0
            };
        }
        fn clone_boxed(&self) -> Box<dyn ErrorFilter> {
            Box::new(self.clone())
        }
        fn copy_to(&self, dst: &mut dyn ErrorFilter) -> bool {
            match dst.as_any_mut().downcast_mut::<Self>() {
                Some(d) => {
                    d.clone_from(self);
                    true
                }
                None => false,
            }
        }
        fn as_any_mut(&mut self) -> &mut dyn core::any::Any {
            self
        }
    };
}

fn r_block<const M: usize>(r: &Mat4) -> SMatrix<f64, M, M> {
    r.fixed_view::<M, M>(0, 0).into_owned()
}

fn ones<const M: usize>() -> SVector<f64, M> {
    SVector::<f64, M>::repeat(1.0)
}

/// Plain Kalman filter (Joseph form), fixed `R_0`.
#[derive(Debug, Clone)]
pub struct Kf {
    core: Core,
}

impl Kf {
    /// A KF with the model's `Q` and the setup's `P_0`, `R_0`.
    ///
    /// # Errors
    /// [`BuildError`] when the setup does not validate.
    pub fn new(model: PaperModel, setup: &FilterSetup) -> Result<Self, BuildError> {
        setup.validate()?;
        Ok(Self {
            core: Core::new(model, setup, false),
        })
    }

    fn update_m<const M: usize>(
        &mut self,
        z: &SVector<f64, M>,
    ) -> Result<UpdateReport, UpdateError> {
        let prior = self.core.prior(z)?;
        let r = r_block::<M>(&self.core.r);
        let post = self.core.correct(&self.core.p, &prior.v, &r)?;
        self.core.commit(&post, self.core.r);
        Ok(Core::report(&prior, &ones(), &r, 1.0, false, false))
    }
}

impl ErrorFilter for Kf {
    fn kind(&self) -> FilterKind {
        FilterKind::Kf
    }
    common_filter_methods!();
    fn reset(&mut self, p0: &Mat14) -> Result<(), ResetError> {
        self.core.reset(p0)
    }
}

/// Simplified Sage-Husa adaptive filter (eqs. 16-22, errata 7-9): `R` is
/// re-estimated at every update in the residual form with `K_{k-1}`,
/// `P_{k-1}`, after a warm-up, clamped, and used in both the gain and the
/// Joseph form.
#[derive(Debug, Clone)]
pub struct Shaf {
    core: Core,
    sh: SageHusa,
}

impl Shaf {
    /// A SHAF with the model's `Q`, the setup's `P_0`, `R_0` and the Sage-Husa parameters.
    ///
    /// # Errors
    /// [`BuildError`] when the parameters or the setup do not validate.
    pub fn new(
        model: PaperModel,
        params: &FilterParams,
        setup: &FilterSetup,
    ) -> Result<Self, BuildError> {
        params.validate()?;
        setup.validate()?;
        Ok(Self {
            core: Core::new(model, setup, false),
            sh: SageHusa::new(params, setup),
        })
    }

    fn update_m<const M: usize>(
        &mut self,
        z: &SVector<f64, M>,
    ) -> Result<UpdateReport, UpdateError> {
        let prior = self.core.prior(z)?;
        let r_k = self.sh.estimate(&prior.v, &self.core.r);
        let r = r_block::<M>(&r_k);
        let post = self.core.correct(&self.core.p, &prior.v, &r)?;
        self.core.commit(&post, r_k);
        self.sh.record(&post.k, &post.p);
        Ok(Core::report(&prior, &ones(), &r, 1.0, false, false))
    }
}

impl ErrorFilter for Shaf {
    fn kind(&self) -> FilterKind {
        FilterKind::Shaf
    }
    common_filter_methods!();
    sage_husa_state_methods!();
    fn reset(&mut self, p0: &Mat14) -> Result<(), ResetError> {
        self.core.reset(p0)?;
        self.sh.reset(p0);
        Ok(())
    }
}

/// Zhou's strong tracking filter: a fading factor on every update (erratum
/// 15), `f = max(1, tr N / tr M)` with `N = V_k - beta R - H Q_acc H^T`,
/// `M = H Phi P_{k-1} Phi^T H^T`, `V_k = (rho V_{k-1} + v v^T) / (1 + rho)`,
/// applied to the measured block and capped; fixed `R_0`.
#[derive(Debug, Clone)]
pub struct Stf {
    core: Core,
    rho: f64,
    beta: f64,
    cap: f64,
    v_est: Mat4,
    seen: [bool; N_MEAS],
}

impl Stf {
    /// An STF with the model's `Q`, the setup's `P_0`, `R_0` and `stf_rho`,
    /// `stf_beta`, `fading_cap`.
    ///
    /// # Errors
    /// [`BuildError`] when the parameters or the setup do not validate.
    pub fn new(
        model: PaperModel,
        params: &FilterParams,
        setup: &FilterSetup,
    ) -> Result<Self, BuildError> {
        params.validate()?;
        setup.validate()?;
        Ok(Self {
            core: Core::new(model, setup, true),
            rho: params.stf_rho,
            beta: params.stf_beta,
            cap: params.fading_cap,
            v_est: Mat4::zeros(),
            seen: [false; N_MEAS],
        })
    }

    fn update_m<const M: usize>(
        &mut self,
        z: &SVector<f64, M>,
    ) -> Result<UpdateReport, UpdateError> {
        let prior = self.core.prior(z)?;
        let vv = prior.v * prior.v.transpose();
        let mut v_est = self.v_est;
        for i in 0..M {
            for j in 0..M {
                let seen = self.seen.get(i).copied().unwrap_or(false)
                    && self.seen.get(j).copied().unwrap_or(false);
                v_est[(i, j)] = if seen {
                    (self.rho * v_est[(i, j)] + vv[(i, j)]) / (1.0 + self.rho)
                } else {
                    vv[(i, j)]
                };
            }
        }
        let (tr_m, tr_q) = self.core.traces::<M>();
        let mut tr_n = -tr_q;
        for i in 0..M {
            tr_n += v_est[(i, i)] - self.beta * self.core.r[(i, i)];
        }
        let f = fading_factor(tr_n, tr_m, self.cap);
        let p_used = self.core.faded::<M>(f);
        let r = r_block::<M>(&self.core.r);
        let post = self.core.correct(&p_used, &prior.v, &r)?;
        self.core.commit(&post, self.core.r);
        self.v_est = v_est;
        for s in self.seen.iter_mut().take(M) {
            *s = true;
        }
        Ok(Core::report(&prior, &ones(), &r, f, false, false))
    }
}

impl ErrorFilter for Stf {
    fn kind(&self) -> FilterKind {
        FilterKind::Stf
    }
    common_filter_methods!();
    fn reset(&mut self, p0: &Mat14) -> Result<(), ResetError> {
        self.core.reset(p0)?;
        self.v_est = Mat4::zeros();
        self.seen = [false; N_MEAS];
        Ok(())
    }
}

/// The paper's improved adaptive Kalman filter (section 3.3, errata 10-14):
/// simplified Sage-Husa, plus innovation outlier weighting
/// `lambda_i = min(1, sqrt((D_i + eps_i) / G_i))` with `eps_i = (kappa^2 - 1) S_ii`,
/// plus the divergence test `v^T v > gamma tr(S)` (skipped on epochs with an
/// outlier) which switches to the fading branch (eqs. 28-31 with `P_{k-1}`,
/// measured block, capped) with `R` frozen.
#[derive(Debug, Clone)]
pub struct Iakf {
    core: Core,
    sh: SageHusa,
    outlier_form: OutlierForm,
    kappa: f64,
    limit_mode: LimitMode,
    divergence_fading: bool,
    gamma: f64,
    cap: f64,
}

impl Iakf {
    /// An IAKF with the model's `Q`, the setup's `P_0`, `R_0` and the parameters.
    ///
    /// # Errors
    /// [`BuildError`] when the parameters or the setup do not validate.
    pub fn new(
        model: PaperModel,
        params: &FilterParams,
        setup: &FilterSetup,
    ) -> Result<Self, BuildError> {
        params.validate()?;
        setup.validate()?;
        Ok(Self {
            core: Core::new(model, setup, true),
            sh: SageHusa::new(params, setup),
            outlier_form: params.outlier_form,
            kappa: params.kappa,
            limit_mode: params.limit_mode,
            divergence_fading: params.divergence_fading,
            gamma: params.gamma,
            cap: params.fading_cap,
        })
    }

    /// Outlier weights of eqs. 23-26 (errata 10-12).
    fn weights<const M: usize>(&self, z: &SVector<f64, M>, prior: &Prior<M>) -> SVector<f64, M> {
        let mut lambda = ones::<M>();
        if self.outlier_form == OutlierForm::Off {
            return lambda;
        }
        for i in 0..M {
            let s_ii = prior.s[(i, i)];
            let (g, d) = match self.outlier_form {
                OutlierForm::ZForm => (z[i] * z[i], s_ii + self.core.x[i] * self.core.x[i]),
                _ => (prior.v[i] * prior.v[i], s_ii),
            };
            let bound = d + (self.kappa * self.kappa - 1.0) * s_ii;
            if g > bound {
                // g > bound > 0 (S is positive definite): 0 < lambda < 1.
                lambda[i] = (bound / g).sqrt();
            }
        }
        lambda
    }

    fn update_m<const M: usize>(
        &mut self,
        z: &SVector<f64, M>,
    ) -> Result<UpdateReport, UpdateError> {
        let prior = self.core.prior(z)?;
        let lambda = self.weights(z, &prior);
        let outlier = lambda.iter().any(|&l| l < 1.0);
        let v_w = prior.v.component_mul(&lambda);
        let vtv = prior.v.dot(&prior.v);
        let divergence = self.divergence_fading && !outlier && vtv > self.gamma * prior.s.trace();
        let (f, r_k) = if divergence {
            let (tr_m, tr_q) = self.core.traces::<M>();
            let mut tr_n = vtv - tr_q;
            for i in 0..M {
                tr_n -= self.core.r[(i, i)];
            }
            (fading_factor(tr_n, tr_m, self.cap), self.core.r)
        } else {
            (1.0, self.sh.estimate(&v_w, &self.core.r))
        };
        let r_est = r_block::<M>(&r_k);
        let (v_gain, r_gain) = match self.limit_mode {
            LimitMode::ScaleInnovation => (v_w, r_est),
            LimitMode::InflateR => {
                let inv = lambda.map(|l| 1.0 / l);
                (
                    prior.v,
                    SMatrix::<f64, M, M>::from_fn(|i, j| r_est[(i, j)] * inv[i] * inv[j]),
                )
            }
        };
        let post = if f == 1.0 {
            self.core.correct(&self.core.p, &v_gain, &r_gain)?
        } else {
            let p_used = self.core.faded::<M>(f);
            self.core.correct(&p_used, &v_gain, &r_gain)?
        };
        self.core.commit(&post, r_k);
        self.sh.record(&post.k, &post.p);
        Ok(Core::report(
            &prior, &lambda, &r_gain, f, divergence, outlier,
        ))
    }
}

impl ErrorFilter for Iakf {
    fn kind(&self) -> FilterKind {
        FilterKind::Iakf
    }
    common_filter_methods!();
    sage_husa_state_methods!();
    fn reset(&mut self, p0: &Mat14) -> Result<(), ResetError> {
        self.core.reset(p0)?;
        self.sh.reset(p0);
        Ok(())
    }
}

/// Builds the filter of `kind` (KF, SHAF, STF or IAKF) on `model` with the
/// shared `setup` (`P_0`, `R_0`) and the adaptive `params`.
///
/// # Errors
/// [`BuildError`] when `params` or `setup` do not validate, or for
/// [`FilterKind::IakfTdoa`], which this crate does not provide.
pub fn build(
    kind: FilterKind,
    model: PaperModel,
    params: &FilterParams,
    setup: &FilterSetup,
) -> Result<Box<dyn ErrorFilter>, BuildError> {
    params.validate()?;
    setup.validate()?;
    Ok(match kind {
        FilterKind::Kf => Box::new(Kf::new(model, setup)?),
        FilterKind::Shaf => Box::new(Shaf::new(model, params, setup)?),
        FilterKind::Stf => Box::new(Stf::new(model, params, setup)?),
        FilterKind::Iakf => Box::new(Iakf::new(model, params, setup)?),
        FilterKind::IakfTdoa => return Err(BuildError::UnsupportedKind { kind }),
    })
}
