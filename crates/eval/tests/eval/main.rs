//! The integration tests of insuwb-eval, linked into one binary: each
//! module is one topic (`eager`, `faults`, `vehicle`), documented at its
//! top.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod aiding;
mod eager;
mod faults;
mod vehicle;
