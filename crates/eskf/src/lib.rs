//! Tightly coupled INS/UWB-TDOA error-state Kalman filter (beyond the paper).
//!
//! The paper's IAKF (`insuwb-filter`) is loosely coupled and 2D. This crate
//! owns the 3D, tightly coupled alternative for real flights: a 15-state
//! error-state filter (`δp, δv, δθ, δb_a, δb_g`, global attitude error)
//! that propagates its covariance on the INS's nominal states (it never
//! integrates the nominal state itself), fuses every TDOA difference with a
//! robust, IAKF-style per-measurement weight (erratum 13, with the IAKF's
//! [`insuwb_filter::LimitMode`]), decorrelates the UWB errors' time
//! correlation by a rate-adaptive `R` inflation, optionally carries each
//! anchor's share of the TDOA error as a Gauss-Markov state beside the 15
//! ([`EskfConfig::tdoa_anchor_sigma_m`]) and returns closed-loop
//! corrections in the conventions of [`insuwb_msg::InsCorrection`]. Its
//! consistency is watched from outside, by the NIS monitor every filter
//! shares ([`insuwb_filter::DivergenceMonitor`], which the fusion engine
//! feeds with each update's [`TdoaUpdateReport::nis`]); the filter itself
//! only asks for a reset when its covariance stops being finite.
//! Conventions:
//!
//! - `δp = p_ins - p_true`, `δv = v_ins - v_true` (the INS subtracts them);
//! - `q_true = Exp(-δθ) ⊗ q_ins`, `δθ` an ENU rotation vector;
//! - `δb = b_true - b_ins` (the INS adds it); the INS compensates
//!   `f = a_meas - b_a`, `ω = ω_meas - b_g`.
//!
//! Frames: ENU navigation, FLU body, quaternions `[w, x, y, z]` body to ENU.
//! All operations are deterministic and allocation-free (fixed-size
//! nalgebra matrices).
#![warn(missing_docs)]

mod anchor_error;
mod config;
mod eskf;
mod math;

pub use config::{EskfConfig, EskfConfigError};
pub use eskf::{
    process_noise, range_model, tdoa_model, transition_matrix, Correction, Covariance, Eskf,
    EskfStats, MultirotorDynamics, PositionUpdateError, PositionUpdateReport, PredictError,
    PseudoUpdateError, PseudoUpdateReport, ResetError, StateVector, TdoaModel, TdoaOutcome,
    TdoaUpdateError, TdoaUpdateReport, IDX_ACCEL_BIAS, IDX_ATT, IDX_GYRO_BIAS, IDX_POS, IDX_VEL,
    N_STATES,
};
pub use insuwb_filter::LimitMode;
pub use math::{quat_to_rot, skew};
