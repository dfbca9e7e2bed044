//! The clock of the stamps a bridge writes: insuwb headers hold
//! CLOCK_MONOTONIC ns; ROS nodes, Foxglove and a fleet station stamp with
//! the system clock (CLOCK_REALTIME). A [`ClockOffset`] maps one to the
//! other by an offset measured at start and again at each report period
//! ([`StampClock::Realtime`], the default), or keeps the monotonic value
//! ([`StampClock::Monotonic`]).

use serde::{Deserialize, Serialize};

/// The clock of the stamps (`stamp_clock` of `[ros2]`, `[foxglove]`, `[zenoh]`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum StampClock {
    /// CLOCK_REALTIME (ROS system time): header time plus the offset
    /// between the clocks.
    #[default]
    Realtime,
    /// CLOCK_MONOTONIC, as in the insuwb headers (seconds since boot).
    Monotonic,
}

/// The offset from CLOCK_MONOTONIC to the stamp clock, ns.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ClockOffset {
    /// Stamp minus CLOCK_MONOTONIC, ns.
    pub offset_ns: i64,
}

impl ClockOffset {
    /// No offset (monotonic stamps).
    pub const ZERO: Self = Self { offset_ns: 0 };

    /// The offset of `clock` now: for the real-time clock, the reading of
    /// CLOCK_REALTIME between the two closest of 5 pairs of
    /// CLOCK_MONOTONIC readings.
    #[must_use]
    pub fn measure(clock: StampClock) -> Self {
        match clock {
            StampClock::Monotonic => Self::ZERO,
            StampClock::Realtime => {
                let mut best = (u64::MAX, 0i64);
                for _ in 0..5 {
                    let m1 = insuwb_runtime::monotonic_ns();
                    let r = realtime_ns();
                    let m2 = insuwb_runtime::monotonic_ns();
                    let width = m2.saturating_sub(m1);
                    if width < best.0 {
                        let mid = i128::from(m1) + i128::from(width / 2);
                        let off = i128::from(r) - mid;
                        best = (width, i64::try_from(off).unwrap_or(0));
                    }
                }
                Self { offset_ns: best.1 }
            }
        }
    }

    /// The stamp clock's time of a CLOCK_MONOTONIC time, ns (negative
    /// before 1970).
    #[must_use]
    pub fn stamp_ns(&self, monotonic_ns: u64) -> i128 {
        i128::from(monotonic_ns) + i128::from(self.offset_ns)
    }
}

/// CLOCK_REALTIME now, ns since 1970 (0 when the clock is before 1970).
fn realtime_ns() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_nanos()).unwrap_or(i64::MAX))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn realtime_offset_maps_now_to_now() {
        let off = ClockOffset::measure(StampClock::Realtime);
        let stamp = off.stamp_ns(insuwb_runtime::monotonic_ns());
        let real = i128::from(realtime_ns());
        assert!((real - stamp).abs() < 50_000_000, "{real} vs {stamp}");
        assert_eq!(
            ClockOffset::measure(StampClock::Monotonic),
            ClockOffset::ZERO
        );
    }
}
