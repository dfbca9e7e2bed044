//! The 15-state error-state Kalman filter: covariance propagation on the
//! INS's nominal states, sequential robust TDOA updates (with the anchors'
//! error states of [`crate::anchor_error`] beside the 15 when configured),
//! an optional 3D position update and the closed-loop correction.

use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

use crate::anchor_error::{self, AnchorErrors, ErrorVector};
use crate::config::{EskfConfig, EskfConfigError};
use crate::math::{checked_rotation, finite, skew, InputFault};
use insuwb_filter::LimitMode;

/// Number of error states.
pub const N_STATES: usize = 15;
/// Index of the first position error state (δp, ENU, m; INS minus truth).
pub const IDX_POS: usize = 0;
/// Index of the first velocity error state (δv, ENU, m/s; INS minus truth).
pub const IDX_VEL: usize = 3;
/// Index of the first attitude error state (δθ, ENU rotation vector, rad;
/// `q_true = Exp(-δθ) ⊗ q_ins`).
pub const IDX_ATT: usize = 6;
/// Index of the first accelerometer bias error state (δb_a, body, m/s^2;
/// truth minus INS, the increment to add to the INS's estimate).
pub const IDX_ACCEL_BIAS: usize = 9;
/// Index of the first gyro bias error state (δb_g, body, rad/s; truth minus
/// INS, the increment to add to the INS's estimate).
pub const IDX_GYRO_BIAS: usize = 12;

/// The error-state vector `[δp, δv, δθ, δb_a, δb_g]`.
pub type StateVector = SVector<f64, N_STATES>;
/// The error-state covariance.
pub type Covariance = SMatrix<f64, N_STATES, N_STATES>;

/// Smallest time between two measurements of one pair used by the
/// rate-adaptive inflation, s (one IMU period at 1 kHz).
const MIN_PAIR_DT_S: f64 = 1e-3;
/// Smallest anchor-to-antenna distance the TDOA model accepts, m.
const MIN_ANCHOR_DIST_M: f64 = 1e-6;
/// Number of anchor pairs whose last update time is remembered (8 anchors
/// give 28 unordered pairs); the least recently used slot is reused.
const PAIR_SLOTS: usize = 64;

/// The error estimate handed to the INS, in the units and conventions of
/// [`insuwb_msg::InsCorrection`].
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Correction {
    /// Position error to remove (INS minus truth), ENU, m: `pos -= d_pos_m`.
    pub d_pos_m: [f64; 3],
    /// Velocity error to remove, ENU, m/s: `vel -= d_vel_mps`.
    pub d_vel_mps: [f64; 3],
    /// Attitude error to remove, ENU rotation vector, rad:
    /// `q = Exp(-d_att_rad) ⊗ q`.
    pub d_att_rad: [f64; 3],
    /// Accelerometer bias increment, body, m/s^2: `bias += d_accel_bias_mps2`.
    pub d_accel_bias_mps2: [f64; 3],
    /// Gyro bias increment, body, rad/s: `bias += d_gyro_bias_rps`.
    pub d_gyro_bias_rps: [f64; 3],
}

impl Correction {
    /// Copies the deltas into a correction message (other fields untouched).
    pub fn write_to(&self, msg: &mut insuwb_msg::InsCorrection) {
        msg.d_pos_m = self.d_pos_m;
        msg.d_vel_mps = self.d_vel_mps;
        msg.d_att_rad = self.d_att_rad;
        msg.d_accel_bias_mps2 = self.d_accel_bias_mps2;
        msg.d_gyro_bias_rps = self.d_gyro_bias_rps;
    }
}

/// What happened to one TDOA measurement.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TdoaOutcome {
    /// Applied with full weight (`r <= kappa`).
    Accepted,
    /// Applied with weight `lambda = kappa / r < 1` (`kappa < r <= hard gate`).
    Downweighted,
    /// Not applied: `r` beyond the hard gate; counted.
    Rejected,
    /// Not applied: the same anchor pair was applied less than
    /// `min_interval_per_pair_s` ago.
    Decimated,
}

/// Diagnostics of one TDOA update (`r = |v| / sqrt(S)`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TdoaUpdateReport {
    /// What happened to the measurement.
    pub outcome: TdoaOutcome,
    /// Innovation `v = z - h(x_ins) - H δx`, before weighting, m.
    pub innovation_m: f64,
    /// Marginal innovation variance `S = H P H^T + tdoa_sigma^2`, m^2.
    pub innovation_var_m2: f64,
    /// Measurement variance used in the gain (correlation inflation and,
    /// in `InflateR` mode, the robust inflation included), m^2; 0 when not applied.
    pub r_gain_m2: f64,
    /// Outlier weight: 1 accepted, `kappa / r` down-weighted, 0 rejected or decimated.
    pub lambda: f64,
    /// Normalised innovation squared `v^2 / S` (rejected measurements
    /// included: what a divergence monitor reads).
    pub nis: f64,
    /// The measurement was rejected by the hard gate.
    pub rejected: bool,
    /// The covariance is no longer finite and the filter must be
    /// re-initialised ([`Eskf::needs_reset`]; sticky until [`Eskf::reset`]).
    pub needs_reset: bool,
    /// The process-noise scale after this update ([`Eskf::q_scale`]).
    pub q_scale: f64,
}

impl TdoaUpdateReport {
    /// Fills a diagnostics message for this (scalar) update: entry 0 of the
    /// arrays, `dim = 1`, `nis`, `filter_kind` = [`insuwb_msg::FilterKind::IakfTdoa`],
    /// `FLAG_OUTLIER` when `lambda < 1` and `FLAG_DIVERGENCE` when a reset is
    /// needed; the header and `fading` are left to the caller.
    pub fn write_to(&self, diag: &mut insuwb_msg::FilterDiag) {
        diag.innovation = [0.0; 8];
        diag.innovation_var = [0.0; 8];
        diag.lambda = [0.0; 8];
        diag.r_diag = [0.0; 8];
        diag.innovation[0] = self.innovation_m;
        diag.innovation_var[0] = self.innovation_var_m2;
        diag.lambda[0] = self.lambda;
        diag.r_diag[0] = self.r_gain_m2;
        diag.nis = self.nis;
        diag.dim = 1;
        diag.filter_kind = insuwb_msg::FilterKind::IakfTdoa as u32;
        let mut flags = diag.header.flags
            & !(insuwb_msg::FilterDiag::FLAG_OUTLIER | insuwb_msg::FilterDiag::FLAG_DIVERGENCE);
        if self.lambda < 1.0 {
            flags |= insuwb_msg::FilterDiag::FLAG_OUTLIER;
        }
        if self.needs_reset {
            flags |= insuwb_msg::FilterDiag::FLAG_DIVERGENCE;
        }
        diag.header.flags = flags;
    }
}

/// Diagnostics of one 3D position update.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PositionUpdateReport {
    /// Innovation `z - (p_ins + C l) - H δx`, ENU, m.
    pub innovation_m: [f64; 3],
    /// Normalised innovation squared `v^T S^-1 v` (3 degrees of freedom).
    pub nis: f64,
    /// Rejected: `sqrt(nis)` beyond `hard_gate_sigma`.
    pub rejected: bool,
}

/// Counters since construction.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct EskfStats {
    /// Prediction steps.
    pub predicts: u64,
    /// TDOA measurements applied with full weight.
    pub accepted: u64,
    /// TDOA measurements applied with reduced weight.
    pub downweighted: u64,
    /// TDOA measurements rejected by the hard gate.
    pub rejected: u64,
    /// TDOA measurements skipped by the per-pair decimation.
    pub decimated: u64,
    /// Position updates applied.
    pub position_updates: u64,
    /// Resets.
    pub resets: u64,
}

/// The TDOA measurement model evaluated at the INS state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TdoaModel {
    /// Predicted `|p_ant - b| - |p_ant - a|`, m.
    pub predicted_m: f64,
    /// Jacobian row with respect to the error state: `[-u^T, 0, u^T [(C l) x], 0, 0]`
    /// with `u = (p_ant - b)/|p_ant - b| - (p_ant - a)/|p_ant - a|`.
    pub h: StateVector,
}

/// Why a prediction step was refused (the filter is unchanged).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum PredictError {
    /// An input holds NaN or an infinity.
    #[error("predict: {input} is not finite ({value})")]
    NonFinite {
        /// Which input.
        input: &'static str,
        /// The offending value.
        value: f64,
    },
    /// The attitude quaternion is not of unit norm.
    #[error("predict: quaternion norm {norm} is not 1")]
    QuatNotUnit {
        /// Its norm.
        norm: f64,
    },
    /// The step is negative or longer than `max_dt_s`.
    #[error("predict: dt {dt_s} s outside [0, {max_dt_s}] s")]
    DtOutOfRange {
        /// The step asked for, s.
        dt_s: f64,
        /// The configured maximum, s.
        max_dt_s: f64,
    },
}

/// Why a TDOA update was refused (the filter is unchanged).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum TdoaUpdateError {
    /// An input holds NaN or an infinity.
    #[error("TDOA update: {input} is not finite ({value})")]
    NonFinite {
        /// Which input.
        input: &'static str,
        /// The offending value.
        value: f64,
    },
    /// The attitude quaternion is not of unit norm.
    #[error("TDOA update: quaternion norm {norm} is not 1")]
    QuatNotUnit {
        /// Its norm.
        norm: f64,
    },
    /// The antenna sits on an anchor: the measurement gradient is undefined.
    #[error("TDOA update: antenna {distance_m} m from an anchor")]
    AntennaAtAnchor {
        /// The distance, m.
        distance_m: f64,
    },
}

/// Why a position update was refused (the filter is unchanged).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum PositionUpdateError {
    /// An input holds NaN or an infinity.
    #[error("position update: {input} is not finite ({value})")]
    NonFinite {
        /// Which input.
        input: &'static str,
        /// The offending value.
        value: f64,
    },
    /// The attitude quaternion is not of unit norm.
    #[error("position update: quaternion norm {norm} is not 1")]
    QuatNotUnit {
        /// Its norm.
        norm: f64,
    },
    /// The fix covariance is not symmetric positive definite.
    #[error("position update: fix covariance is not symmetric positive definite (entry [{row}][{col}] = {value})")]
    CovarianceNotPd {
        /// Row of the first offending entry (diagonal when not PD).
        row: usize,
        /// Its column.
        col: usize,
        /// Its value.
        value: f64,
    },
}

/// Why a reset covariance was refused (the filter is unchanged).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum ResetError {
    /// The covariance is not finite, not symmetric or not positive definite.
    #[error(
        "reset: covariance is not symmetric positive definite (entry [{row}][{col}] = {value})"
    )]
    CovarianceNotPd {
        /// Row of the first offending entry.
        row: usize,
        /// Its column.
        col: usize,
        /// Its value.
        value: f64,
    },
}

macro_rules! from_fault {
    ($t:ident) => {
        impl From<InputFault> for $t {
            fn from(f: InputFault) -> Self {
                match f {
                    InputFault::NonFinite { input, value } => $t::NonFinite { input, value },
                    InputFault::QuatNorm { norm } => $t::QuatNotUnit { norm },
                }
            }
        }
    };
}
from_fault!(PredictError);
from_fault!(TdoaUpdateError);
from_fault!(PositionUpdateError);

/// Last applied update time of one unordered anchor pair.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct PairSlot {
    used: bool,
    /// Bit patterns of the two anchor positions, smaller one first.
    key: [u64; 6],
    last_time_s: f64,
}

fn pair_key(a: &[f64; 3], b: &[f64; 3]) -> [u64; 6] {
    let ka = a.map(f64::to_bits);
    let kb = b.map(f64::to_bits);
    let (lo, hi) = if ka <= kb { (ka, kb) } else { (kb, ka) };
    [lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]]
}

/// The velocity rows of the continuous error dynamics `F`:
/// `δv̇ = a_vθ δθ + a_vb δb_a + a_vv δv` (see [`transition_matrix`] and
/// [`Eskf::set_multirotor`]).
#[derive(Debug, Clone, Copy)]
pub(crate) struct VelRows {
    /// `-[f x]`, plus the drag's attitude term for a multirotor.
    a_vtheta: Matrix3<f64>,
    /// `C`, or `C diag(0, 0, 1)` for a multirotor (only the thrust axis's
    /// bias enters the integrated force).
    a_vb: Matrix3<f64>,
    /// Zero, or the drag's `-k C diag(1, 1, 0) C^T` for a multirotor.
    a_vv: Option<Matrix3<f64>>,
}

/// Applies the continuous error dynamics `F` to `x` (15 x C), using its
/// sparsity: rows δp <- δv; δv <- a_vθ δθ + a_vb δb_a (+ a_vv δv);
/// δθ <- C δb_g.
pub(crate) fn apply_f<const C: usize>(
    rows: &VelRows,
    rot: &Matrix3<f64>,
    x: &SMatrix<f64, N_STATES, C>,
) -> SMatrix<f64, N_STATES, C> {
    let mut y = SMatrix::<f64, N_STATES, C>::zeros();
    y.fixed_view_mut::<3, C>(IDX_POS, 0)
        .copy_from(&x.fixed_view::<3, C>(IDX_VEL, 0));
    let mut vel = rows.a_vtheta * x.fixed_view::<3, C>(IDX_ATT, 0)
        + rows.a_vb * x.fixed_view::<3, C>(IDX_ACCEL_BIAS, 0);
    if let Some(a_vv) = rows.a_vv {
        vel += a_vv * x.fixed_view::<3, C>(IDX_VEL, 0);
    }
    y.fixed_view_mut::<3, C>(IDX_VEL, 0).copy_from(&vel);
    y.fixed_view_mut::<3, C>(IDX_ATT, 0)
        .copy_from(&(rot * x.fixed_view::<3, C>(IDX_GYRO_BIAS, 0)));
    y
}

fn symmetrize(p: &mut Covariance) {
    for i in 0..N_STATES {
        for j in (i + 1)..N_STATES {
            let m = 0.5 * (p[(i, j)] + p[(j, i)]);
            p[(i, j)] = m;
            p[(j, i)] = m;
        }
    }
}

/// Checks a covariance: finite, symmetric (relative 1e-9), positive definite.
fn check_covariance<const D: usize>(p: &SMatrix<f64, D, D>) -> Result<(), (usize, usize, f64)> {
    for i in 0..D {
        for j in 0..D {
            let (a, b) = (p[(i, j)], p[(j, i)]);
            let scale = p[(i, i)].abs().max(p[(j, j)].abs()).max(f64::MIN_POSITIVE);
            if !a.is_finite() || (a - b).abs() > 1e-9 * scale {
                return Err((i, j, a));
            }
        }
    }
    if p.cholesky().is_none() {
        let worst = (0..D)
            .min_by(|&i, &j| p[(i, i)].total_cmp(&p[(j, j)]))
            .unwrap_or(0);
        return Err((worst, worst, p[(worst, worst)]));
    }
    Ok(())
}

/// The continuous-time white-noise process noise of one step `dt`
/// (first order, `Q_d = G Q_c G^T dt`): `sigma_a^2 dt` on δv, `sigma_g^2 dt`
/// on δθ (isotropic noise, so the rotation to ENU drops out), the bias random
/// walks on δb_a and δb_g; none on δp.
#[must_use]
pub fn process_noise(config: &EskfConfig, dt_s: f64) -> SVector<f64, N_STATES> {
    let mut q = SVector::<f64, N_STATES>::zeros();
    let blocks = [
        (IDX_VEL, config.accel_noise_mps2_per_rthz),
        (IDX_ATT, config.gyro_noise_rps_per_rthz),
        (IDX_ACCEL_BIAS, config.accel_bias_rw_mps3_per_rthz),
        (IDX_GYRO_BIAS, config.gyro_bias_rw_rps2_per_rthz),
    ];
    for (idx, density) in blocks {
        q.fixed_rows_mut::<3>(idx).fill(density * density * dt_s);
    }
    q
}

/// The discrete transition `Φ = I + F dt` of the error state for one step.
///
/// `F` (global-angle-error ESKF, Solà 2017 §7, with this crate's signs):
/// `δṗ = δv`, `δv̇ = -[f_n x] δθ + C δb_a`, `δθ̇ = C δb_g`, `δḃ = w`, where
/// `C` is the body-to-ENU rotation of `quat` and `f_n` the specific force in
/// ENU. (With the attitude error in the navigation frame the body rate does
/// not enter `F`.) [`Eskf::predict`] applies exactly `Φ P Φ^T + Q`, using
/// the sparsity of `F`.
///
/// # Errors
/// [`PredictError`] on a non-finite input, a non-unit quaternion or a negative `dt_s`.
pub fn transition_matrix(
    dt_s: f64,
    quat: [f64; 4],
    f_nav_mps2: [f64; 3],
) -> Result<Covariance, PredictError> {
    finite("dt_s", &[dt_s])?;
    finite("f_nav_mps2", &f_nav_mps2)?;
    let rot = checked_rotation(quat)?;
    if dt_s < 0.0 {
        return Err(PredictError::DtOutOfRange {
            dt_s,
            max_dt_s: f64::INFINITY,
        });
    }
    let rows = VelRows {
        a_vtheta: -skew(&Vector3::from(f_nav_mps2)),
        a_vb: rot,
        a_vv: None,
    };
    Ok(Covariance::identity() + apply_f(&rows, &rot, &Covariance::identity()) * dt_s)
}

/// Evaluates the TDOA model `|p_ant - b| - |p_ant - a|`, `p_ant = p + C(q) l`,
/// and its Jacobian row with respect to the error state.
///
/// With `p_true = p_ins - δp` and `C_true = Exp(-δθ) C_ins`, the true antenna
/// is `p_ant - δp + [(C l) x] δθ` to first order, hence
/// `H = [-u^T, 0, u^T [(C l) x], 0, 0]`.
///
/// # Errors
/// [`TdoaUpdateError`] on a non-finite input, a non-unit quaternion or an
/// antenna on an anchor.
pub fn tdoa_model(
    p_ins_m: [f64; 3],
    quat: [f64; 4],
    lever_arm_body_m: [f64; 3],
    anchor_a_m: [f64; 3],
    anchor_b_m: [f64; 3],
) -> Result<TdoaModel, TdoaUpdateError> {
    finite("p_ins_m", &p_ins_m)?;
    finite("lever_arm_body_m", &lever_arm_body_m)?;
    finite("anchor_a_m", &anchor_a_m)?;
    finite("anchor_b_m", &anchor_b_m)?;
    let rot = checked_rotation(quat)?;
    let lever_nav = rot * Vector3::from(lever_arm_body_m);
    let p_ant = Vector3::from(p_ins_m) + lever_nav;
    let to_a = p_ant - Vector3::from(anchor_a_m);
    let to_b = p_ant - Vector3::from(anchor_b_m);
    let (da, db) = (to_a.norm(), to_b.norm());
    if da < MIN_ANCHOR_DIST_M || db < MIN_ANCHOR_DIST_M {
        return Err(TdoaUpdateError::AntennaAtAnchor {
            distance_m: da.min(db),
        });
    }
    let u = to_b / db - to_a / da;
    let mut h = StateVector::zeros();
    h.fixed_rows_mut::<3>(IDX_POS).copy_from(&(-u));
    // u^T [l x] as a column: ([l x]^T u) = -[l x] u = u x l.
    h.fixed_rows_mut::<3>(IDX_ATT)
        .copy_from(&u.cross(&lever_nav));
    Ok(TdoaModel {
        predicted_m: db - da,
        h,
    })
}

/// The measurement model of one two-way range to `anchor_m` at the INS
/// state: predicted `|p_ant - a|` and `H = [-u^T, 0, u^T [(C l) x], 0, 0]`
/// with `u = (p_ant - a)/|p_ant - a|` (as [`tdoa_model`], one anchor).
///
/// # Errors
/// [`TdoaUpdateError`] on a non-finite input, a non-unit quaternion or an
/// antenna on the anchor.
pub fn range_model(
    p_ins_m: [f64; 3],
    quat: [f64; 4],
    lever_arm_body_m: [f64; 3],
    anchor_m: [f64; 3],
) -> Result<TdoaModel, TdoaUpdateError> {
    finite("p_ins_m", &p_ins_m)?;
    finite("lever_arm_body_m", &lever_arm_body_m)?;
    finite("anchor_m", &anchor_m)?;
    let rot = checked_rotation(quat)?;
    let lever_nav = rot * Vector3::from(lever_arm_body_m);
    let to_a = Vector3::from(p_ins_m) + lever_nav - Vector3::from(anchor_m);
    let da = to_a.norm();
    if da < MIN_ANCHOR_DIST_M {
        return Err(TdoaUpdateError::AntennaAtAnchor { distance_m: da });
    }
    let u = to_a / da;
    let mut h = StateVector::zeros();
    h.fixed_rows_mut::<3>(IDX_POS).copy_from(&(-u));
    h.fixed_rows_mut::<3>(IDX_ATT)
        .copy_from(&u.cross(&lever_nav));
    Ok(TdoaModel { predicted_m: da, h })
}

/// The tightly coupled error-state Kalman filter (15 states, closed loop).
///
/// The INS integrates the nominal state; this filter propagates the error
/// covariance with the nominal values it is given ([`Eskf::predict`]),
/// updates with each TDOA difference ([`Eskf::update_tdoa`]) and hands its
/// error estimate back with [`Eskf::take_correction`], after which the INS
/// applies it and the error state is zero again. Time is the sum of the
/// `dt_s` given to `predict` (used by the per-pair decimation, the
/// correlation inflation and the process-noise scale).
///
/// ```
/// use insuwb_eskf::{Eskf, EskfConfig, TdoaOutcome};
/// let mut f = Eskf::new(EskfConfig::default()).unwrap();
/// let q = [1.0, 0.0, 0.0, 0.0]; // level, facing east
/// f.predict(0.001, q, [0.0, 0.0, 9.81]).unwrap(); // at rest
/// // The INS believes it is at the origin at 1.5 m; the TDOA says 0.3 m more
/// // range to anchor B than the INS predicts.
/// let (a, b, p_ins) = ([-4.0, -4.0, 0.2], [4.0, -4.0, 3.0], [0.0, 0.0, 1.5]);
/// let dist = |x: [f64; 3], y: [f64; 3]| ((x[0] - y[0]).powi(2) + (x[1] - y[1]).powi(2) + (x[2] - y[2]).powi(2)).sqrt();
/// let z = dist(p_ins, b) - dist(p_ins, a) + 0.3;
/// let rep = f.update_tdoa(p_ins, q, [0.0; 3], a, b, z).unwrap();
/// assert_eq!(rep.outcome, TdoaOutcome::Accepted);
/// assert!((rep.innovation_m - 0.3).abs() < 1e-12);
/// let c = f.take_correction(); // for the INS: pos -= d_pos_m, ...
/// assert!(c.d_pos_m.iter().any(|x| x.abs() > 1e-3));
/// assert_eq!(f.state().norm(), 0.0);
/// ```
#[derive(Debug, Clone)]
pub struct Eskf {
    config: EskfConfig,
    x: StateVector,
    p: Covariance,
    p0: Covariance,
    time_s: f64,
    nis_last: Option<f64>,
    needs_reset: bool,
    pairs: [PairSlot; PAIR_SLOTS],
    stats: EskfStats,
    q_adapt: QAdapt,
    /// The learnt TDOA and range sigmas ([`EskfConfig::tdoa_sigma_adapt_time_s`]).
    r_adapt: [RAdapt; 2],
    /// The specific force of the last prediction step, ENU, m/s^2.
    f_last: [f64; 3],
    /// Velocity noise density added to the accelerometer's, m^2/s^3
    /// ([`Eskf::set_extra_velocity_noise`]).
    q_vel_extra: f64,
    /// The multirotor error dynamics ([`Eskf::set_multirotor`]); `None`: free.
    multirotor: Option<MultirotorDynamics>,
    /// Factor on the TDOA sigma of the updates that follow
    /// ([`Eskf::set_tdoa_sigma_scale`]).
    tdoa_sigma_scale: f64,
    /// The anchors' TDOA error states ([`EskfConfig::tdoa_anchor_sigma_m`]).
    anchors: AnchorErrors,
}

/// The multirotor model's parameters in the error dynamics
/// ([`Eskf::set_multirotor`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MultirotorDynamics {
    /// Linear drag coefficient the error dynamics assume, 1/s: the velocity
    /// damping of the filter's model of the vehicle.
    pub drag_per_s: f64,
    /// Linear drag coefficient the INS integrates, 1/s. Where the model's
    /// damping is larger, the true velocity decays faster than the INS's,
    /// and the error state's mean takes up the difference,
    /// `δv̇ += (k - k_ins) C diag(1, 1, 0) C^T v` (closed loop: the next
    /// correction hands it to the INS).
    pub ins_drag_per_s: f64,
    /// White-noise density of the unmodelled body x/y force, m/s^2/sqrt(Hz).
    pub model_noise_mps2_per_rthz: f64,
}

/// What a pseudo-measurement update did ([`Eskf::update_pseudo`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PseudoUpdateReport {
    /// Normalised innovation squared.
    pub nis: f64,
    /// Applied (not beyond the hard gate).
    pub applied: bool,
}

/// Why a pseudo-measurement was refused (the filter is unchanged).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum PseudoUpdateError {
    /// The Jacobian row or the innovation holds NaN or an infinity.
    #[error("pseudo-measurement: Jacobian or innovation not finite")]
    NonFinite,
    /// The variance is not finite and positive.
    #[error("pseudo-measurement: variance {0} must be finite and > 0")]
    Variance(f64),
}

/// Updates the process-noise scale looks back over (median window).
const Q_ADAPT_WINDOW: usize = 128;
/// Fewest updates in the window before the scale moves.
const Q_ADAPT_MIN: usize = 32;
/// Median of a chi-square variable with one degree of freedom.
const CHI2_1_MEDIAN: f64 = 0.454_936_4;
/// Density of a chi-square variable with one degree of freedom at its median.
const CHI2_1_MEDIAN_DENSITY: f64 = 0.471_1;

/// The last applied updates' squared innovations and predicted parts,
/// which the process-noise scale and the learnt UWB sigmas read.
#[derive(Debug, Clone, Copy, PartialEq)]
struct InnovationWindow {
    /// Squared innovations, m^2 (ring).
    v2: [f64; Q_ADAPT_WINDOW],
    /// Their predicted parts `H P H^T`, m^2 (ring).
    hph: [f64; Q_ADAPT_WINDOW],
    len: usize,
    next: usize,
    /// Filter time of the last update taken, s.
    last_s: Option<f64>,
}

impl InnovationWindow {
    const fn new() -> Self {
        Self {
            v2: [0.0; Q_ADAPT_WINDOW],
            hph: [0.0; Q_ADAPT_WINDOW],
            len: 0,
            next: 0,
            last_s: None,
        }
    }

    /// Takes one update's innovation `v` and predicted part `hph` at filter
    /// time `t_s`; once the window holds [`Q_ADAPT_MIN`] updates and time
    /// moved, returns the medians of `v^2` and of `H P H^T` and the time
    /// since the previous update.
    fn push(&mut self, v: f64, hph: f64, t_s: f64) -> Option<(f64, f64, f64)> {
        if let (Some(x), Some(y)) = (self.v2.get_mut(self.next), self.hph.get_mut(self.next)) {
            *x = v * v;
            *y = hph;
        }
        self.next = (self.next + 1) % Q_ADAPT_WINDOW;
        self.len = (self.len + 1).min(Q_ADAPT_WINDOW);
        let dt = self.last_s.map_or(0.0, |t| (t_s - t).max(0.0));
        self.last_s = Some(t_s);
        if self.len < Q_ADAPT_MIN || dt <= 0.0 {
            return None;
        }
        Some((
            median_of(&self.v2, self.len)?,
            median_of(&self.hph, self.len)?,
            dt,
        ))
    }
}

/// State of the innovation-based process-noise scale
/// ([`EskfConfig::q_adapt_time_s`]).
#[derive(Debug, Clone, Copy, PartialEq)]
struct QAdapt {
    /// The scale on `Q`, in `[1, q_scale_max]`.
    alpha: f64,
    window: InnovationWindow,
}

impl QAdapt {
    const fn new() -> Self {
        Self {
            alpha: 1.0,
            window: InnovationWindow::new(),
        }
    }
}

/// Which learnt UWB noise an update feeds and uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum UwbNoise {
    Tdoa = 0,
    Range = 1,
}

/// State of a learnt UWB measurement sigma
/// ([`EskfConfig::tdoa_sigma_adapt_time_s`]).
#[derive(Debug, Clone, Copy, PartialEq)]
struct RAdapt {
    /// The variance used, m^2 (`None`: the configured one, nothing learnt yet).
    sigma2: Option<f64>,
    window: InnovationWindow,
}

impl RAdapt {
    const fn new() -> Self {
        Self {
            sigma2: None,
            window: InnovationWindow::new(),
        }
    }

    /// Takes one applied update's innovation `v` and predicted part `hph`
    /// at filter time `t_s`, and moves the variance used towards the
    /// window's (time constant `tau_s`, bounded in `[min2, max2]`).
    fn push(&mut self, v: f64, hph: f64, t_s: f64, tau_s: f64, min2: f64, max2: f64) {
        let Some((m_v2, m_hph, dt)) = self.window.push(v, hph, t_s) else {
            return;
        };
        let target = (m_v2 / CHI2_1_MEDIAN - m_hph).clamp(min2, max2);
        let cur = self.sigma2.unwrap_or(max2);
        self.sigma2 = Some(cur + (target - cur) * (1.0 - (-dt / tau_s).exp()));
    }
}

/// Median of the first `n` values of `vals` (copied; `None` when empty).
fn median_of(vals: &[f64; Q_ADAPT_WINDOW], n: usize) -> Option<f64> {
    let mut buf = *vals;
    let work = buf.get_mut(..n)?;
    if work.is_empty() {
        return None;
    }
    let (_, m, _) = work.select_nth_unstable_by(n / 2, f64::total_cmp);
    Some(*m)
}

impl Eskf {
    /// A filter with zero error state and the configured initial covariance.
    ///
    /// # Errors
    /// [`EskfConfigError`] naming the first invalid key.
    pub fn new(config: EskfConfig) -> Result<Self, EskfConfigError> {
        config.validate()?;
        let p0 = Self::initial_covariance(&config);
        Ok(Self {
            x: StateVector::zeros(),
            p: p0,
            p0,
            time_s: 0.0,
            nis_last: None,
            needs_reset: false,
            pairs: [PairSlot::default(); PAIR_SLOTS],
            stats: EskfStats::default(),
            q_adapt: QAdapt::new(),
            r_adapt: [RAdapt::new(); 2],
            f_last: [0.0; 3],
            q_vel_extra: 0.0,
            multirotor: None,
            tdoa_sigma_scale: 1.0,
            anchors: AnchorErrors::new(
                config.tdoa_anchor_sigma_m,
                config.tdoa_anchor_corr_time_s,
                config.tdoa_anchor_highpass_s,
            ),
            config,
        })
    }

    /// The diagonal initial covariance of a configuration: position,
    /// velocity, roll/pitch (δθ east and north), yaw (δθ up) and bias sigmas.
    ///
    /// The attitude error is an ENU rotation vector, so its up component is
    /// the yaw error whatever the heading, and its east/north components are
    /// tilt errors.
    #[must_use]
    pub fn initial_covariance(config: &EskfConfig) -> Covariance {
        let sig = [
            config.init_pos_sigma_m,
            config.init_pos_sigma_m,
            config.init_pos_sigma_m,
            config.init_vel_sigma_mps,
            config.init_vel_sigma_mps,
            config.init_vel_sigma_mps,
            config.init_roll_pitch_sigma_rad,
            config.init_roll_pitch_sigma_rad,
            config.init_yaw_sigma_rad,
            config.init_accel_bias_sigma_mps2,
            config.init_accel_bias_sigma_mps2,
            config.init_accel_bias_sigma_mps2,
            config.init_gyro_bias_sigma_rps,
            config.init_gyro_bias_sigma_rps,
            config.init_gyro_bias_sigma_rps,
        ];
        Covariance::from_diagonal(&StateVector::from(sig.map(|s| s * s)))
    }

    /// The configuration in use.
    #[must_use]
    pub fn config(&self) -> &EskfConfig {
        &self.config
    }

    /// Propagates the error state and its covariance over `dt_s` with the
    /// nominal attitude `quat` (`[w, x, y, z]`, body to ENU) and specific
    /// force `f_nav_mps2` in ENU (`accel_nav + [0, 0, g]`):
    /// `P <- Φ P Φ^T + Q` with `Φ = I + F dt` ([`transition_matrix`]) and `Q`
    /// from [`process_noise`]; `P` is kept exactly symmetric. Allocation-free.
    /// A zero `dt_s` does nothing. Pass the INS's attitude and specific force
    /// over the step (e.g. at its middle). `F` couples yaw error to velocity
    /// through the horizontal part of `f_nav_mps2`, so accelerometer noise
    /// passed here acts as "acceleration" and lends the yaw some spurious
    /// observability; with strong low-frequency vibration pass a smoothed
    /// specific force.
    ///
    /// # Errors
    /// [`PredictError`] on a non-finite input, a non-unit quaternion or a
    /// step outside `[0, max_dt_s]`; the filter is then unchanged.
    pub fn predict(
        &mut self,
        dt_s: f64,
        quat: [f64; 4],
        f_nav_mps2: [f64; 3],
    ) -> Result<(), PredictError> {
        self.predict_moving(dt_s, quat, f_nav_mps2, [0.0; 3])
    }

    /// [`Eskf::predict`] with the INS velocity `vel_nav_mps` (ENU), which
    /// the multirotor model's drag terms need ([`Eskf::set_multirotor`]);
    /// for a free vehicle the velocity does not enter `F` and this is
    /// [`Eskf::predict`].
    ///
    /// # Errors
    /// As [`Eskf::predict`], and a non-finite velocity.
    pub fn predict_moving(
        &mut self,
        dt_s: f64,
        quat: [f64; 4],
        f_nav_mps2: [f64; 3],
        vel_nav_mps: [f64; 3],
    ) -> Result<(), PredictError> {
        finite("dt_s", &[dt_s])?;
        finite("f_nav_mps2", &f_nav_mps2)?;
        finite("vel_nav_mps", &vel_nav_mps)?;
        let rot = checked_rotation(quat)?;
        if !(0.0..=self.config.max_dt_s).contains(&dt_s) {
            return Err(PredictError::DtOutOfRange {
                dt_s,
                max_dt_s: self.config.max_dt_s,
            });
        }
        if dt_s == 0.0 {
            return Ok(());
        }
        self.f_last = f_nav_mps2;
        let mut rows = VelRows {
            a_vtheta: -skew(&Vector3::from(f_nav_mps2)),
            a_vb: rot,
            a_vv: None,
        };
        // C diag(1, 1, 0) C^T: the body x/y plane in ENU (multirotor only).
        let horizontal_body = self
            .multirotor
            .map(|_| rot * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 0.0)) * rot.transpose());
        if let (Some(m), Some(plane)) = (self.multirotor, horizontal_body) {
            // Body x/y force -k E C^T v: its error is -k C E C^T (δv + [v x] δθ);
            // only the thrust axis's bias is integrated.
            let drag = plane * (-m.drag_per_s);
            rows.a_vtheta += drag * skew(&Vector3::from(vel_nav_mps));
            rows.a_vv = Some(drag);
            rows.a_vb = rot * Matrix3::from_diagonal(&Vector3::new(0.0, 0.0, 1.0));
        }
        // Φ P Φ^T = P + dt (F P + P F^T) + dt^2 F P F^T, with F P F^T = F (F P)^T.
        let fp = apply_f(&rows, &rot, &self.p);
        let fpft = apply_f(&rows, &rot, &fp.transpose());
        self.p += (fp + fp.transpose()) * dt_s + fpft * (dt_s * dt_s);
        self.anchors.predict(dt_s, |m| apply_f(&rows, &rot, m));
        let q = process_noise(&self.config, dt_s);
        // The scale applies to the accelerometer's noise and bias walk: the
        // position innovations it is read from measure the velocity drift.
        let alpha = self.q_adapt.alpha;
        for i in 0..N_STATES {
            let vel = (IDX_VEL..IDX_VEL + 3).contains(&i);
            if vel && self.multirotor.is_some() {
                continue;
            }
            let accel = vel || (IDX_ACCEL_BIAS..IDX_ACCEL_BIAS + 3).contains(&i);
            self.p[(i, i)] += if accel { alpha * q[i] } else { q[i] };
        }
        if let Some(m) = self.multirotor {
            // The model's error (unmodelled forces) in body x/y, the
            // accelerometer's noise on the thrust axis: C diag C^T.
            let (sm, sa) = (
                m.model_noise_mps2_per_rthz,
                self.config.accel_noise_mps2_per_rthz,
            );
            let d = Matrix3::from_diagonal(&Vector3::new(sm * sm, sm * sm, sa * sa));
            let qv = rot * d * rot.transpose() * (alpha * dt_s);
            let mut block = self.p.fixed_view_mut::<3, 3>(IDX_VEL, IDX_VEL);
            block += qv;
        }
        for i in IDX_VEL..IDX_VEL + 2 {
            self.p[(i, i)] += self.q_vel_extra * dt_s;
        }
        symmetrize(&mut self.p);
        if self.x.iter().any(|&v| v != 0.0) {
            self.x += apply_f(&rows, &rot, &self.x) * dt_s;
        }
        if let (Some(m), Some(plane)) = (self.multirotor, horizontal_body) {
            let extra = m.drag_per_s - m.ins_drag_per_s;
            if extra != 0.0 {
                let dv = plane * Vector3::from(vel_nav_mps) * (extra * dt_s);
                let mut v = self.x.fixed_rows_mut::<3>(IDX_VEL);
                v += dv;
            }
        }
        self.time_s += dt_s;
        self.stats.predicts += 1;
        if !self.p.iter().all(|v| v.is_finite()) {
            self.needs_reset = true;
        }
        Ok(())
    }

    /// Turns on the radio's height state (`crate::anchor_error`, "The
    /// radio's height"): the height at which the UWB places the tag above
    /// the vehicle's, a Gauss-Markov state of stationary sigma `sigma_m`
    /// and correlation time `corr_time_s`, starting at zero; for a filter
    /// that measures its height another way (a range finder), so that the
    /// radio's height error is not read as the vehicle's. Nothing when it
    /// is on already; `false`, the filter unchanged, for values that are
    /// not finite and positive. A reset ([`Eskf::reset`]) turns it off.
    pub fn enable_radio_height(&mut self, sigma_m: f64, corr_time_s: f64) -> bool {
        if !(sigma_m.is_finite() && sigma_m > 0.0 && corr_time_s.is_finite() && corr_time_s > 0.0) {
            return false;
        }
        self.anchors.enable_height(sigma_m, corr_time_s);
        true
    }

    /// Resumes the radio's height state (a checkpoint's
    /// [`Eskf::radio_height_error`]) at `value_m` with sigma
    /// `value_sigma_m`, uncorrelated with the other states, turning it on
    /// as [`Eskf::enable_radio_height`] does where it is off; `false`, the
    /// filter unchanged, for a value that is not finite, a sigma that is
    /// not finite and positive, or a state that cannot be turned on.
    pub fn restore_radio_height(
        &mut self,
        sigma_m: f64,
        corr_time_s: f64,
        value_m: f64,
        value_sigma_m: f64,
    ) -> bool {
        let config_ok =
            sigma_m.is_finite() && sigma_m > 0.0 && corr_time_s.is_finite() && corr_time_s > 0.0;
        if !(config_ok && value_m.is_finite() && value_sigma_m.is_finite() && value_sigma_m > 0.0) {
            return false;
        }
        self.anchors
            .set_height(sigma_m, corr_time_s, value_m, value_sigma_m);
        true
    }

    /// The radio's height error and its sigma, m, while that state is on
    /// ([`Eskf::enable_radio_height`]).
    #[must_use]
    pub fn radio_height_error(&self) -> Option<(f64, f64)> {
        self.anchors.height_error()
    }

    /// Switches the error dynamics to the multirotor model of
    /// `insuwb_nav::vehicle` (thrust along body z, linear drag
    /// `drag_per_s` in body x/y), as the INS integrates it: the velocity
    /// error is driven by the attitude error through the thrust, damped by
    /// the drag, and only the z accelerometer bias enters it; the velocity
    /// noise is `model_noise_mps2_per_rthz` in body x/y (unmodelled forces)
    /// and the accelerometer's on body z. `None` returns to the free model.
    /// Values that are not finite and non-negative are refused (`false`,
    /// the filter unchanged).
    pub fn set_multirotor(&mut self, model: Option<MultirotorDynamics>) -> bool {
        if let Some(m) = model {
            let ok = [m.drag_per_s, m.ins_drag_per_s, m.model_noise_mps2_per_rthz]
                .iter()
                .all(|v| v.is_finite() && *v >= 0.0);
            if !ok {
                return false;
            }
        }
        self.multirotor = model;
        true
    }

    /// The multirotor dynamics in use ([`Eskf::set_multirotor`]).
    #[must_use]
    pub fn multirotor(&self) -> Option<MultirotorDynamics> {
        self.multirotor
    }

    /// Fuses a scalar pseudo-measurement with Jacobian row `h`, innovation
    /// `innovation` (measurement minus its prediction at the INS state,
    /// before the error state; `h · δx` is removed here) and variance
    /// `r` (> 0): a velocity constraint or a drag measurement, composed by
    /// the caller. Robust as the TDOA updates (`kappa`, `hard_gate_sigma`,
    /// `limit_mode`), but outside the process-noise adaptation and the pair
    /// bookkeeping. Returns the NIS and whether it was applied.
    ///
    /// # Errors
    /// [`PseudoUpdateError`] on a non-finite input or a variance that is not
    /// positive; the filter is then unchanged.
    pub fn update_pseudo(
        &mut self,
        h: &StateVector,
        innovation: f64,
        r: f64,
    ) -> Result<PseudoUpdateReport, PseudoUpdateError> {
        self.pseudo_update(h, innovation, r, self.yaw_frozen())
    }

    /// [`Eskf::update_pseudo`] for one axis of a measured body-frame
    /// velocity (odometry, optical flow): such a measurement makes the yaw
    /// observable whenever the vehicle moves, so
    /// [`EskfConfig::yaw_min_excitation_mps2`] does not hold the yaw out of
    /// it (the TDOA and range updates stay held).
    ///
    /// # Errors
    /// As [`Eskf::update_pseudo`].
    pub fn update_body_velocity(
        &mut self,
        h: &StateVector,
        innovation: f64,
        r: f64,
    ) -> Result<PseudoUpdateReport, PseudoUpdateError> {
        self.pseudo_update(h, innovation, r, false)
    }

    /// The pseudo update, the yaw held out of it where `hold_yaw`.
    fn pseudo_update(
        &mut self,
        h: &StateVector,
        innovation: f64,
        r: f64,
        hold_yaw: bool,
    ) -> Result<PseudoUpdateReport, PseudoUpdateError> {
        if !innovation.is_finite() || !h.iter().all(|v| v.is_finite()) {
            return Err(PseudoUpdateError::NonFinite);
        }
        if !(r.is_finite() && r > 0.0) {
            return Err(PseudoUpdateError::Variance(r));
        }
        let v = innovation - h.dot(&self.x);
        let c = self.p * h;
        let (_, cb, _) = self.anchors.terms(h, &ErrorVector::zeros());
        let hph = h.dot(&c).max(0.0);
        let s = hph + r;
        let nis = v * v / s;
        let ratio = nis.sqrt();
        if ratio > self.config.hard_gate_sigma {
            return Ok(PseudoUpdateReport {
                nis,
                applied: false,
            });
        }
        let lambda = if ratio > self.config.kappa {
            self.config.kappa / ratio
        } else {
            1.0
        };
        let (v_used, r_gain) = match self.config.limit_mode {
            LimitMode::ScaleInnovation => (lambda * v, r),
            LimitMode::InflateR => (v, r / (lambda * lambda)),
        };
        self.scalar_update(&c, &cb, hph, r_gain, v_used, hold_yaw);
        Ok(PseudoUpdateReport { nis, applied: true })
    }

    /// Sets a horizontal velocity noise density (m^2/s^3) added to the
    /// accelerometer's in the predictions that follow (e.g. from the
    /// vibration the IMU measures); a value that is not finite and
    /// non-negative is taken as 0.
    pub fn set_extra_velocity_noise(&mut self, q_m2_per_s3: f64) {
        self.q_vel_extra = if q_m2_per_s3.is_finite() && q_m2_per_s3 >= 0.0 {
            q_m2_per_s3
        } else {
            0.0
        };
    }

    /// [`Eskf::predict`] from an INS state: specific force
    /// `accel_nav_mps2 + [0, 0, gravity_mps2]` and the state's quaternion.
    ///
    /// # Errors
    /// As [`Eskf::predict`].
    pub fn predict_from_nav(
        &mut self,
        dt_s: f64,
        nav: &insuwb_msg::NavState,
        gravity_mps2: f64,
    ) -> Result<(), PredictError> {
        let a = nav.accel_nav_mps2;
        self.predict(dt_s, nav.quat, [a[0], a[1], a[2] + gravity_mps2])
    }

    /// Sets the factor on the TDOA sigma (configured or learnt) of the
    /// updates that follow: a pair's noise relative to the typical pair's,
    /// from a site calibration (`insuwb_uwb::calibration`). 1 (the default)
    /// treats every pair alike; a value that is not finite and positive is
    /// taken as 1.
    pub fn set_tdoa_sigma_scale(&mut self, scale: f64) {
        self.tdoa_sigma_scale = if scale.is_finite() && scale > 0.0 {
            scale
        } else {
            1.0
        };
    }

    /// Fuses one TDOA measurement `diff_m = |p_ant - b| - |p_ant - a|`
    /// (`p_ant = p + C(q) lever`) taken at the INS state `(p_ins_m, quat)`.
    ///
    /// Steps: innovation `v = z - h(x_ins) - H δx` and marginal
    /// `S = H P H^T + tdoa_sigma^2`, `r = |v| / sqrt(S)`; the pair (unordered)
    /// is skipped if applied less than `min_interval_per_pair_s` ago; `r`
    /// beyond `hard_gate_sigma` rejects (counted); beyond `kappa` the weight
    /// is `lambda = kappa / r` ([`LimitMode::ScaleInnovation`]: innovation
    /// scaled by `lambda`, Huber; [`LimitMode::InflateR`]: gain `R` divided
    /// by `lambda^2`). The gain uses `R = tdoa_sigma^2 * tdoa_r_inflation *
    /// max(1, 2 tdoa_corr_time_s / dt_pair)` for time-correlated errors (see
    /// [`EskfConfig::tdoa_corr_time_s`]); `P` gets the Joseph-form update.
    /// The report's NIS is what the caller's divergence monitor reads
    /// (the fusion engine's `insuwb_filter::DivergenceMonitor`). Pairs are told
    /// apart by their anchor positions (bit-exact), in either order. A
    /// non-zero error state (no correction taken since the last update) is
    /// accounted for in `v`.
    ///
    /// # Errors
    /// [`TdoaUpdateError`] on a non-finite input, a non-unit quaternion or an
    /// antenna on an anchor; the filter is then unchanged.
    pub fn update_tdoa(
        &mut self,
        p_ins_m: [f64; 3],
        quat: [f64; 4],
        lever_arm_body_m: [f64; 3],
        anchor_a_m: [f64; 3],
        anchor_b_m: [f64; 3],
        diff_m: f64,
    ) -> Result<TdoaUpdateReport, TdoaUpdateError> {
        finite("diff_m", &[diff_m])?;
        let model = tdoa_model(p_ins_m, quat, lever_arm_body_m, anchor_a_m, anchor_b_m)?;
        let t = self.time_s;
        let mut hb = AnchorErrors::row(
            self.anchors.slot(&anchor_b_m, t),
            self.anchors.slot(&anchor_a_m, t),
        );
        if self.anchors.height_on() {
            // The radio places the tag at its height plus this state.
            hb[anchor_error::HEIGHT] = -model.h[IDX_POS + 2];
        }
        Ok(self.update_uwb(
            &model,
            &hb,
            diff_m,
            pair_key(&anchor_a_m, &anchor_b_m),
            UwbNoise::Tdoa,
        ))
    }

    /// Updates with one two-way range `range_m = |p_ant - anchor|` taken
    /// at the INS state `(p_ins_m, quat)` ([`range_model`]): the same
    /// robust weighting, gates, correlation inflation (per anchor) and
    /// process-noise adaptation as [`Eskf::update_tdoa`], with
    /// [`EskfConfig::range_sigma_m`] as the measurement's sigma and
    /// [`EskfConfig::range_corr_time_s`] as its correlation time.
    ///
    /// # Errors
    /// [`TdoaUpdateError`] on a non-finite input, a non-unit quaternion or an
    /// antenna on the anchor; the filter is then unchanged.
    pub fn update_range(
        &mut self,
        p_ins_m: [f64; 3],
        quat: [f64; 4],
        lever_arm_body_m: [f64; 3],
        anchor_m: [f64; 3],
        range_m: f64,
    ) -> Result<TdoaUpdateReport, TdoaUpdateError> {
        finite("range_m", &[range_m])?;
        let model = range_model(p_ins_m, quat, lever_arm_body_m, anchor_m)?;
        let mut hb = ErrorVector::zeros();
        if self.anchors.height_on() {
            hb[anchor_error::HEIGHT] = -model.h[IDX_POS + 2];
        }
        Ok(self.update_uwb(
            &model,
            &hb,
            range_m,
            pair_key(&anchor_m, &anchor_m),
            UwbNoise::Range,
        ))
    }

    /// The configured sigma and the learning time constant of a kind.
    fn noise_config(&self, kind: UwbNoise) -> (f64, f64) {
        match kind {
            UwbNoise::Tdoa => (
                self.config.tdoa_sigma_m,
                self.config.tdoa_sigma_adapt_time_s,
            ),
            UwbNoise::Range => (
                self.config.range_sigma_m,
                self.config.range_sigma_adapt_time_s,
            ),
        }
    }

    /// The TDOA and the range sigma in use, m: the configured ones, or
    /// what the innovations taught ([`EskfConfig::tdoa_sigma_adapt_time_s`]).
    #[must_use]
    pub fn uwb_sigmas_m(&self) -> (f64, f64) {
        (
            self.uwb_sigma2(UwbNoise::Tdoa).sqrt(),
            self.uwb_sigma2(UwbNoise::Range).sqrt(),
        )
    }

    /// What the filter learnt from its innovations, for a restarted filter
    /// to resume from (checkpoints): the process-noise scale and the learnt
    /// TDOA and range variances, m^2 (NaN where nothing was learnt).
    #[must_use]
    pub fn adaptive_state(&self) -> [f64; 3] {
        let learnt = |k: UwbNoise| {
            self.r_adapt
                .get(k as usize)
                .and_then(|a| a.sigma2)
                .unwrap_or(f64::NAN)
        };
        [
            self.q_adapt.alpha,
            learnt(UwbNoise::Tdoa),
            learnt(UwbNoise::Range),
        ]
    }

    /// Restores an [`Eskf::adaptive_state`]; false, the filter unchanged,
    /// when it does not fit: not three values, a scale outside `[1,
    /// q_scale_max]`, a learnt variance that is not NaN and not positive
    /// and finite.
    pub fn restore_adaptive_state(&mut self, state: &[f64]) -> bool {
        let &[alpha, tdoa, range] = state else {
            return false;
        };
        let var_ok = |v: f64| v.is_nan() || (v.is_finite() && v > 0.0);
        if !(1.0..=self.config.q_scale_max).contains(&alpha) || !var_ok(tdoa) || !var_ok(range) {
            return false;
        }
        self.q_adapt.alpha = alpha;
        for (k, v) in [(UwbNoise::Tdoa, tdoa), (UwbNoise::Range, range)] {
            if let Some(a) = self.r_adapt.get_mut(k as usize) {
                a.sigma2 = (!v.is_nan()).then_some(v);
            }
        }
        true
    }

    fn uwb_sigma2(&self, kind: UwbNoise) -> f64 {
        let (sigma, tau) = self.noise_config(kind);
        let learnt = self.r_adapt.get(kind as usize).and_then(|a| a.sigma2);
        match learnt {
            Some(s2) if tau > 0.0 => s2,
            _ => sigma * sigma,
        }
    }

    /// One scalar UWB update of measurement `z` with `model`, its pair slot
    /// `key` and the noise of its kind (see [`Eskf::update_tdoa`]).
    fn update_uwb(
        &mut self,
        model: &TdoaModel,
        hb: &ErrorVector,
        z: f64,
        key: [u64; 6],
        kind: UwbNoise,
    ) -> TdoaUpdateReport {
        let h = model.h;
        let (c_anchor, cb, hb_b) = self.anchors.terms(&h, hb);
        let v = z - model.predicted_m - h.dot(&self.x) - hb_b;
        let c = self.p * h + c_anchor;
        let hph = (h.dot(&c) + hb.dot(&cb)).max(0.0);
        let scale = match kind {
            UwbNoise::Tdoa => self.tdoa_sigma_scale,
            UwbNoise::Range => 1.0,
        };
        let sigma2 = self.uwb_sigma2(kind) * scale * scale;
        let s = hph + sigma2;
        let nis = v * v / s;
        let r = nis.sqrt();
        let mut report = TdoaUpdateReport {
            outcome: TdoaOutcome::Accepted,
            innovation_m: v,
            innovation_var_m2: s,
            r_gain_m2: 0.0,
            lambda: 0.0,
            nis,
            rejected: false,
            needs_reset: self.needs_reset,
            q_scale: self.q_adapt.alpha,
        };

        let slot = self.pairs.iter().position(|p| p.used && p.key == key);
        let dt_pair = slot
            .and_then(|i| self.pairs.get(i))
            .map_or(f64::INFINITY, |p| self.time_s - p.last_time_s);
        if self.config.min_interval_per_pair_s > 0.0
            && dt_pair < self.config.min_interval_per_pair_s
        {
            self.stats.decimated += 1;
            report.outcome = TdoaOutcome::Decimated;
            return report;
        }

        self.nis_last = Some(nis);

        if r > self.config.hard_gate_sigma {
            self.stats.rejected += 1;
            report.outcome = TdoaOutcome::Rejected;
            report.rejected = true;
            report.needs_reset = self.needs_reset;
            return report;
        }

        let lambda = if r > self.config.kappa {
            self.config.kappa / r
        } else {
            1.0
        };
        let corr_time = match kind {
            UwbNoise::Tdoa => self.config.tdoa_corr_time_s,
            UwbNoise::Range => self.config.range_corr_time_s,
        };
        let corr = if corr_time > 0.0 {
            (2.0 * corr_time / dt_pair.max(MIN_PAIR_DT_S)).max(1.0)
        } else {
            1.0
        };
        let r_gain = sigma2 * self.config.tdoa_r_inflation * corr;
        let (v_used, r_gain) = match self.config.limit_mode {
            LimitMode::ScaleInnovation => (lambda * v, r_gain),
            LimitMode::InflateR => (v, r_gain / (lambda * lambda)),
        };
        self.adapt_q(v, hph, sigma2);
        let (sigma_cfg, tau) = self.noise_config(kind);
        if tau > 0.0 {
            let min = self.config.sigma_adapt_min_m.min(sigma_cfg);
            let t = self.time_s;
            if let Some(a) = self.r_adapt.get_mut(kind as usize) {
                // What is learnt is the unscaled sigma.
                a.push(
                    v / scale,
                    hph / (scale * scale),
                    t,
                    tau,
                    min * min,
                    sigma_cfg * sigma_cfg,
                );
            }
        }
        self.scalar_update(&c, &cb, hph, r_gain, v_used, self.yaw_frozen());

        self.touch_pair(slot, key);
        if lambda < 1.0 {
            self.stats.downweighted += 1;
            report.outcome = TdoaOutcome::Downweighted;
        } else {
            self.stats.accepted += 1;
        }
        report.lambda = lambda;
        report.r_gain_m2 = r_gain;
        report.q_scale = self.q_adapt.alpha;
        report.needs_reset = self.needs_reset;
        report
    }

    /// Fuses a 3D position fix of the antenna (`pos_uwb_m`, covariance
    /// `cov_m2`) taken at the INS state `(p_ins_m, quat)`: `H = [-I, 0,
    /// [(C l) x], 0, 0]`, rejected when the Mahalanobis distance
    /// `sqrt(v^T S^-1 v)` exceeds `hard_gate_sigma`, otherwise a plain
    /// (unweighted) Joseph-form update. For initialisation checks and loose
    /// coupling.
    ///
    /// # Errors
    /// [`PositionUpdateError`] on a non-finite input, a non-unit quaternion
    /// or a fix covariance that is not symmetric positive definite.
    pub fn update_position(
        &mut self,
        p_ins_m: [f64; 3],
        quat: [f64; 4],
        lever_arm_body_m: [f64; 3],
        pos_uwb_m: [f64; 3],
        cov_m2: [[f64; 3]; 3],
    ) -> Result<PositionUpdateReport, PositionUpdateError> {
        finite("p_ins_m", &p_ins_m)?;
        finite("lever_arm_body_m", &lever_arm_body_m)?;
        finite("pos_uwb_m", &pos_uwb_m)?;
        let rot = checked_rotation(quat)?;
        let cov = Matrix3::from_fn(|i, j| cov_m2[i][j]);
        check_covariance(&cov).map_err(|(row, col, value)| {
            PositionUpdateError::CovarianceNotPd { row, col, value }
        })?;
        let lever_nav = rot * Vector3::from(lever_arm_body_m);
        let mut h = SMatrix::<f64, 3, N_STATES>::zeros();
        h.fixed_view_mut::<3, 3>(0, IDX_POS)
            .copy_from(&(-Matrix3::identity()));
        h.fixed_view_mut::<3, 3>(0, IDX_ATT)
            .copy_from(&skew(&lever_nav));
        let v = Vector3::from(pos_uwb_m) - (Vector3::from(p_ins_m) + lever_nav) - h * self.x;
        let pht = self.p * h.transpose();
        let s = h * pht + cov;
        let s_inv = match s.cholesky() {
            Some(ch) => ch.inverse(),
            None => {
                return Err(PositionUpdateError::CovarianceNotPd {
                    row: 0,
                    col: 0,
                    value: s[(0, 0)],
                })
            }
        };
        let nis = v.dot(&(s_inv * v));
        let rejected = nis.sqrt() > self.config.hard_gate_sigma;
        if !rejected {
            let k = pht * s_inv;
            if self.anchors.enabled() {
                // P_bx H^T and H P_xb; Joseph form on the bias blocks.
                let pbht = self.anchors.pxb.transpose() * h.transpose();
                let hpxb = h * self.anchors.pxb;
                let kb = pbht * s_inv;
                self.anchors.b += kb * v;
                let pxb =
                    self.anchors.pxb - k * hpxb - pht * kb.transpose() + k * s * kb.transpose();
                let pbb =
                    self.anchors.pbb - kb * hpxb - pbht * kb.transpose() + kb * s * kb.transpose();
                self.anchors.pxb = pxb;
                self.anchors.pbb = (pbb + pbb.transpose()) * 0.5;
            }
            self.x += k * v;
            let i_kh = Covariance::identity() - k * h;
            self.p = i_kh * self.p * i_kh.transpose() + k * cov * k.transpose();
            symmetrize(&mut self.p);
            self.stats.position_updates += 1;
        }
        Ok(PositionUpdateReport {
            innovation_m: v.into(),
            nis,
            rejected,
        })
    }

    /// Returns the error estimate as a [`Correction`] for the INS and zeroes
    /// the error state (closed loop).
    ///
    /// With `reset_jacobian` (default) the attitude block of `P` is mapped
    /// through `G = I - [δθ/2 x]`: after the INS applies `q <- Exp(-δθ) ⊗ q`,
    /// the new error `δθ⁺ = Log(Exp(-δθ̂) Exp(δθ)) ≈ (I - [δθ̂/2 x]) (δθ - δθ̂)`
    /// (Solà 2017 §7.2); the other blocks are shifted by constants, so their
    /// Jacobian is the identity. Without it, `P` is unchanged.
    pub fn take_correction(&mut self) -> Correction {
        let x = &self.x;
        let v3 = |i: usize| [x[i], x[i + 1], x[i + 2]];
        let corr = Correction {
            d_pos_m: v3(IDX_POS),
            d_vel_mps: v3(IDX_VEL),
            d_att_rad: v3(IDX_ATT),
            d_accel_bias_mps2: v3(IDX_ACCEL_BIAS),
            d_gyro_bias_rps: v3(IDX_GYRO_BIAS),
        };
        if self.config.reset_jacobian {
            let half = Vector3::from(corr.d_att_rad) * 0.5;
            if half.iter().any(|&v| v != 0.0) {
                let g = Matrix3::identity() - skew(&half);
                let rows = g * self.p.fixed_view::<3, N_STATES>(IDX_ATT, 0);
                self.p
                    .fixed_view_mut::<3, N_STATES>(IDX_ATT, 0)
                    .copy_from(&rows);
                let cols = self.p.fixed_view::<N_STATES, 3>(0, IDX_ATT) * g.transpose();
                self.p
                    .fixed_view_mut::<N_STATES, 3>(0, IDX_ATT)
                    .copy_from(&cols);
                symmetrize(&mut self.p);
                let brows = g * self.anchors.pxb.fixed_rows::<3>(IDX_ATT);
                self.anchors
                    .pxb
                    .fixed_rows_mut::<3>(IDX_ATT)
                    .copy_from(&brows);
            }
        }
        self.x = StateVector::zeros();
        corr
    }

    /// Restarts the filter after the caller re-initialised the INS (e.g. from
    /// a UWB multilateration fix): zero error state, the configured initial
    /// covariance, cleared pair history, `nis_last` and `needs_reset`. The
    /// clock and the counters continue.
    pub fn reset(&mut self) {
        let p0 = self.p0;
        self.reset_to(p0);
    }

    /// [`Eskf::reset`] with the configured initial covariance except its
    /// position block, which is `pos_cov_m2` (e.g. the fix covariance).
    ///
    /// # Errors
    /// [`ResetError`] when `pos_cov_m2` is not finite, symmetric and
    /// positive definite; the filter is then unchanged.
    pub fn reset_with_position_cov(&mut self, pos_cov_m2: [[f64; 3]; 3]) -> Result<(), ResetError> {
        let pc = Matrix3::from_fn(|i, j| pos_cov_m2[i][j]);
        check_covariance(&pc).map_err(|(row, col, value)| ResetError::CovarianceNotPd {
            row,
            col,
            value,
        })?;
        let mut p = self.p0;
        p.fixed_view_mut::<3, 3>(IDX_POS, IDX_POS).copy_from(&pc);
        self.reset_to(p);
        Ok(())
    }

    /// [`Eskf::reset`] with a caller-given initial covariance.
    ///
    /// # Errors
    /// [`ResetError`] when `p0` is not finite, symmetric and positive
    /// definite; the filter is then unchanged.
    pub fn reset_with_covariance(&mut self, p0: &Covariance) -> Result<(), ResetError> {
        check_covariance(p0).map_err(|(row, col, value)| ResetError::CovarianceNotPd {
            row,
            col,
            value,
        })?;
        self.reset_to(*p0);
        Ok(())
    }

    fn reset_to(&mut self, p0: Covariance) {
        self.x = StateVector::zeros();
        self.p = p0;
        symmetrize(&mut self.p);
        self.nis_last = None;
        self.needs_reset = false;
        self.pairs = [PairSlot::default(); PAIR_SLOTS];
        self.anchors.clear();
        self.stats.resets += 1;
    }

    /// The current error-state estimate `[δp, δv, δθ, δb_a, δb_g]` (zero
    /// right after [`Eskf::take_correction`]).
    #[must_use]
    pub fn state(&self) -> &StateVector {
        &self.x
    }

    /// The error-state covariance.
    #[must_use]
    pub fn covariance(&self) -> &Covariance {
        &self.p
    }

    /// The anchors' TDOA error states ([`EskfConfig::tdoa_anchor_sigma_m`]),
    /// slot by slot: the anchor's position, the estimate of its error and
    /// that estimate's sigma, m. Empty when the states are off.
    pub fn anchor_errors(&self) -> impl Iterator<Item = ([f64; 3], f64, f64)> + '_ {
        self.anchors.states()
    }

    /// Covariance of `[pos e, n, u, vel e, n, u]` (as in
    /// [`insuwb_msg::FusedState::cov`]).
    #[must_use]
    pub fn position_velocity_cov(&self) -> [[f64; 6]; 6] {
        let mut out = [[0.0; 6]; 6];
        for (i, row) in out.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = self.p[(IDX_POS + i, IDX_POS + j)];
            }
        }
        out
    }

    /// NIS of the last TDOA measurement that was not decimated.
    #[must_use]
    pub fn nis_last(&self) -> Option<f64> {
        self.nis_last
    }

    /// The covariance became non-finite: the caller must re-initialise the
    /// INS and call [`Eskf::reset`]. Sticky until reset. (Inconsistency,
    /// a filter that is finite but wrong, is the divergence monitor's to
    /// find, from the reports' NIS.)
    #[must_use]
    pub fn needs_reset(&self) -> bool {
        self.needs_reset
    }

    /// Filter time, s: the sum of the steps given to [`Eskf::predict`].
    #[must_use]
    pub fn time_s(&self) -> f64 {
        self.time_s
    }

    /// Counters since construction.
    #[must_use]
    pub fn stats(&self) -> EskfStats {
        self.stats
    }

    /// The yaw is held out of the updates: the last specific force given to
    /// [`Eskf::predict`] has a horizontal part below
    /// [`EskfConfig::yaw_min_excitation_mps2`] (an update of a body-frame
    /// velocity, [`Eskf::update_body_velocity`], is not held).
    #[must_use]
    pub fn yaw_frozen(&self) -> bool {
        let f = self.f_last;
        self.config.yaw_min_excitation_mps2 > 0.0
            && f[0].hypot(f[1]) < self.config.yaw_min_excitation_mps2
    }

    /// The innovation-based scale on the process noise (1 when
    /// [`EskfConfig::q_adapt_time_s`] is 0).
    #[must_use]
    pub fn q_scale(&self) -> f64 {
        self.q_adapt.alpha
    }

    /// One step of the process-noise scale from an applied TDOA update with
    /// innovation `v`, predicted part `hph` and measurement variance
    /// `sigma2` (see [`EskfConfig::q_adapt_time_s`]): the window's median
    /// squared innovation, read as `CHI2_1_MEDIAN` times its variance, less
    /// `sigma2`, against the median `H P H^T`. Medians, so that the NLOS
    /// minority of the measurements (UTIL: 9-23 %) does not count as
    /// process noise.
    fn adapt_q(&mut self, v: f64, hph: f64, sigma2: f64) {
        let tau = self.config.q_adapt_time_s;
        if tau <= 0.0 {
            return;
        }
        let a = &mut self.q_adapt;
        let Some((m_v2, m_hph, dt)) = a.window.push(v, hph, self.time_s) else {
            return;
        };
        if m_hph <= 0.0 {
            return;
        }
        // The window's median squared innovation estimates its variance
        // with a relative standard deviation of 1 / (2 f(m) m sqrt(n)) for
        // chi-square(1) (m its median, f its density there): 21 % for 128
        // updates. Only an excess beyond two of those raises the scale, so
        // that the sampling noise of the median does not ratchet it up.
        #[allow(clippy::cast_precision_loss)]
        let n = a.window.len as f64;
        let rel_sd = 1.0 / (2.0 * CHI2_1_MEDIAN_DENSITY * CHI2_1_MEDIAN * n.sqrt());
        let observed = m_v2 / CHI2_1_MEDIAN;
        let predicted = m_hph + sigma2;
        let ratio = ((observed - sigma2) / m_hph).clamp(0.25, 4.0);
        // Up fast, down slowly: the scale describes the vehicle (its
        // vibration), which does not change from one manoeuvre to the next,
        // while a consistent stretch only says the scale is high enough.
        let tau = if observed > (1.0 + 2.0 * rel_sd) * predicted && ratio > 1.0 {
            tau
        } else if ratio < 1.0 {
            tau * self.config.q_adapt_decay_factor
        } else {
            return;
        };
        a.alpha = (a.alpha * ratio.powf(dt / tau)).clamp(1.0, self.config.q_scale_max);
    }

    fn touch_pair(&mut self, slot: Option<usize>, key: [u64; 6]) {
        let idx = slot
            .or_else(|| self.pairs.iter().position(|p| !p.used))
            .or_else(|| {
                (0..PAIR_SLOTS).min_by(|&i, &j| {
                    let ti = self.pairs.get(i).map_or(0.0, |p| p.last_time_s);
                    let tj = self.pairs.get(j).map_or(0.0, |p| p.last_time_s);
                    ti.total_cmp(&tj)
                })
            });
        if let Some(p) = idx.and_then(|i| self.pairs.get_mut(i)) {
            *p = PairSlot {
                used: true,
                key,
                last_time_s: self.time_s,
            };
        }
    }

    /// Scalar update with gain `K = c / (hph + r)`, `c = P h`:
    /// `δx += K v`, Joseph form `P <- (I - K h^T) P (I - K h^T)^T + K r K^T
    /// = P - K c^T - c K^T + (hph + r) K K^T`.
    ///
    /// With `hold_yaw` (the yaw unobservable to this update,
    /// [`Eskf::yaw_frozen`]) the gain's yaw and yaw-rate bias entries are
    /// zero (a consider update: the Joseph form keeps `P` consistent for any
    /// gain).
    fn scalar_update(
        &mut self,
        c: &StateVector,
        cb: &ErrorVector,
        hph: f64,
        r: f64,
        v: f64,
        hold_yaw: bool,
    ) {
        let s = hph + r;
        let mut k = c / s;
        if hold_yaw {
            k[IDX_ATT + 2] = 0.0;
            k[IDX_GYRO_BIAS + 2] = 0.0;
        }
        if self.anchors.enabled() {
            let kb = cb / s;
            self.anchors.update(&k, &kb, c, cb, s, v);
        }
        self.x += k * v;
        let kc = k * c.transpose();
        self.p += k * k.transpose() * s - kc - kc.transpose();
        symmetrize(&mut self.p);
        if !self.p.iter().all(|v| v.is_finite()) {
            self.needs_reset = true;
        }
    }
}
