//! The Zenoh bridge binary starts, documents its flag and refuses a
//! missing config or a bad `[zenoh]` key before it opens anything (its own
//! test file also makes cargo build the binary for
//! bins/insuwb/tests/zenoh_bridge.rs).
#![allow(clippy::unwrap_used)]

const STAGE_BIN: &str = env!("CARGO_BIN_EXE_insuwb-stage-zenoh");
const TABLE: &str = "zenoh";
const BAD_ENTRY: &str = "connect = [\"udp/127.0.0.1:7447\"]";
const BAD_KEY: &str = "zenoh.connect";

include!("../../../tests/bridge_cli.rs");
