//! The `insuwb` command's tests that start no process group: the command
//! line as a user meets it, the programs beside it, the real flights and
//! the site calibration through `insuwb eval` and `insuwb calibrate`, cut
//! logs. They run in parallel. Each module is one topic, documented at its
//! top; `common` (shared with `processes`) holds their helpers.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

#[path = "../common/mod.rs"]
mod common;

mod calibration;
mod cli;
mod cut_logs;
mod eval_flights;
mod programs;
mod real_flights;
