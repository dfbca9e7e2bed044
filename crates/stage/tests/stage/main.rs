//! The integration tests of insuwb-stage, linked into one binary: each
//! module is one topic (`alloc`), documented at its
//! top.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod alloc;
