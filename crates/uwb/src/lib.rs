//! UWB geometry: TDOA and two-way-ranging multilateration (2D and 3D,
//! Gauss-Newton seeded in closed form), DOP covariance, epoch grouping of a
//! TDOA or range stream into fixes, and velocity from successive fixes.
//!
//! - [`solve`]: position from range differences (`diff = |p - b| - |p - a|`,
//!   the convention of [`insuwb_msg::UwbTdoa`]).
//! - [`range`]: position from two-way ranges (`range = |p - a|`, the
//!   convention of [`insuwb_msg::UwbRange`]), robustly weighted.
//! - [`fix`]: [`fix::FixBuilder`] turns [`insuwb_msg::UwbTdoa`] or
//!   [`insuwb_msg::UwbRange`] samples into
//!   [`insuwb_msg::UwbFix`] samples, deterministically.
//! - [`velocity`]: sliding-window regression velocity and its covariance.
//! - [`calibration`]: a site calibration of the per-pair TDOA biases,
//!   learnt from flights with ground truth, applied by the fix builder.
//! - [`survey`]: each anchor's offset over a flight's residuals, the check
//!   of an anchor survey against a flight with ground truth.
//!
//! Library code: no clock, no global state; the only I/O is reading and
//! writing calibration files ([`calibration::SiteCalibration::load`], `save`).
#![warn(missing_docs)]

pub mod calibration;
pub mod fix;
pub mod range;
pub mod solve;
pub mod survey;
pub mod velocity;

pub use fix::{FixBuilder, FixConfig, FixMode, FixStats};
pub use solve::{solve_2d, solve_3d, Fix, SolveError, SolverConfig, TdoaObs};
pub use velocity::{VelocityConfig, VelocityEstimator};
