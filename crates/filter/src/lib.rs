//! The paper's error-state model and filters (sections 2.3 and 3, with the
//! errata and resolutions of `shared/paper/READING.md`).
//!
//! - [`model`]: the 14-state error model, `F` (eq. 10, errata 2-3) in a
//!   sparse form, `Q` (eq. 11, erratum 5), `H = [I4 | 0]`, and its
//!   configuration ([`ModelConfig`]);
//! - [`sparse`]: `P' = F P F^T + Q` exploiting the sparsity of `F`, and the
//!   dense reference;
//! - [`params`]: the tuning of the adaptive filters ([`FilterParams`]) and
//!   the prior they share ([`FilterSetup`]);
//! - [`filter`]: the [`ErrorFilter`] trait and the [`Kf`], [`Shaf`], [`Stf`]
//!   and [`Iakf`] filters (errata 6-15), and [`build`];
//! - [`monitor`]: the windowed NIS divergence monitor every filter shares,
//!   the tightly coupled one of `insuwb-eskf` included
//!   ([`DivergenceMonitor`]).
//!
//! Conventions: errors are "INS minus truth" (the measurement is
//! `z = [P_ins - P_uwb; V_ins - V_uwb]`, eq. 15), ENU frame, heading
//! counter-clockwise from east; the acceleration error states are
//! `d a = a_true - a_meas` (erratum 4). Everything is deterministic and,
//! after construction, allocation free.
//!
//! ```
//! use insuwb_filter::{build, FilterParams, FilterSetup, ModelConfig, PaperModel};
//! use insuwb_msg::FilterKind;
//! use nalgebra::SVector;
//!
//! let model = PaperModel::new(ModelConfig::default()).unwrap();
//! let mut f = build(FilterKind::Iakf, model, &FilterParams::default(), &FilterSetup::default()).unwrap();
//! for _ in 0..10 {
//!     f.predict(0.01, 0.0, 0.0).unwrap(); // 100 Hz IMU
//! }
//! let report = f.update(&SVector::<f64, 4>::new(0.1, -0.05, 0.0, 0.0)).unwrap(); // 10 Hz UWB
//! assert_eq!(report.dim, 4);
//! let dx = f.take_correction(); // closed loop: feed dx back to the INS
//! assert!(dx[0] > 0.0 && f.state()[0] == 0.0);
//! ```
#![warn(missing_docs)]

mod engine;
pub mod filter;
pub mod model;
pub mod monitor;
pub mod params;
pub mod sparse;

#[cfg(test)]
mod tests;
#[cfg(test)]
mod testutil;

pub use filter::{
    build, BuildError, ErrorFilter, Iakf, Kf, PredictError, ResetError, Shaf, Stf, UpdateError,
    UpdateReport,
};
pub use model::{
    ar3_is_stable, dense, h_matrix, h_matrix_pos, idx, ArConfig, BiasRandomWalk, Mat14, Mat4,
    ModelConfig, ModelConfigError, ModelForm, PaperModel, PredictSteps, StepError, Transition14,
    Vec14, N_MEAS, N_STATES,
};
pub use monitor::{
    DivergenceMonitor, MonitorConfig, MonitorConfigError, MAX_MONITOR_WINDOW,
    MAX_OUTLIER_WINDOW_LEN, MIN_OUTLIER_WINDOW_LEN,
};
pub use params::{
    FilterParams, FilterParamsError, FilterSetup, FilterSetupError, LimitMode, OutlierForm,
};
pub use sparse::{predict_dense, predict_sparse};
