//! INS mechanisation (quaternion attitude, gravity removal, ENU velocity and position), static alignment and AR(3) Yule-Walker fitting.
#![warn(missing_docs)]
