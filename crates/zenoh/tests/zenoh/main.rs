//! The integration tests of insuwb-zenoh, linked into one binary: each
//! module is one topic (`tls`), documented at its
//! top.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod tls;
