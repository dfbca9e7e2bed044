//! How the fleet's samples reach the station: per robot the samples
//! received, the ones lost on the way (gaps in the publisher's sequence
//! numbers, [`SeqTracker`]) and the delay of each pose from its stamp to
//! its arrival; for the station the delays of every pose in a histogram of
//! bounded size ([`DelayHistogram`], an HDR histogram of the `hdrhistogram`
//! crate), so a station that runs for days does not grow.
//!
//! A publisher counts the samples of each key from 0 when it starts (the
//! `seq` of the payloads' attachment): a sample whose `seq` jumps ahead
//! follows lost ones, one whose `seq` does not move ahead starts a new run
//! (the bridge restarted). The first sample a station sees of a robot
//! starts a run too: what was published before the station listened is not
//! a loss.
//!
//! ```
//! use insuwb_fleet::delivery::Delivery;
//!
//! let mut d = Delivery::default();
//! for (seq, delay_ns) in [(5, 1_000_000), (6, 2_000_000), (9, 1_500_000), (0, 1_000_000)] {
//!     d.on_pose("r1", seq, delay_ns);
//! }
//! let r = d.robot("r1").unwrap();
//! assert_eq!((r.poses.received(), r.poses.gaps(), r.poses.runs()), (4, 2, 2));
//! let s = d.summary();
//! assert_eq!((s.poses, s.gaps), (4, 2));
//! assert!((s.delay_p50_ms.unwrap() - 1.0).abs() < 0.05);
//! ```

use std::collections::BTreeMap;

use hdrhistogram::Histogram;
use serde::{Deserialize, Serialize};

/// The sequence numbers of one key from one robot.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SeqTracker {
    last: Option<u64>,
    received: u64,
    gaps: u64,
    runs: u64,
}

impl SeqTracker {
    /// Notes sample `seq`; returns how many samples were lost just before
    /// it (0 for the first of a run).
    pub fn note(&mut self, seq: u64) -> u64 {
        self.received += 1;
        let lost = match self.last {
            Some(last) if seq > last => seq - last - 1,
            // The first sample seen, or a publisher that started again.
            _ => {
                self.runs += 1;
                0
            }
        };
        self.gaps += lost;
        self.last = Some(seq);
        lost
    }

    /// Samples received.
    #[must_use]
    pub fn received(&self) -> u64 {
        self.received
    }

    /// Samples lost: the sum of the gaps in the sequence numbers.
    #[must_use]
    pub fn gaps(&self) -> u64 {
        self.gaps
    }

    /// Runs of the publisher seen (1 + restarts seen by their `seq`).
    #[must_use]
    pub fn runs(&self) -> u64 {
        self.runs
    }

    /// The last sequence number received.
    #[must_use]
    pub fn last(&self) -> Option<u64> {
        self.last
    }
}

/// Significant decimal digits the histogram keeps: quantiles are within
/// 1 % of the value (hdrhistogram's precision for 2 digits).
const SIGNIFICANT_DIGITS: u8 = 2;
/// The largest value the histogram tells apart (hdrhistogram's ceiling,
/// 2^63 - 1 ns: 292 years); larger values count as it.
const HIGHEST_NS: u64 = u64::MAX / 2;

/// Non-negative values (ns) in a high-dynamic-range histogram of the
/// `hdrhistogram` crate: quantiles within 1 % from 1 ns to 292 years, in a
/// fixed 57 KiB whatever the count; the largest value is kept exactly.
#[derive(Clone)]
pub struct DelayHistogram {
    /// `None` only if hdrhistogram refused the constant bounds (it does
    /// not: a test checks it); then nothing is counted.
    hist: Option<Histogram<u64>>,
    max: u64,
}

impl Default for DelayHistogram {
    fn default() -> Self {
        Self {
            hist: Histogram::new_with_bounds(1, HIGHEST_NS, SIGNIFICANT_DIGITS).ok(),
            max: 0,
        }
    }
}

impl std::fmt::Debug for DelayHistogram {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DelayHistogram")
            .field("count", &self.count())
            .field("p50", &self.quantile(0.5))
            .field("p99", &self.quantile(0.99))
            .field("max", &self.max)
            .finish()
    }
}

impl DelayHistogram {
    /// Counts `v` (values above 2^63 - 1 count as that in the quantiles).
    pub fn record(&mut self, v: u64) {
        if let Some(h) = &mut self.hist {
            h.saturating_record(v);
            self.max = self.max.max(v);
        }
    }

    /// Values counted.
    #[must_use]
    pub fn count(&self) -> u64 {
        self.hist.as_ref().map_or(0, Histogram::len)
    }

    /// The largest value counted, exactly (0 when none).
    #[must_use]
    pub fn max(&self) -> u64 {
        self.max
    }

    /// The value at quantile `q` (0 to 1; the smallest value with at least
    /// that share of the counts at or below it, within 1 %, at most
    /// [`DelayHistogram::max`]), `None` when empty.
    #[must_use]
    pub fn quantile(&self, q: f64) -> Option<u64> {
        let h = self.hist.as_ref().filter(|h| !h.is_empty())?;
        Some(h.value_at_quantile(q.clamp(0.0, 1.0)).min(self.max))
    }
}

/// What reached the station of one robot.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RobotDelivery {
    /// Its poses' sequence numbers.
    pub poses: SeqTracker,
    /// Its health samples' sequence numbers.
    pub health: SeqTracker,
    /// The delay of its last pose, ns: receive time minus stamp, both in
    /// the robots' stamp clock (negative where the robot's clock is ahead
    /// of the station's).
    pub last_delay_ns: Option<i64>,
}

/// The station's delivery totals, as the snapshots carry them.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct DeliverySummary {
    /// Poses received.
    pub poses: u64,
    /// Health samples received.
    pub health: u64,
    /// Samples lost on the way (gaps in the sequence numbers, poses and
    /// health).
    pub gaps: u64,
    /// Samples that were not fleet payloads of this version (not counted
    /// elsewhere).
    pub invalid: u64,
    /// Samples of robots the station does not track because it tracked
    /// `max_robots` already (not counted elsewhere; the station's count,
    /// [`crate::station::Station::excess`], which [`Delivery::summary`]
    /// leaves at 0 and [`crate::view::Snapshot::new`] fills in).
    #[serde(default)]
    pub excess: u64,
    /// Puts of a robot under another robot's keys (or of a peer that is no
    /// listed robot) that the station's router refused (identity bound to
    /// the certificate; the station's count, which [`Delivery::summary`]
    /// leaves at 0 and the Zenoh station fills in).
    #[serde(default)]
    pub refused: u64,
    /// Delay of the poses (receive time minus stamp), median, ms (`null`
    /// before the first pose).
    pub delay_p50_ms: Option<f64>,
    /// Same, 99th percentile, ms.
    pub delay_p99_ms: Option<f64>,
    /// Same, largest, ms.
    pub delay_max_ms: Option<f64>,
}

/// What reached the station: every robot's [`RobotDelivery`], the delays
/// of every pose, the invalid samples.
#[derive(Debug, Clone, Default)]
pub struct Delivery {
    robots: BTreeMap<String, RobotDelivery>,
    delay: DelayHistogram,
    invalid: u64,
}

fn ms(ns: u64) -> f64 {
    ns as f64 * 1e-6
}

impl Delivery {
    fn entry(&mut self, robot: &str) -> &mut RobotDelivery {
        self.robots.entry(robot.to_owned()).or_default()
    }

    /// A pose of `robot`, sample `seq` of its publisher, `delay_ns` after
    /// its stamp (a negative delay counts as 0 in the histogram).
    pub fn on_pose(&mut self, robot: &str, seq: u64, delay_ns: i64) {
        let r = self.entry(robot);
        r.poses.note(seq);
        r.last_delay_ns = Some(delay_ns);
        self.delay.record(u64::try_from(delay_ns).unwrap_or(0));
    }

    /// A health sample of `robot`, sample `seq` of its publisher.
    pub fn on_health(&mut self, robot: &str, seq: u64) {
        self.entry(robot).health.note(seq);
    }

    /// A sample that is not a fleet payload of this version.
    pub fn on_invalid(&mut self) {
        self.invalid += 1;
    }

    /// What reached the station of `robot`.
    #[must_use]
    pub fn robot(&self, robot: &str) -> Option<&RobotDelivery> {
        self.robots.get(robot)
    }

    /// The delays of every pose.
    #[must_use]
    pub fn delays(&self) -> &DelayHistogram {
        &self.delay
    }

    /// The totals.
    #[must_use]
    pub fn summary(&self) -> DeliverySummary {
        let sum = |f: fn(&RobotDelivery) -> u64| self.robots.values().map(f).sum::<u64>();
        let any = self.delay.count() > 0;
        DeliverySummary {
            poses: sum(|r| r.poses.received()),
            health: sum(|r| r.health.received()),
            gaps: sum(|r| r.poses.gaps() + r.health.gaps()),
            invalid: self.invalid,
            excess: 0,
            refused: 0,
            delay_p50_ms: self.delay.quantile(0.5).map(ms),
            delay_p99_ms: self.delay.quantile(0.99).map(ms),
            delay_max_ms: any.then(|| ms(self.delay.max())),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaps_are_counted_and_a_restart_starts_a_run() {
        let mut t = SeqTracker::default();
        assert_eq!(t.note(10), 0, "the first sample seen is no gap");
        assert_eq!(t.note(11), 0);
        assert_eq!(t.note(14), 2);
        assert_eq!(t.note(0), 0, "a restarted publisher");
        assert_eq!(t.note(1), 0);
        assert_eq!(t.note(1), 0, "a repeat starts a run too");
        assert_eq!((t.received(), t.gaps(), t.runs()), (6, 2, 3));
        assert_eq!(t.last(), Some(1));
    }

    #[test]
    fn every_magnitude_is_kept_within_1_percent_in_a_fixed_size() {
        let size = |h: &DelayHistogram| h.hist.as_ref().map(Histogram::distinct_values);
        let empty = DelayHistogram::default();
        assert!(empty.hist.is_some(), "hdrhistogram takes the bounds");
        let values = (0..64u32)
            .map(|e| 1u64 << e)
            .chain([0, 3, 999, 12_345_678, u64::MAX]);
        for v in values {
            let mut h = DelayHistogram::default();
            h.record(v);
            let got = h.quantile(0.5).unwrap();
            let want = v.min(HIGHEST_NS) as f64;
            assert!((got as f64 - want).abs() <= want / 100.0, "{v}: {got}");
            assert_eq!(h.max(), v, "the max is exact");
            assert_eq!(size(&h), size(&empty), "no growth");
        }
        // 57 KiB of counts.
        assert_eq!(size(&empty).map(|n| n * 8 / 1024), Some(57));
    }

    #[test]
    fn quantiles_of_a_known_spread() {
        let mut h = DelayHistogram::default();
        assert_eq!(h.quantile(0.5), None);
        for us in 1..=1000u64 {
            h.record(us * 1000);
        }
        let near = |q: f64, want: f64| {
            let got = h.quantile(q).unwrap() as f64;
            assert!((got - want).abs() <= want / 100.0, "q {q}: {got} vs {want}");
        };
        near(0.0, 1_000.0);
        near(0.1, 100_000.0);
        near(0.5, 500_000.0);
        near(0.99, 990_000.0);
        near(1.0, 1_000_000.0);
        assert_eq!(h.quantile(1.0), Some(1_000_000), "clamped to the max");
        assert_eq!(h.quantile(7.0), Some(1_000_000), "q clamped to 1");
        assert_eq!((h.count(), h.max()), (1000, 1_000_000));
    }

    #[test]
    fn the_summary_adds_up_robots_and_clamps_negative_delays() {
        let mut d = Delivery::default();
        d.on_pose("r1", 0, 2_000_000);
        d.on_pose("r1", 2, 2_000_000);
        d.on_pose("r2", 7, -5_000_000);
        d.on_health("r2", 0);
        d.on_health("r2", 3);
        d.on_invalid();
        let s = d.summary();
        assert_eq!((s.poses, s.health, s.gaps, s.invalid), (3, 2, 3, 1));
        assert_eq!(s.delay_max_ms, Some(2.0));
        assert_eq!(d.robot("r2").unwrap().last_delay_ns, Some(-5_000_000));
        assert_eq!(d.delays().quantile(0.0), Some(0), "negative counts as 0");
        assert!(d.robot("r3").is_none());
        let j = serde_json::to_value(s).unwrap();
        assert_eq!(j["gaps"], 3);
        assert_eq!(DeliverySummary::default().delay_p50_ms, None);
    }
}
