//! UWB geometry: TDOA multilateration (2D and 3D, Gauss-Newton seeded in closed form), DOP covariance and velocity from successive fixes.
#![warn(missing_docs)]
