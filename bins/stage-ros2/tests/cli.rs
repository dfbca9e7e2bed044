//! The ROS 2 bridge binary starts, documents its flag and refuses a missing
//! config or a bad `[ros2]` key before it opens anything (its own test file
//! also makes cargo build the binary for bins/insuwb/tests/ros2_interop.rs).
#![allow(clippy::unwrap_used)]

const STAGE_BIN: &str = env!("CARGO_BIN_EXE_insuwb-stage-ros2");
const TABLE: &str = "ros2";
const BAD_ENTRY: &str = "frame_id = \"/map\"";
const BAD_KEY: &str = "ros2.frame_id";

include!("../../../tests/bridge_cli.rs");
