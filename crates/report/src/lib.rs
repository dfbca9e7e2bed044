//! What the stages that report on the whole group share, with no
//! transport of their own (the ROS 2 bridge's `/diagnostics`, the Foxglove
//! live view, the Zenoh bridge's `health`):
//!
//! - [`health`]: the group's health from the stages' heartbeats;
//! - [`report_loop`]: the loop of such a stage (wake on each fused state,
//!   drain, report periodically, beat);
//! - [`clock`]: the clock of the stamps they write (CLOCK_REALTIME by
//!   default, or CLOCK_MONOTONIC as in the headers).
#![warn(missing_docs)]

pub mod clock;
pub mod health;
pub mod report_loop;
