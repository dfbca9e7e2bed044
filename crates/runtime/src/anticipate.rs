//! When the next sample of a periodic stream is due, learned from the last
//! two, so that a stage can get ready for it shortly before.
//!
//! A stage that sleeps between samples pays for it on the next one: after
//! ~100 ms asleep its code and data have left the caches (in a virtual
//! machine the core may even have run another guest), and the compute of
//! the fusion update costs several times its hot figure. [`Anticipator`]
//! gives the moment [`WARM_LEAD_NS`] before the next fix is due; the fusion
//! stage wakes then and runs its update once on a scratch copy. The floor
//! graph of `insuwb bench latency` wakes at the same moment (with nothing
//! to warm), so the two graphs keep the same wake-ups.

/// How long before the next sample is due a stage gets ready, ns: more
/// than the warm-up takes (16-21 us cold, measured in the fusion stage)
/// plus the publish jitter of a driver (tens of microseconds), little
/// enough that the caches stay warm (the fusion update on the path took a
/// median 10 us after a warm-up 120 us ahead, 12 us after one 250 us ahead,
/// 15-28 us without one; 3.3 us hot).
pub const WARM_LEAD_NS: u64 = 120_000;

/// Shortest period learned, ns (faster streams need no anticipation).
pub const MIN_PERIOD_NS: u64 = 5_000_000;
/// Longest period learned, ns (a longer gap is an outage, not a period).
pub const MAX_PERIOD_NS: u64 = 2_000_000_000;

/// The next due time of a periodic stream (see the module documentation).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Anticipator {
    last_meas_ns: Option<u64>,
    period_ns: Option<u64>,
    /// Smallest publish latency (publish minus measurement time) seen.
    min_latency_ns: Option<u64>,
    due_ns: Option<u64>,
}

impl Anticipator {
    /// Nothing learned yet.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// A sample of the stream arrived: its measurement time and publish time
    /// (CLOCK_MONOTONIC ns). The period is the difference of the last two
    /// measurement times when it lies in [[`MIN_PERIOD_NS`], [`MAX_PERIOD_NS`]];
    /// the next sample is expected one period after this one's measurement
    /// time plus the smallest publish latency seen (a sample published late
    /// does not move the next deadline onto the next sample's arrival).
    pub fn observe(&mut self, meas_ns: u64, pub_ns: u64) {
        if let Some(last) = self.last_meas_ns {
            let d = meas_ns.saturating_sub(last);
            self.period_ns = (MIN_PERIOD_NS..=MAX_PERIOD_NS).contains(&d).then_some(d);
        }
        let latency = pub_ns.saturating_sub(meas_ns);
        let lat = self.min_latency_ns.map_or(latency, |l| l.min(latency));
        self.min_latency_ns = Some(lat);
        self.last_meas_ns = Some(meas_ns);
        self.due_ns = self.period_ns.map(|p| {
            meas_ns
                .saturating_add(p)
                .saturating_add(lat)
                .saturating_sub(WARM_LEAD_NS)
        });
    }

    /// When to get ready for the next sample, if known and not done yet.
    #[must_use]
    pub fn deadline(&self) -> Option<u64> {
        self.due_ns
    }

    /// The deadline to wait for at `now_ns`: this one, or `now_ns + max_ns`
    /// when that comes first or none is known (a loop that also serves
    /// other wake-ups waits at most `max_ns`).
    #[must_use]
    pub fn deadline_within(&self, now_ns: u64, max_ns: u64) -> u64 {
        let limit = now_ns.saturating_add(max_ns);
        self.due_ns.map_or(limit, |d| d.min(limit))
    }

    /// True once when the deadline has passed at `now_ns`; the deadline is
    /// then cleared until the next [`Anticipator::observe`] (no sample: no
    /// further wake-up).
    pub fn take_due(&mut self, now_ns: u64) -> bool {
        match self.due_ns {
            Some(d) if now_ns >= d => {
                self.due_ns = None;
                true
            }
            _ => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    #[test]
    fn the_deadline_is_one_period_on_less_the_lead() {
        let mut a = Anticipator::new();
        a.observe(1_000 * MS, 1_000 * MS + 40_000);
        assert_eq!(a.deadline(), None, "one sample gives no period");
        a.observe(1_100 * MS, 1_100 * MS + 30_000);
        // The smallest publish latency (30 us) after the next measurement time.
        let due = 1_200 * MS + 30_000 - WARM_LEAD_NS;
        assert_eq!(a.deadline(), Some(due));
        assert_eq!(a.deadline_within(due - MS, 500 * MS), due);
        assert_eq!(a.deadline_within(due - MS, MS / 2), due - MS / 2);
        assert!(!a.take_due(due - 1));
        assert!(a.take_due(due));
        assert!(!a.take_due(due + MS), "once only");
        assert_eq!(a.deadline(), None);
        assert_eq!(a.deadline_within(due, 500 * MS), due + 500 * MS);
    }

    #[test]
    fn gaps_and_bursts_are_not_periods() {
        let mut a = Anticipator::new();
        a.observe(0, 10);
        a.observe(3 * MS, 3 * MS); // faster than MIN_PERIOD_NS
        assert_eq!(a.deadline(), None);
        a.observe(3 * MS + 3_000 * MS, 3_003 * MS); // an outage
        assert_eq!(a.deadline(), None);
        a.observe(3_103 * MS, 3_103 * MS);
        assert_eq!(a.deadline(), Some(3_203 * MS - WARM_LEAD_NS));
        // A sample before the deadline moves it on.
        a.observe(3_153 * MS, 3_153 * MS);
        assert_eq!(a.deadline(), Some(3_203 * MS - WARM_LEAD_NS));
    }

    #[test]
    fn a_late_publish_does_not_move_the_next_deadline() {
        let mut a = Anticipator::new();
        a.observe(0, 50_000);
        a.observe(100 * MS, 100 * MS + 50_000);
        assert_eq!(a.deadline(), Some(200 * MS + 50_000 - WARM_LEAD_NS));
        // Published 3 ms late: the next one is still due on the grid.
        a.observe(200 * MS, 203 * MS);
        assert_eq!(a.deadline(), Some(300 * MS + 50_000 - WARM_LEAD_NS));
    }
}
