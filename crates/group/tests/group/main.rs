//! The integration tests of insuwb-group, linked into one binary: each
//! module is one topic (`robot`), documented at its
//! top.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod robot;
