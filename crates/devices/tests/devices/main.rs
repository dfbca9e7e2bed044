//! The integration tests of insuwb-devices, linked into one binary: each
//! module is one topic (`codecs`, `fuzz`, `links`), documented at its
//! top.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod codecs;
mod fuzz;
mod links;
