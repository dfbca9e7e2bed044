//! The integration tests of insuwb-bench-floor, linked into one binary:
//! each module is one topic (`cli`, `graph`), documented at its top.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod cli;
mod graph;
