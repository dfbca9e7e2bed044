//! The logger stage binary starts, documents its flags and refuses a missing config.
#![allow(clippy::unwrap_used)]

const STAGE_BIN: &str = env!("CARGO_BIN_EXE_insuwb-stage-logger");

include!("../../../tests/stage_cli.rs");
