//! The fleet: many robots' poses and health at one station.
//!
//! - [`keys`]: the key expressions a robot publishes under
//!   (`insuwb/<robot>/pose`, `insuwb/<robot>/health`) and the robot ids
//!   they allow.
//! - [`station`]: what the station knows of each robot (last pose, rate,
//!   age, status OK / degraded / stale / lost, restarts) and the lost and
//!   back events, from samples stamped with the station's receive time.
//! - [`delivery`]: what reached the station: samples received, lost on the
//!   way (gaps in the publishers' sequence numbers), the poses' delays.
//! - [`view`]: a snapshot of the fleet (JSON) and its terminal table.
//! - [`record`]: each robot's stream into its own insuwb log.
//!
//! All but [`record`] are pure and deterministic: the same samples at the
//! same receive times give the same view; the transport is elsewhere.
//!
//! ```
//! use insuwb_fleet::keys::{Key, Kind};
//! use insuwb_fleet::station::{PoseSample, Station, StationConfig, Status};
//!
//! let key: Key = "insuwb/r1/pose".parse().unwrap();
//! assert_eq!((key.robot(), key.kind()), ("r1", Kind::Pose));
//!
//! let mut s = Station::new(StationConfig::default()).unwrap();
//! for k in 0..10u64 {
//!     let t = k * 100_000_000;
//!     s.on_pose(key.robot(), PoseSample { stamp_ns: t, pos_m: [1.0, 2.0, 0.5], yaw_rad: 0.0 }, t);
//! }
//! let view = s.snapshot(1_000_000_000);
//! assert_eq!(view[0].status, Status::Ok);
//! assert!((view[0].rate_hz - 10.0).abs() < 1e-9);
//! ```

#![warn(missing_docs)]

pub mod delivery;
pub mod keys;
pub mod record;
pub mod station;
pub mod view;
