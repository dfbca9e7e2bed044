//! The integration tests of insuwb-sim, linked into one binary: each
//! module is one topic (`calibration`, `sim`, `twr`, `velocity`),
//! documented at its top.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod calibration;
mod sim;
mod twr;
mod velocity;
