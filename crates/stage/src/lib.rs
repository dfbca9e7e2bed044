//! The body of each stage process and what they share: the sensor sources
//! ([`source`]), one module per stage ([`driver`] for the IMU and UWB
//! drivers, [`device`] for their loop over a real sensor, [`ros2_source`]
//! for their loop over a ROS 2 topic, [`ins`], [`fusion`], [`logger`]) and
//! the locks that keep one group per prefix and one process per stage role
//! ([`lock`]). Every stage reads the robot group configuration of
//! `insuwb_group::robot`. The stage binaries in `bins/` are thin `main`s
//! over [`cli`]; all the algorithms come from `insuwb-fusion`, the same code
//! `insuwb eval` runs.
#![warn(missing_docs)]

pub mod checkpoint;
pub mod cli;
pub mod device;
pub mod driver;
pub mod fusion;
pub mod ins;
pub mod lock;
pub mod logger;
pub mod ros2_source;
pub mod source;
