//! Pure restart arithmetic: the exponential backoff with cap and reset, and
//! the sliding-window restart budget. No processes, no clock: times come in.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// Exponential restart delay: `initial`, doubling per fault, capped at `max`,
/// back to `initial` after a run of at least `stable_after`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Backoff {
    initial_ms: u64,
    max_ms: u64,
    stable_after: Duration,
    next_ms: u64,
}

impl Backoff {
    /// A backoff whose first delay is `initial_ms` (callers pass `initial_ms <= max_ms`).
    pub(crate) fn new(initial_ms: u64, max_ms: u64, stable_after: Duration) -> Self {
        let initial_ms = initial_ms.min(max_ms);
        Self {
            initial_ms,
            max_ms,
            stable_after,
            next_ms: initial_ms,
        }
    }

    /// The delay before restarting a stage that ran for `ran_for` and then
    /// exited; advances the backoff.
    pub(crate) fn on_exit(&mut self, ran_for: Duration) -> u64 {
        if ran_for >= self.stable_after {
            self.next_ms = self.initial_ms;
        }
        let delay = self.next_ms;
        self.next_ms = self.next_ms.saturating_mul(2).min(self.max_ms);
        delay
    }
}

/// At most `max` restarts within any sliding `window`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct RestartBudget {
    max: u32,
    window: Duration,
    /// Times of the restarts still inside the window, oldest first; never
    /// longer than `max` (bounded by the policy's validation).
    taken: VecDeque<Instant>,
}

impl RestartBudget {
    /// A budget of `max` restarts per `window`.
    pub(crate) fn new(max: u32, window: Duration) -> Self {
        Self {
            max,
            window,
            taken: VecDeque::new(),
        }
    }

    /// Takes one restart at `now` if the window has room; `false` when the
    /// budget is exhausted (nothing is recorded then). Restarts taken
    /// `window` or longer before `now` have expired.
    pub(crate) fn try_take(&mut self, now: Instant) -> bool {
        while let Some(&t) = self.taken.front() {
            if now.saturating_duration_since(t) >= self.window {
                self.taken.pop_front();
            } else {
                break;
            }
        }
        if self.taken.len() >= self.max as usize {
            return false;
        }
        self.taken.push_back(now);
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(v: u64) -> Duration {
        Duration::from_millis(v)
    }

    #[test]
    fn backoff_doubles_caps_and_resets() {
        let mut b = Backoff::new(50, 300, ms(5000));
        // Hand-computed: 50, 100, 200, 400 -> capped 300, 300.
        let got: Vec<u64> = (0..5).map(|_| b.on_exit(ms(10))).collect();
        assert_eq!(got, [50, 100, 200, 300, 300]);
        // A run of exactly stable_after resets to the initial delay, then doubles again.
        assert_eq!(b.on_exit(ms(5000)), 50);
        assert_eq!(b.on_exit(ms(4999)), 100);
        // Cap that is not a power-of-two multiple of the initial delay.
        let mut b = Backoff::new(70, 250, ms(1000));
        let got: Vec<u64> = (0..4).map(|_| b.on_exit(ms(0))).collect();
        assert_eq!(got, [70, 140, 250, 250]);
    }

    #[test]
    fn budget_counts_within_a_sliding_window() {
        let t0 = Instant::now();
        let at = |v: u64| t0 + ms(v);
        let mut b = RestartBudget::new(3, ms(1000));
        assert!(b.try_take(at(0)));
        assert!(b.try_take(at(100)));
        assert!(b.try_take(at(200)));
        // A fourth inside [0, 1000) is refused and not recorded.
        assert!(!b.try_take(at(999)));
        // At 1000 the restart taken at 0 has expired: room for exactly one.
        assert!(b.try_take(at(1000)));
        assert!(!b.try_take(at(1050)));
        // At 1200 the ones at 100 and 200 have expired: room for two.
        assert!(b.try_take(at(1200)));
        assert!(b.try_take(at(1200)));
        assert!(!b.try_take(at(1200)));
        // Sparse faults (one per window) never exhaust it.
        let mut b = RestartBudget::new(1, ms(1000));
        for k in 0..100 {
            assert!(b.try_take(at(k * 1000)), "fault {k}");
        }
        // A zero budget refuses everything.
        assert!(!RestartBudget::new(0, ms(1000)).try_take(at(0)));
    }
}
