//! The integration tests of insuwb-log, linked into one binary: each
//! module is one topic (`corpus`, `header`, `roundtrip`, `segments`, `torn`), documented at its
//! top; `common` holds their shared helpers.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;
mod corpus;
mod header;
mod roundtrip;
mod segments;
mod torn;
