//! The integration tests of insuwb-eskf, linked into one binary: each
//! module is one topic (`anchor_error`, `damping`, `linearisation`,
//! `monitor`, `radio_height`, `scenario`), documented at its top; `common` holds their
//! shared helpers.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod anchor_error;
mod common;
mod damping;
mod linearisation;
mod monitor;
mod radio_height;
mod scenario;
