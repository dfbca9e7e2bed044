//! The Foxglove live-view binary starts, documents its flag and refuses a
//! missing config or a bad `[foxglove]` key before it opens anything (its
//! own test file also makes cargo build the binary for
//! bins/insuwb/tests/foxglove_live.rs).
#![allow(clippy::unwrap_used)]

const STAGE_BIN: &str = env!("CARGO_BIN_EXE_insuwb-stage-foxglove");
const TABLE: &str = "foxglove";
const BAD_ENTRY: &str = "bind = \"localhost:8765\"";
const BAD_KEY: &str = "foxglove.bind";

include!("../../../tests/bridge_cli.rs");
