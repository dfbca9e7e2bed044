//! The integration tests of insuwb-uwb, linked into one binary: each
//! module is one topic (`fix`, `solve`, `velocity`), documented at its
//! top; `common` holds their shared helpers.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;
mod fix;
mod solve;
mod velocity;
