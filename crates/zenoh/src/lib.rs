//! The Zenoh bridge of insuwb: a robot's fused pose, its stages' health
//! and, when asked, its UWB fixes and filter diagnostics, published to the
//! fleet's station over Zenoh under `insuwb/<robot>/...`
//! ([`insuwb_fleet::keys`]), in payloads any language decodes
//! (`docs/ZENOH.md`).
//!
//! - [`config`]: the `[zenoh]` table of the robot config (robot id, mode,
//!   endpoints, TLS, what to publish), and the [`config::LinkConfig`] a
//!   station shares;
//! - [`payload`]: the versioned payloads, encode and decode (ROS 2 CDR of
//!   `nav_msgs/msg/Odometry` for the pose, JSON for the rest), into the
//!   station's samples;
//! - `session` (feature `transport`, on by default): the `zenoh::Config`
//!   of a link (explicit endpoints, no scouting, TLS) and the session,
//!   opened with the stage's signals blocked, and the decoding of a
//!   received sample;
//! - `bridge` (feature `transport`): the stage's loop, iceoryx2 in, Zenoh
//!   out.
//! - `station` (feature `transport`): the fleet's station (`insuwb
//!   fleet`): subscribes to every robot, feeds `insuwb_fleet`'s model,
//!   delivery counts and recording, hands out snapshots.
//! - `identity` (feature `transport`): `[station.identity]`, the Zenoh
//!   access control it makes at the station's router (a robot puts only
//!   under its certificate's id) and the refusals counted.
//! - `loadgen` (feature `transport`): simulated robots for the station's
//!   benchmark (`insuwb bench fleet`).
//!
//! Without `transport` the crate is the config and the payloads alone
//! (what `insuwb-group` reads for the robot config, and a decoder that
//! brings its own transport).
//!
//! ```
//! use insuwb_zenoh::ZenohConfig;
//! let c: ZenohConfig = toml::from_str("robot = \"r1\"\nconnect = [\"tcp/127.0.0.1:7447\"]").unwrap();
//! c.validate_enabled().unwrap();
//! assert_eq!(c.key(insuwb_fleet::keys::Kind::Pose).unwrap().to_string(), "insuwb/r1/pose");
//! ```
#![warn(missing_docs)]

#[cfg(feature = "transport")]
pub mod bridge;
pub mod config;
#[cfg(feature = "transport")]
pub mod identity;
#[cfg(feature = "transport")]
pub mod loadgen;
pub mod payload;
#[cfg(feature = "transport")]
pub mod session;
#[cfg(feature = "transport")]
pub mod station;

pub use config::{ZenohConfig, ZenohConfigError};
