//! The bridge's intake of a robot base's odometry from ROS (`[ros2]
//! odometry_in`): each message's twist made a body velocity
//! ([`crate::convert::TwistMessage`]), checked by the one check of body
//! velocities ([`VelocityGate`]: values, then a time strictly after the
//! previous accepted one's), counted. Pure: no DDS, no iceoryx2 (the
//! bridge takes the messages and publishes what this accepts).
//!
//! ```
//! use insuwb_report::clock::ClockOffset;
//! use insuwb_ros2::config::Ros2Config;
//! use insuwb_ros2::msgs::{Header, Odometry, Time};
//! use insuwb_ros2::odometry_in::OdometryIntake;
//! let mut intake = OdometryIntake::new(&Ros2Config::default());
//! let mut m = Odometry { child_frame_id: "base_link".into(), ..Odometry::default() };
//! m.header.stamp = Time { sec: 1, nanosec: 0 };
//! m.twist.twist.linear.x = 0.5;
//! m.twist.covariance.0[0] = 0.01; // x: sigma 0.1 m/s
//! m.twist.covariance.0[7] = 1e6; // y, z: not measured
//! m.twist.covariance.0[14] = 1e6;
//! let v = intake.take(&m, &ClockOffset::ZERO, 1_000_500_000).unwrap();
//! assert_eq!((v.header.meas_time_ns, v.vel_mps[0], v.sigma_mps), (1_000_000_000, 0.5, [0.1, 0.0, 0.0]));
//! // The same stamp again: refused and counted.
//! assert!(intake.take(&m, &ClockOffset::ZERO, 1_000_600_000).is_none());
//! assert_eq!(intake.refusals().time_repeated, 1);
//! ```

use insuwb_msg::check::{VelocityGate, VelocityRefusals};
use insuwb_msg::BodyVelocity;
use insuwb_report::clock::ClockOffset;

use crate::config::Ros2Config;
use crate::convert::{RosTimeSource, TwistMessage};

/// What the intake counted of the messages.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct OdometryInCounts {
    /// Messages taken (decoded or not).
    pub received: u64,
    /// Velocities accepted (the gate passed them).
    pub accepted: u64,
    /// Messages whose twist is in a frame other than the body frame (used
    /// all the same).
    pub other_frame: u64,
    /// Velocities timed by their receive time (stamp unset, ahead or too
    /// old).
    pub receive_timed: u64,
    /// Messages that did not decode as the configured type.
    pub undecodable: u64,
}

/// Turns received odometry messages into checked body velocities.
#[derive(Debug)]
pub struct OdometryIntake {
    body_frame: String,
    default_sigma_mps: f64,
    gate: VelocityGate,
    counts: OdometryInCounts,
}

impl OdometryIntake {
    /// An intake whose body frame is `[ros2] child_frame_id` and whose
    /// sigma of an axis without variance is `odometry_in_sigma_mps`.
    #[must_use]
    pub fn new(ros2: &Ros2Config) -> Self {
        Self {
            body_frame: ros2.child_frame_id.clone(),
            default_sigma_mps: ros2.odometry_in_sigma_mps,
            gate: VelocityGate::new(),
            counts: OdometryInCounts::default(),
        }
    }

    /// The body velocity of message `m` taken at `rx_ns` (CLOCK_MONOTONIC)
    /// with the stamp clock's offset `clock`; `None` when the gate refuses
    /// it (counted in [`OdometryIntake::refusals`]). A twist in another
    /// frame than the body frame is used as a body-frame vector, counted,
    /// and warned of once.
    pub fn take<M: TwistMessage>(
        &mut self,
        m: &M,
        clock: &ClockOffset,
        rx_ns: u64,
    ) -> Option<BodyVelocity> {
        self.counts.received += 1;
        if m.twist_frame() != self.body_frame {
            self.counts.other_frame += 1;
            if self.counts.other_frame == 1 {
                tracing::warn!(
                    "ros2: odometry in frame {:?}, not the body frame {:?} ([ros2] child_frame_id): its twist is used as a body-frame velocity",
                    m.twist_frame(),
                    self.body_frame
                );
            }
        }
        let v = m.body_velocity(self.default_sigma_mps, clock, rx_ns);
        if v.time == RosTimeSource::Receive {
            self.counts.receive_timed += 1;
        }
        match self.gate.check(&v.sample) {
            Ok(()) => {
                self.counts.accepted += 1;
                Some(v.sample)
            }
            Err(e) => {
                crate::convert::warn_refused("odometry", self.gate.refusals().total(), &e);
                None
            }
        }
    }

    /// Counts a message that did not decode.
    pub fn undecodable(&mut self) {
        self.counts.received += 1;
        self.counts.undecodable += 1;
    }

    /// What was counted so far.
    #[must_use]
    pub fn counts(&self) -> OdometryInCounts {
        self.counts
    }

    /// The velocities refused so far, by reason.
    #[must_use]
    pub fn refusals(&self) -> &VelocityRefusals {
        self.gate.refusals()
    }

    /// Messages dropped for their values (`Health::dropped_invalid`):
    /// refused values and undecodable messages.
    #[must_use]
    pub fn dropped_invalid(&self) -> u64 {
        self.refusals()
            .invalid()
            .saturating_add(self.counts.undecodable)
    }

    /// Messages dropped for their time (`Health::dropped_time`).
    #[must_use]
    pub fn dropped_time(&self) -> u64 {
        self.refusals().time()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::{Header, Odometry, Time, TwistStamped};

    fn odom(frame: &str, t_ns: u64, vx: f64, var: f64) -> Odometry {
        let mut m = Odometry {
            header: Header {
                stamp: Time {
                    sec: i32::try_from(t_ns / 1_000_000_000).unwrap(),
                    nanosec: u32::try_from(t_ns % 1_000_000_000).unwrap(),
                },
                frame_id: "odom".into(),
            },
            child_frame_id: frame.into(),
            ..Odometry::default()
        };
        m.twist.twist.linear.x = vx;
        for i in [0, 7, 14] {
            m.twist.covariance.0[i] = var;
        }
        m
    }

    #[test]
    fn counts_each_message_by_what_became_of_it() {
        let c = Ros2Config::default();
        let mut intake = OdometryIntake::new(&c);
        let z = ClockOffset::ZERO;
        let rx = 10_000_000_000;
        assert!(intake
            .take(&odom("base_link", 9_000_000_000, 1.0, 0.0), &z, rx)
            .is_some());
        // Another frame: used, counted.
        let v = intake
            .take(&odom("wheels", 9_100_000_000, 1.0, 0.04), &z, rx)
            .unwrap();
        assert_eq!(v.sigma_mps, [0.2; 3]);
        // Invalid values, an older stamp.
        assert!(intake
            .take(&odom("base_link", 9_200_000_000, f64::NAN, 0.0), &z, rx)
            .is_none());
        assert!(intake
            .take(&odom("base_link", 9_300_000_000, 1.0, -1.0), &z, rx)
            .is_none());
        assert!(intake
            .take(&odom("base_link", 9_050_000_000, 1.0, 0.0), &z, rx)
            .is_none());
        intake.undecodable();
        // Unset stamp: the receive time, after the last one.
        assert!(intake
            .take(&odom("base_link", 0, 1.0, 0.0), &z, rx)
            .is_some());
        let n = intake.counts();
        assert_eq!(
            n,
            OdometryInCounts {
                received: 7,
                accepted: 3,
                other_frame: 1,
                receive_timed: 1,
                undecodable: 1,
            }
        );
        assert_eq!((intake.dropped_invalid(), intake.dropped_time()), (3, 1));
        let r = intake.refusals();
        assert_eq!((r.non_finite, r.sigma, r.time_backwards), (1, 1, 1));
    }

    #[test]
    fn twist_stamped_messages_go_through_the_same_gate() {
        let c = Ros2Config {
            odometry_in_sigma_mps: 0.3,
            ..Ros2Config::default()
        };
        let mut intake = OdometryIntake::new(&c);
        let mut m = TwistStamped::default();
        m.header.frame_id = "base_link".into();
        m.header.stamp = Time { sec: 2, nanosec: 0 };
        m.twist.linear.x = 0.4;
        let v = intake.take(&m, &ClockOffset::ZERO, 2_100_000_000).unwrap();
        assert_eq!((v.vel_mps[0], v.sigma_mps), (0.4, [0.3; 3]));
        m.twist.linear.x = 500.0;
        m.header.stamp.nanosec = 1;
        assert!(intake.take(&m, &ClockOffset::ZERO, 2_100_000_000).is_none());
        assert_eq!(intake.refusals().out_of_range, 1);
        assert_eq!(intake.counts().other_frame, 0);
    }
}
