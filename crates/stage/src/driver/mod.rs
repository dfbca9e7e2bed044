//! The IMU and UWB driver stages: read a source, check each sample, pace
//! recorded samples against the group's start epoch, publish.
//!
//! [`pacing`] holds what both drivers share (the resume after a restart,
//! the due times, lockstep, the wait loop, the heartbeat); [`imu`] and
//! [`uwb`] what each publishes and checks. A `device` source runs the live
//! loop of [`crate::device`] instead, a `ros2:/TOPIC` IMU source that of
//! [`crate::ros2_source`].
//!
//! Recorded times are mapped onto CLOCK_MONOTONIC as `start_epoch + t`
//! (an offset, never a scale: every interval the algorithms see is the
//! recorded one); a sample is published at `start_epoch + t / speed`. The
//! chosen epoch is a whole second plus 2.5 ms, off the kernel's tick
//! ([`insuwb_runtime::epoch`]); the fix builder aligns its epoch windows to
//! it, so the fix epochs fall as in the recording.
//! At speed 1 the measurement times are real monotonic times, so ages and
//! latencies are meaningful. A restarted driver resumes at the sample the
//! recording has reached, so its consumers see a sequence gap.
//!
//! # What the heartbeat reports
//!
//! Both drivers pass each sample through the gate of its stream
//! ([`insuwb_msg::check`], the gates `insuwb eval` uses too) and count what
//! it refuses: a NaN, infinite or out-of-range value (accelerometer >= 400
//! m/s^2, gyro >= 70 rad/s, equal anchor ids, a TDOA difference longer than
//! its anchors' distance) in `Health::dropped_invalid`; a time going
//! backwards, an IMU sample at the time of the previous one, or a TDOA of
//! the same anchor pair at the time of an earlier one (several pairs of one
//! epoch share a time) in `Health::dropped_time`. A measurement the fix
//! builder still refuses after the site calibration (too long once
//! corrected, the epoch's pair table full) is published all the same,
//! counted in its `FixStats` and logged, at most every
//! [`SKIP_LOG_PERIOD_NS`]. The UWB driver's heartbeat counters are the
//! fix builder's figures ([`insuwb_msg::UwbDriverCounters`]: fixes
//! published, epochs skipped for too few pairs, for their geometry, or
//! because the solver failed). Skips are also logged with their last
//! reason, at most every [`SKIP_LOG_PERIOD_NS`].

pub mod imu;
pub mod pacing;
pub mod uwb;

use anyhow::Result;

use crate::source::Want;
use insuwb_group::robot::RobotConfig;
use insuwb_group::sources::Source;

pub use uwb::SKIP_LOG_PERIOD_NS;

/// Runs a driver stage until SIGINT/SIGTERM. Source `device`: the live
/// loop of [`crate::device`]; `ros2:/TOPIC` (IMU only): that of
/// [`crate::ros2_source`] (speed and epoch do not apply to either).
pub fn run(
    want: Want,
    cfg: &RobotConfig,
    source: &Source,
    speed: f64,
    epoch_ns: u64,
) -> Result<()> {
    match (source, want) {
        (Source::Device, _) => crate::device::run(want, cfg),
        (Source::Ros2 { topic }, Want::Imu) => crate::ros2_source::run(cfg, topic),
        (Source::Ros2 { .. }, Want::Uwb) => Err(crate::ros2_source::Ros2SourceError::NotImu {
            sensor: "uwb",
            spec: source.to_string(),
        }
        .into()),
        (Source::Sim | Source::Replay(_), Want::Imu) => imu::run(cfg, source, speed, epoch_ns),
        (Source::Sim | Source::Replay(_), Want::Uwb) => uwb::run(cfg, source, speed, epoch_ns),
    }
}
