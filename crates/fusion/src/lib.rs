//! The closed-loop INS/UWB fusion engine shared by `insuwb eval`, replay and
//! the INS and fusion stages.
//!
//! [`ins_engine::InsEngine`] turns IMU samples into navigation states and
//! applies corrections; [`engine::FusionEngine`] turns navigation states and
//! UWB measurements into fused states and corrections; [`offline`] wires the
//! two (and the UWB fix builder) together in one process, in lockstep, with
//! exactly the code the stage processes run; [`tight`] wraps the tightly
//! coupled error-state filter as an estimator; [`vibration`] turns the
//! vibration the IMU measures into process noise for every filter.
#![warn(missing_docs)]

pub mod engine;
pub mod estimator;
pub mod ins_engine;
pub mod offline;
pub mod tight;
pub mod vibration;
