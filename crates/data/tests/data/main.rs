//! The integration tests of insuwb-data, linked into one binary: each
//! module is one topic (`corpus`, `util_real`), documented at its
//! top.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod corpus;
mod util_real;
