//! The integration tests of insuwb-fusion, linked into one binary: each
//! module is one topic (`divergence`, `ins_outage`, `util_real`), documented at its
//! top; `common` holds their shared helpers.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;
mod divergence;
mod ins_outage;
mod util_real;
