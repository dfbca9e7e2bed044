//! INS mechanisation (quaternion attitude, gravity removal, ENU velocity and
//! position), static alignment and AR(p) Yule-Walker fitting.
//!
//! - [`ins`]: strapdown INS in 3D, ENU, flat earth, with closed-loop
//!   corrections in the "error = INS minus truth" convention;
//! - [`align`]: static levelling, gyro bias from a static record and the
//!   [`align::StaticDetector`] that finds the initial static phase of a stream;
//! - [`vehicle`]: vehicle models (free, multirotor thrust and drag, ground
//!   non-holonomic) shared by the mechanisation and the filters;
//! - [`ar`]: AR(p) coefficients of a sensor-error record by Yule-Walker with
//!   Levinson-Durbin, in the paper's sign convention (eq. 4).
//!
//! Conventions are those of `insuwb-msg`: ENU navigation frame, FLU body
//! frame, quaternions `[w, x, y, z]` body to ENU, accelerometers give specific
//! force, times are `u64` nanoseconds.
#![warn(missing_docs)]

pub mod align;
pub mod ar;
pub mod ins;
pub mod vehicle;

#[cfg(test)]
mod testutil;

pub use align::{
    gyro_bias_from_static, initial_state, level_from_accel, AlignError, StaticDetectError,
    StaticDetector, StaticDetectorConfig, StaticDetectorConfigError, StaticSegment,
};
pub use ar::{fit_ar, fit_ar3, Ar3Fit, ArFit, ArFitError};
pub use ins::{
    yaw_of, CorrectionError, Ins, InsConfig, InsConfigError, InsNewError, InsState, InsStateError,
    InsStepError, NavOutput,
};
