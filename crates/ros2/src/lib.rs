//! The ROS 2 bridge of insuwb: the fused pose, the IMU samples and the
//! stages' health as ROS 2 topics, with no ROS installation.
//!
//! - [`cdr`]: their ROS 2 CDR encoding and decoding (the MCAP export's
//!   and the Zenoh bridge's payload);
//! - [`msgs`]: the ROS 2 messages (serde structs in `.msg` field order),
//!   their type names and `ros2msg` definitions;
//! - [`convert`]: pure conversions from insuwb samples (stamps, frames,
//!   covariance layout, quaternion order, diagnostics levels);
//! - [`config`]: the `[ros2]` table of the robot config;
//! - [`odometry_in`]: a robot base's odometry from ROS (`[ros2]
//!   odometry_in`) made checked body velocities;
//! - [`height_in`]: a downward range finder from ROS (`[ros2] height_in`)
//!   made checked heights;
//! - `bridge` (feature `dds`, on by default through `jazzy`): the stage's
//!   loop, iceoryx2 in, DDS out through `ros2-client` (RustDDS), and the
//!   base's odometry and the range finder DDS in, `body_vel` and `height`
//!   out on iceoryx2. Feature
//!   `humble` (without the default features) builds it for ROS 2 Humble.
//! - `subscribe` (feature `dds`): a `sensor_msgs/Imu` subscriber, the IMU
//!   driver's source for an IMU already in ROS (`sources.imu = "ros2:/TOPIC"`).
//!
//! ```
//! use insuwb_msg::{FusedState, Header};
//! use insuwb_report::clock::ClockOffset;
//! use insuwb_ros2::convert::{fused_to_odometry, Frames};
//! use insuwb_ros2::msgs::{Odometry, RosMessage};
//! let s = FusedState { header: Header::new(0, 1_000_000_000), quat: [1.0, 0.0, 0.0, 0.0], ..Default::default() };
//! let odom = fused_to_odometry(&s, &Frames::default(), &ClockOffset::ZERO).unwrap();
//! assert_eq!((odom.header.frame_id.as_str(), odom.child_frame_id.as_str()), ("map", "base_link"));
//! assert_eq!(Odometry::dds_type_name(), "nav_msgs::msg::dds_::Odometry_");
//! ```
#![warn(missing_docs)]

#[cfg(feature = "dds")]
pub mod bridge;
pub mod cdr;
pub mod config;
pub mod convert;
pub mod height_in;
pub mod msgs;
pub mod odometry_in;
#[cfg(feature = "dds")]
pub mod subscribe;

pub use config::{OdometryInType, Ros2Config, Ros2ConfigError};
