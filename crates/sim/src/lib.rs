//! Deterministic simulator: trajectories, IMU errors, UWB TDOA with noise and NLOS outlier bursts.
#![warn(missing_docs)]
