//! The IMU driver over a ROS 2 topic, for robots whose IMU is already in
//! ROS (`sources.imu = "ros2:/TOPIC"`): `sensor_msgs/Imu` in over DDS
//! (`insuwb_ros2::subscribe`, node `<[ros2] node_name>_imu_in` in the
//! `[ros2]` namespace and domain, best-effort QoS), [`ImuSample`] out on
//! topic `imu`. The DDS part needs the cargo feature `ros2-source` (on when
//! the workspace is built with the ROS 2 bridge, or with
//! `-p insuwb-stage-imu --features jazzy`); without it [`run`] refuses the source
//! with [`Ros2SourceError::NotBuilt`].
//!
//! # Samples
//!
//! `linear_acceleration` (m/s^2) and `angular_velocity` (rad/s) are taken
//! as body-frame vectors: the message's frame must be the body frame
//! (`[ros2] child_frame_id`, or `imu_frame_id`, an identity transform from
//! it); messages in another frame are used all the same, counted, and
//! warned of once (rotate them upstream, e.g. with `imu_transformer`).
//! Orientation and covariances are not read.
//!
//! # Time stamps
//!
//! Each message is stamped with CLOCK_MONOTONIC when it is taken from the
//! reader. Its measurement time is its `header.stamp` (ROS time: the
//! real-time clock, or CLOCK_MONOTONIC with `[ros2] stamp_clock =
//! "monotonic"`) mapped to CLOCK_MONOTONIC by the clock offset (measured at
//! start and at each heartbeat), which leaves out the transport's delay,
//! when the stamp is set, not after the receive time and at most 1 s
//! before it; otherwise the receive time
//! ([`insuwb_ros2::convert::ros_to_imu_sample`]).
//!
//! # Checks and heartbeat
//!
//! As for device sources ([`crate::device`]): samples with a NaN, infinite
//! or out-of-range value are dropped and counted in
//! `Health::dropped_invalid` (with messages that do not decode as
//! `sensor_msgs/Imu`), samples whose time is not after the previous one in
//! `Health::dropped_time`. State [`HealthState::Ok`] while messages
//! arrive, [`HealthState::Degraded`] before the first one and when none
//! came for [`SILENT_NS`]; a change of state is published at once. Counters:
//! `received` messages taken, `published` samples, and
//! [`Ros2SourceCounters`]: samples timed by their receive time (stamp
//! unset, ahead or too old), messages that did not decode as
//! `sensor_msgs/Imu`, the clock offset (CLOCK_MONOTONIC minus the stamp
//! clock, ns; 0 for monotonic stamps), messages in a frame other than the
//! body frame.
//!
//! Each message allocates its frame id as it is decoded (unlike the device
//! loop, which allocates nothing per sample).

use insuwb_msg::{HealthState, ImuSample, Ros2SourceCounters, StageCounters};
use insuwb_report::clock::ClockOffset;
use insuwb_ros2::config::Ros2Config;
use insuwb_ros2::convert::{ros_to_imu_sample, RosTimeSource};
use insuwb_ros2::msgs::Imu;

use crate::device::SILENT_NS;
use insuwb_group::robot::RobotConfig;
use insuwb_msg::check::imu_values;

/// Why a ROS 2 source cannot run.
#[derive(Debug, thiserror::Error)]
pub enum Ros2SourceError {
    /// This build has no DDS subscriber (feature `ros2-source` off).
    #[error(
        "Ros2SourceError::NotBuilt: sources.imu = \"ros2:{topic}\": this IMU stage was built without the ROS 2 source (cargo feature `ros2-source` of insuwb-stage): build it with `cargo build --release --workspace` (with the ROS 2 bridge) or `cargo build --release -p insuwb-stage-imu --features jazzy`"
    )]
    NotBuilt {
        /// The source's topic.
        topic: String,
    },
    /// A ROS 2 source for a driver other than the IMU's.
    #[error("Ros2SourceError::NotImu: sources.{sensor} = \"{spec}\": a ROS 2 source is for the IMU only")]
    NotImu {
        /// `uwb`.
        sensor: &'static str,
        /// The source as given.
        spec: String,
    },
}

/// What the driver counted of the messages.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct IntakeCounts {
    /// Messages taken (decoded or not).
    pub received: u64,
    /// Samples dropped for a NaN, infinite or out-of-range value.
    pub invalid: u64,
    /// Samples dropped for a time not after the previous sample's.
    pub time: u64,
    /// Samples timed by their receive time.
    pub receive_timed: u64,
    /// Messages that did not decode.
    pub undecodable: u64,
    /// Messages in a frame other than the body frame.
    pub other_frame: u64,
}

/// Turns received messages into checked samples: times, checks, counters.
/// Pure (no I/O).
#[derive(Debug)]
pub struct Intake {
    body_frames: [String; 2],
    last_t: Option<u64>,
    counts: IntakeCounts,
}

impl Intake {
    /// An intake whose body frames are `[ros2] child_frame_id` and
    /// `imu_frame_id`.
    #[must_use]
    pub fn new(ros2: &Ros2Config) -> Self {
        Self {
            body_frames: [ros2.child_frame_id.clone(), ros2.imu_frame_id.clone()],
            last_t: None,
            counts: IntakeCounts::default(),
        }
    }

    /// What was counted so far.
    #[must_use]
    pub fn counts(&self) -> IntakeCounts {
        self.counts
    }

    /// The sample of message `m` taken at `rx_ns` (CLOCK_MONOTONIC) with the
    /// stamp clock's offset `clock`; `None` when it is dropped (counted).
    pub fn take(&mut self, m: &Imu, clock: &ClockOffset, rx_ns: u64) -> Option<ImuSample> {
        self.counts.received += 1;
        if !self.body_frames.contains(&m.header.frame_id) {
            self.counts.other_frame += 1;
            if self.counts.other_frame == 1 {
                tracing::warn!(
                    "imu driver: IMU messages in frame {:?}, not the body frame {:?}: their vectors are used as body-frame vectors",
                    m.header.frame_id,
                    self.body_frames[0]
                );
            }
        }
        let (s, source) = ros_to_imu_sample(m, clock, rx_ns);
        if source == RosTimeSource::Receive {
            self.counts.receive_timed += 1;
        }
        if imu_values(&s).is_err() {
            self.counts.invalid += 1;
            return None;
        }
        let t = s.header.meas_time_ns;
        if self.last_t.is_some_and(|l| t <= l) {
            self.counts.time += 1;
            return None;
        }
        self.last_t = Some(t);
        Some(s)
    }

    /// Counts a message that did not decode.
    pub fn undecodable(&mut self) {
        self.counts.received += 1;
        self.counts.undecodable += 1;
    }

    /// The heartbeat's counters (all but `published`).
    #[must_use]
    pub fn health(&self, clock: &ClockOffset) -> insuwb_runtime::HealthCounters {
        let c = &self.counts;
        insuwb_runtime::HealthCounters {
            received: c.received,
            dropped_invalid: c.invalid.saturating_add(c.undecodable),
            dropped_time: c.time,
            stage: StageCounters::Ros2Source(Ros2SourceCounters {
                receive_timed: c.receive_timed,
                undecodable: c.undecodable,
                clock_offset_ns: clock.offset_ns.wrapping_neg(),
                other_frame: c.other_frame,
            }),
            ..insuwb_runtime::HealthCounters::default()
        }
    }
}

/// The driver's state: OK while messages arrive, DEGRADED before the first
/// and after [`SILENT_NS`] without one.
#[must_use]
pub fn source_state(last_msg_ns: Option<u64>, now_ns: u64) -> HealthState {
    match last_msg_ns {
        Some(t) if now_ns.saturating_sub(t) < SILENT_NS => HealthState::Ok,
        _ => HealthState::Degraded,
    }
}

/// Runs the IMU driver on the ROS 2 source `ros2:TOPIC` (its topic, checked
/// as the source was parsed) until SIGINT/SIGTERM.
///
/// # Errors
/// [`Ros2SourceError`] for a build without the feature; the subscriber
/// cannot be opened; a port, the waiter or the reader fails.
#[cfg(feature = "ros2-source")]
pub fn run(cfg: &RobotConfig, topic: &str) -> anyhow::Result<()> {
    use std::time::Duration;

    use anyhow::Context;
    use insuwb_msg::topics;
    use insuwb_ros2::subscribe::ImuSubscriber;
    use insuwb_runtime::{monotonic_ns, Stage, Wake};

    /// Longest wait for a message: bounds the delay of a heartbeat or a
    /// shutdown.
    const RECV_TIMEOUT: Duration = Duration::from_millis(20);
    /// Messages taken at most per round after the first.
    const BATCH: usize = 256;

    let name = crate::source::Want::Imu.role().name();
    let stage = Stage::new(cfg.runtime(name))?;
    let mut imu_pub = stage.publisher::<ImuSample>(topics::IMU)?;
    let mut health = stage.health_reporter()?;
    let waiter = stage.waiter()?;
    let hb = waiter.attach_interval(health.period())?;
    let mut sub = ImuSubscriber::open(&cfg.ros2, topic)
        .with_context(|| format!("sources.imu = \"ros2:{topic}\": opening the ROS 2 subscriber"))?;
    tracing::info!(
        "{name} driver: ROS 2 topic {} (sensor_msgs/Imu, domain {}, node {}/{}), generation {}",
        sub.topic(),
        cfg.ros2.domain_id,
        cfg.ros2.namespace,
        insuwb_ros2::subscribe::node_name(&cfg.ros2),
        stage.generation()
    );
    let mut intake = Intake::new(&cfg.ros2);
    let mut clock = ClockOffset::measure(cfg.ros2.stamp_clock);
    let mut counters = insuwb_runtime::HealthCounters::default();
    let mut last_msg_ns: Option<u64> = None;
    let mut last_state: Option<HealthState> = None;
    loop {
        let beat = match waiter.wait_timeout(Duration::ZERO)? {
            Wake::Shutdown => break,
            Wake::Fired(f) => f.contains(&hb),
            Wake::Timeout => false,
        };
        let mut next = sub.recv_timeout(RECV_TIMEOUT);
        for _ in 0..BATCH {
            match next {
                Ok(Some(m)) => {
                    let rx = monotonic_ns();
                    last_msg_ns = Some(rx);
                    if let Some(s) = intake.take(&m, &clock, rx) {
                        imu_pub.publish(s)?;
                    }
                }
                Ok(None) => break,
                Err(e) if e.is_recoverable() => {
                    intake.undecodable();
                    let n = intake.counts().undecodable;
                    if n % 1000 == 1 {
                        tracing::warn!("{name} driver: {} ({n} so far): {e}", sub.topic());
                    }
                }
                Err(e) => return Err(e).context(format!("reading {}", sub.topic())),
            }
            next = sub.try_recv();
        }
        let state = source_state(last_msg_ns, monotonic_ns());
        if last_state != Some(state) {
            match state {
                HealthState::Ok => tracing::info!("{name} driver: {}: receiving", sub.topic()),
                _ if last_state.is_some() => tracing::warn!(
                    "{name} driver: {}: no message for {} ms",
                    sub.topic(),
                    SILENT_NS / 1_000_000
                ),
                _ => {}
            }
        }
        if beat || last_state != Some(state) {
            if beat {
                clock = ClockOffset::measure(cfg.ros2.stamp_clock);
            }
            counters = intake.health(&clock);
            counters.published = imu_pub.published();
            health.report(&counters, state)?;
            last_state = Some(state);
            // Late subscribers get history only when the publisher acts.
            imu_pub.update_connections()?;
        }
    }
    health.report(&counters, HealthState::Stopping)?;
    tracing::info!(
        "{name} driver: stopped after {} samples from {}",
        counters.published,
        sub.topic()
    );
    Ok(())
}

/// Refuses the ROS 2 source `ros2:TOPIC`: this build has no DDS subscriber.
///
/// # Errors
/// Always [`Ros2SourceError::NotBuilt`].
#[cfg(not(feature = "ros2-source"))]
pub fn run(_cfg: &RobotConfig, topic: &str) -> anyhow::Result<()> {
    Err(Ros2SourceError::NotBuilt {
        topic: topic.to_owned(),
    }
    .into())
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

    use insuwb_ros2::msgs::{Header, Time, Vector3};

    use super::*;

    fn msg(t_ns: u64, accel: [f64; 3], gyro: [f64; 3]) -> Imu {
        let v = |a: [f64; 3]| Vector3 {
            x: a[0],
            y: a[1],
            z: a[2],
        };
        Imu {
            header: Header {
                stamp: Time {
                    sec: i32::try_from(t_ns / 1_000_000_000).unwrap(),
                    nanosec: u32::try_from(t_ns % 1_000_000_000).unwrap(),
                },
                frame_id: "base_link".into(),
            },
            linear_acceleration: v(accel),
            angular_velocity: v(gyro),
            ..Imu::default()
        }
    }

    #[test]
    fn samples_are_timed_checked_and_counted_as_device_samples() {
        let mut i = Intake::new(&Ros2Config::default());
        let clock = ClockOffset::ZERO;
        let rx = 10_000_000_000;
        let a = [0.1, 0.2, 9.8];
        let g = [0.01, 0.0, -0.3];
        let s = i.take(&msg(rx - 2_000_000, a, g), &clock, rx).unwrap();
        assert_eq!(s.header.meas_time_ns, rx - 2_000_000);
        assert_eq!((s.accel_mps2, s.gyro_rps), (a, g));
        // NaN, out of range: invalid.
        assert!(i
            .take(&msg(rx - 1_000_000, [f64::NAN, 0.0, 0.0], g), &clock, rx)
            .is_none());
        assert!(i
            .take(&msg(rx - 1_000_000, a, [80.0, 0.0, 0.0]), &clock, rx)
            .is_none());
        // Older than its predecessor, or the same time: time.
        assert!(i.take(&msg(rx - 3_000_000, a, g), &clock, rx).is_none());
        assert!(i.take(&msg(rx - 2_000_000, a, g), &clock, rx).is_none());
        // No stamp: the receive time.
        let mut unstamped = msg(0, a, g);
        unstamped.header.frame_id = "imu_link".into();
        assert_eq!(
            i.take(&unstamped, &clock, rx + 5)
                .unwrap()
                .header
                .meas_time_ns,
            rx + 5
        );
        i.undecodable();
        assert_eq!(
            i.counts(),
            IntakeCounts {
                received: 7,
                invalid: 2,
                time: 2,
                receive_timed: 1,
                undecodable: 1,
                other_frame: 1,
            }
        );
        let h = i.health(&ClockOffset { offset_ns: 5 });
        assert_eq!((h.received, h.dropped_invalid, h.dropped_time), (7, 3, 2));
        assert_eq!(
            h.stage,
            StageCounters::Ros2Source(Ros2SourceCounters {
                receive_timed: 1,
                undecodable: 1,
                clock_offset_ns: -5,
                other_frame: 1,
            })
        );
    }

    #[test]
    fn state_follows_the_messages() {
        assert_eq!(source_state(None, 5), HealthState::Degraded);
        assert_eq!(
            source_state(Some(100), 100 + SILENT_NS - 1),
            HealthState::Ok
        );
        assert_eq!(
            source_state(Some(100), 100 + SILENT_NS),
            HealthState::Degraded
        );
    }

    #[cfg(not(feature = "ros2-source"))]
    #[test]
    fn without_the_feature_the_source_is_refused_by_name() {
        let cfg = RobotConfig::default();
        let e = run(&cfg, "/imu").unwrap_err().to_string();
        assert!(
            e.contains("sources.imu = \"ros2:/imu\"") && e.contains("ros2-source"),
            "{e}"
        );
    }
}
