//! When a stage drains the topics that do not wake it: right after the
//! topic that does, and on its own only when that one falls silent.
//!
//! The logger wakes for each fused state (10 Hz) and drains every other
//! topic then, in the quiet part of the 10 Hz cycle just after the fix was
//! fused. A fixed 50 ms interval beside it woke the logger (and its disk
//! writer) at a phase of its own, now and then in the middle of the next
//! fix's path on a two-core machine. [`DrainClock`] keeps the drain at most
//! `period` after the last one, so while fused states flow it never fires,
//! and when they stop (fusion down, coasting) the topics are still drained
//! every `period` (their subscriber buffers hold seconds).

use crate::waiter::{Attachment, Wake};

/// What a loop does after a wait ([`DrainClock::after`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Next {
    /// Drain the topics now.
    pub drain: bool,
    /// The heartbeat interval fired.
    pub beat: bool,
}

/// The deadline of the next drain (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DrainClock {
    period_ns: u64,
    next_ns: u64,
}

impl DrainClock {
    /// A drain due `period_ns` after `now_ns` (and after each later drain).
    #[must_use]
    pub fn new(period_ns: u64, now_ns: u64) -> Self {
        Self {
            period_ns,
            next_ns: now_ns.saturating_add(period_ns),
        }
    }

    /// The moment the next drain is due (CLOCK_MONOTONIC ns): wait no longer.
    #[must_use]
    pub fn deadline(&self) -> u64 {
        self.next_ns
    }

    /// True when a drain is due at `now_ns` (no drain for a whole period).
    #[must_use]
    pub fn is_due(&self, now_ns: u64) -> bool {
        now_ns >= self.next_ns
    }

    /// After `wake` (from a wait until [`DrainClock::deadline`]) at `now_ns`:
    /// `None` on shutdown; else drain when `trigger` fired or a drain is
    /// due, and say whether `beat` fired.
    #[must_use]
    pub fn after(
        &self,
        wake: &Wake,
        trigger: &Attachment<'_, '_>,
        beat: &Attachment<'_, '_>,
        now_ns: u64,
    ) -> Option<Next> {
        match wake {
            Wake::Shutdown => None,
            Wake::Timeout => Some(Next {
                drain: self.is_due(now_ns),
                beat: false,
            }),
            Wake::Fired(f) => Some(Next {
                drain: f.contains(trigger) || self.is_due(now_ns),
                beat: f.contains(beat),
            }),
        }
    }

    /// Notes a drain at `now_ns`: the next one is due a period later.
    pub fn drained(&mut self, now_ns: u64) {
        self.next_ns = now_ns.saturating_add(self.period_ns);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_drain_pushes_the_deadline_back_and_silence_brings_it() {
        let mut c = DrainClock::new(50, 1_000);
        assert_eq!(c.deadline(), 1_050);
        assert!(!c.is_due(1_049));
        // Fused states every 40: the clock never comes due.
        for t in [1_040, 1_080, 1_120] {
            assert!(!c.is_due(t));
            c.drained(t);
        }
        assert_eq!(c.deadline(), 1_170);
        // Silence: due a period after the last drain.
        assert!(!c.is_due(1_169));
        assert!(c.is_due(1_170));
        c.drained(1_171);
        assert_eq!(c.deadline(), 1_221);
    }

    #[test]
    fn after_a_wait_drains_on_the_trigger_or_when_due() {
        let waiter = crate::Waiter::new(false).unwrap();
        let trigger = waiter
            .attach_interval(core::time::Duration::from_millis(1))
            .unwrap();
        let beat = waiter
            .attach_interval(core::time::Duration::from_secs(60))
            .unwrap();
        let now = crate::monotonic_ns();
        let c = DrainClock::new(60_000_000_000, now);
        let wake = waiter.wait().unwrap();
        let n = c.after(&wake, &trigger, &beat, now).unwrap();
        assert!(n.drain && !n.beat, "{wake:?} -> {n:?}");
        // Nothing fired and none due: no drain; due: drain.
        let n = c.after(&Wake::Timeout, &trigger, &beat, now).unwrap();
        assert!(!n.drain && !n.beat);
        let n = c
            .after(&Wake::Timeout, &trigger, &beat, c.deadline())
            .unwrap();
        assert!(n.drain && !n.beat);
        assert!(c.after(&Wake::Shutdown, &trigger, &beat, now).is_none());
    }

    #[test]
    fn saturates_at_the_end_of_time() {
        let c = DrainClock::new(u64::MAX, 5);
        assert_eq!(c.deadline(), u64::MAX);
        assert!(!c.is_due(u64::MAX - 1));
    }
}
