//! The `insuwb` command's tests with real processes: groups launched,
//! replayed, faulted and restarted, devices emulated, the bridges against
//! implementations nobody here wrote, the latency bench. Every test that
//! starts a group takes `common::one_at_a_time` (2 cores). Each module is
//! one topic, documented at its top; `common` (shared with `offline`)
//! holds their helpers.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

#[path = "../common/mod.rs"]
mod common;

mod devices;
mod devices_stage;
mod faults;
mod fleet_identity;
mod fleet_station;
mod foxglove_live;
mod hostile_peers;
mod latency;
mod long_run;
mod mcap_export;
mod one_group;
mod pipeline;
mod ranging;
mod refusals;
mod replay_tight;
mod ros2_imu_source;
mod ros2_interop;
mod ros2_odometry_source;
mod sensor_faults;
mod zenoh_bridge;
