//! The bridge's intake of a downward range finder from ROS (`[ros2]
//! height_in`): each `sensor_msgs/Range` made a [`Height`] of source range
//! finder, checked by the one check of heights ([`HeightGate`]: values,
//! then a time strictly after the previous accepted one's), counted. Pure:
//! no DDS, no iceoryx2 (the bridge takes the messages and publishes what
//! this accepts).
//!
//! A reading outside the sensor's own limits is no distance: REP 117's
//! `-inf` (closer than `min_range`) and `+inf` (nothing within
//! `max_range`), and any finite range below `min_range` or above
//! `max_range` (where the message gives `0 <= min_range <= max_range`),
//! are dropped and counted before the gate. The range is taken along the
//! body's z axis, whatever the message's frame: the ranger must look down
//! along it, below the IMU by `[fusion.aiding.height] range_offset_m`.
//!
//! ```
//! use insuwb_report::clock::ClockOffset;
//! use insuwb_ros2::height_in::HeightIntake;
//! use insuwb_ros2::msgs::{Range, Time};
//! let mut intake = HeightIntake::new();
//! let mut m = Range { min_range: 0.04, max_range: 4.0, range: 1.25, ..Range::default() };
//! m.header.stamp = Time { sec: 1, nanosec: 0 };
//! let h = intake.take(&m, &ClockOffset::ZERO, 1_000_500_000).unwrap();
//! assert_eq!((h.header.meas_time_ns, h.range_m), (1_000_000_000, 1.25));
//! // Nothing within reach (REP 117): no height, counted.
//! m.header.stamp.nanosec = 40_000_000;
//! m.range = f32::INFINITY;
//! assert!(intake.take(&m, &ClockOffset::ZERO, 1_040_500_000).is_none());
//! assert_eq!(intake.counts().beyond_limits, 1);
//! ```

use insuwb_msg::check::{HeightGate, HeightRefusals};
use insuwb_msg::Height;
use insuwb_report::clock::ClockOffset;

use crate::convert::{measurement_time, RosTimeSource};
use crate::msgs::Range;

/// What the intake counted of the messages.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct HeightInCounts {
    /// Messages taken (decoded or not).
    pub received: u64,
    /// Heights accepted (the gate passed them).
    pub accepted: u64,
    /// Readings outside the sensor's own limits (REP 117's `±inf`, or
    /// beyond `min_range` / `max_range`): no distance, dropped.
    pub beyond_limits: u64,
    /// Heights timed by their receive time (stamp unset, ahead or too
    /// old).
    pub receive_timed: u64,
    /// Messages that did not decode as `sensor_msgs/Range`.
    pub undecodable: u64,
}

/// Turns received range messages into checked heights.
#[derive(Debug, Default)]
pub struct HeightIntake {
    gate: HeightGate,
    counts: HeightInCounts,
}

/// Whether `m`'s reading lies outside the limits the message states
/// (always for `±inf`; for a finite range only where `0 <= min_range <=
/// max_range`, finite, so that a sensor that leaves its limits at 0 is
/// not refused for them).
fn beyond_limits(m: &Range) -> bool {
    if m.range.is_infinite() {
        return true;
    }
    let (lo, hi) = (m.min_range, m.max_range);
    let stated = lo.is_finite() && hi.is_finite() && 0.0 <= lo && lo <= hi && hi > 0.0;
    stated && (m.range < lo || m.range > hi)
}

impl HeightIntake {
    /// An intake that has seen nothing.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// The height of message `m` received at `rx_ns` (CLOCK_MONOTONIC)
    /// with the stamp clock's offset `clock`, timed by
    /// [`measurement_time`] of its stamp; `None` when the reading is
    /// beyond the sensor's limits or the gate refuses it (counted in
    /// [`HeightIntake::counts`], [`HeightIntake::refusals`]).
    pub fn take(&mut self, m: &Range, clock: &ClockOffset, rx_ns: u64) -> Option<Height> {
        self.counts.received += 1;
        if beyond_limits(m) {
            self.counts.beyond_limits += 1;
            return None;
        }
        let (t, time) = measurement_time(&m.header.stamp, clock, rx_ns);
        let h = Height {
            header: insuwb_msg::Header::new(0, t),
            range_m: f64::from(m.range),
            source: Height::SOURCE_RANGE_FINDER,
        };
        match self.gate.check(&h) {
            Ok(()) => {
                if time == RosTimeSource::Receive {
                    self.counts.receive_timed += 1;
                }
                self.counts.accepted += 1;
                Some(h)
            }
            Err(e) => {
                crate::convert::warn_refused("range", self.gate.refusals().total(), &e);
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
    pub fn counts(&self) -> HeightInCounts {
        self.counts
    }

    /// The heights refused so far, by reason.
    #[must_use]
    pub fn refusals(&self) -> &HeightRefusals {
        self.gate.refusals()
    }

    /// Messages dropped for their values (`Health::dropped_invalid`):
    /// refused values, readings beyond the sensor's limits and
    /// undecodable messages.
    #[must_use]
    pub fn dropped_invalid(&self) -> u64 {
        self.refusals()
            .invalid()
            .saturating_add(self.counts.beyond_limits)
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
    use crate::msgs::{Header, Time};

    fn range(t_ns: u64, r: f32, min: f32, max: f32) -> Range {
        Range {
            header: Header {
                stamp: Time {
                    sec: i32::try_from(t_ns / 1_000_000_000).unwrap(),
                    nanosec: u32::try_from(t_ns % 1_000_000_000).unwrap(),
                },
                frame_id: "range_down".into(),
            },
            radiation_type: Range::INFRARED,
            field_of_view: 0.47,
            min_range: min,
            max_range: max,
            range: r,
        }
    }

    #[test]
    fn counts_each_message_by_what_became_of_it() {
        let mut intake = HeightIntake::new();
        let z = ClockOffset::ZERO;
        let rx = 10_000_000_000;
        let h = intake.take(&range(9_000_000_000, 0.8, 0.04, 4.0), &z, rx);
        assert_eq!(
            h.map(|h| (h.header.meas_time_ns, h.range_m, h.source)),
            Some((
                9_000_000_000,
                f64::from(0.8f32),
                Height::SOURCE_RANGE_FINDER
            ))
        );
        // REP 117 both ways, and finite readings beyond the stated limits.
        for r in [f32::NEG_INFINITY, f32::INFINITY, 0.02, 4.5] {
            assert!(intake
                .take(&range(9_100_000_000, r, 0.04, 4.0), &z, rx)
                .is_none());
        }
        // No stated limits (both 0): a finite reading passes to the gate.
        assert!(intake
            .take(&range(9_200_000_000, 6.0, 0.0, 0.0), &z, rx)
            .is_some());
        // NaN, zero, 100 m and beyond: the gate's values.
        for (i, r) in [f32::NAN, 0.0, 150.0].into_iter().enumerate() {
            let t = 9_300_000_000 + 10_000_000 * u64::try_from(i).unwrap();
            assert!(intake.take(&range(t, r, 0.0, 0.0), &z, rx).is_none());
        }
        // An older stamp, then the same stamp again.
        assert!(intake
            .take(&range(9_150_000_000, 1.0, 0.04, 4.0), &z, rx)
            .is_none());
        assert!(intake
            .take(&range(9_200_000_000, 1.0, 0.04, 4.0), &z, rx)
            .is_none());
        intake.undecodable();
        // Unset stamp: the receive time, after the last one.
        assert_eq!(
            intake
                .take(&range(0, 1.0, 0.04, 4.0), &z, rx)
                .map(|h| h.header.meas_time_ns),
            Some(rx)
        );
        assert_eq!(
            intake.counts(),
            HeightInCounts {
                received: 13,
                accepted: 3,
                beyond_limits: 4,
                receive_timed: 1,
                undecodable: 1,
            }
        );
        let r = intake.refusals();
        assert_eq!(
            (
                r.non_finite,
                r.out_of_range,
                r.time_backwards,
                r.time_repeated
            ),
            (1, 2, 1, 1)
        );
        assert_eq!((intake.dropped_invalid(), intake.dropped_time()), (8, 2));
    }
}
