//! The integration tests of insuwb-launch, linked into one binary: each
//! module is one topic (`processes`), documented at its
//! top.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod processes;
