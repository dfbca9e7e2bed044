//! The Foxglove live view of insuwb: the fused pose and its path, the UWB
//! fixes and two-way ranges, the anchors, ground truth, the filter's
//! diagnostics, body velocities (odometry, optical flow) and the stages'
//! health, served to the Foxglove app over the Foxglove WebSocket protocol
//! (the `foxglove` SDK's server, default `ws://127.0.0.1:8765`).
//!
//! - [`config`]: the `[foxglove]` table of the robot config;
//! - `convert` (feature `live`, on by default): pure conversions from
//!   insuwb samples to Foxglove messages and JSON (stamps, frames,
//!   quaternion order, the path, anchors, body velocities, ranges,
//!   health);
//! - `live` (feature `live`): the stage's loop, iceoryx2 in, WebSocket out.
//!
//! ```
//! use insuwb_foxglove::FoxgloveConfig;
//! let c = FoxgloveConfig::default();
//! assert_eq!(c.url().unwrap(), "ws://127.0.0.1:8765");
//! assert_eq!(c.topic("pose"), "/insuwb/pose");
//! ```
#![warn(missing_docs)]

pub mod config;
#[cfg(feature = "live")]
pub mod convert;
#[cfg(feature = "live")]
pub mod live;

pub use config::{FoxgloveConfig, FoxgloveConfigError};
