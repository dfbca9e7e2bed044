//! Heartbeat: a stage's counters published as [`insuwb_msg::Health`] on topic
//! `health` at a fixed period; each heartbeat also pages in the shared
//! memory the stage mapped since ([`crate::prefault`]).

use core::time::Duration;

use insuwb_msg::{fixed_name, Header, Health, HealthState, StageCounters};

use crate::monotonic_ns;
use crate::port::{Pub, PublishError, SubStats};
use crate::prefault::{PrefaultError, ShmPrefault};

/// The counters a stage reports in its heartbeat.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct HealthCounters {
    /// Samples received.
    pub received: u64,
    /// Samples published.
    pub published: u64,
    /// Samples dropped for a wrong layout version.
    pub dropped_version: u64,
    /// Samples dropped for a NaN, infinity or out-of-range value.
    pub dropped_invalid: u64,
    /// Samples dropped for a timestamp going backwards or repeated.
    pub dropped_time: u64,
    /// Samples missing on inputs (sequence gaps).
    pub seq_gaps: u64,
    /// The counters of the stage's kind.
    pub stage: StageCounters,
}

impl HealthCounters {
    /// Adds a subscriber's `received`, `dropped_version` and `seq_gaps`.
    pub fn add_sub(&mut self, s: &SubStats) {
        self.received += s.received;
        self.dropped_version += s.dropped_version;
        self.seq_gaps += s.seq_gaps;
    }
}

/// Publishes the stage's [`Health`] on topic `health`.
#[derive(Debug)]
pub struct HealthReporter {
    publisher: Pub<Health>,
    stage: [u8; 16],
    pid: u32,
    period: Duration,
    next_due_ns: u64,
    prefault: ShmPrefault,
}

impl HealthReporter {
    pub(crate) fn new(
        publisher: Pub<Health>,
        stage_name: &str,
        period: Duration,
        prefix: &str,
    ) -> Self {
        Self {
            publisher,
            stage: fixed_name(stage_name),
            pid: std::process::id(),
            period,
            next_due_ns: 0,
            prefault: ShmPrefault::new(prefix),
        }
    }

    /// The heartbeat period (attach it with [`crate::Waiter::attach_interval`]).
    #[must_use]
    pub fn period(&self) -> Duration {
        self.period
    }

    /// Publishes one heartbeat now with `counters` and `state`; returns its
    /// seq.
    pub fn report(
        &mut self,
        counters: &HealthCounters,
        state: HealthState,
    ) -> Result<u64, PublishError> {
        let now = monotonic_ns();
        let h = Health {
            header: Header::new(0, now),
            stage: self.stage,
            pid: self.pid,
            state: state.into(),
            received: counters.received,
            published: counters.published,
            dropped_version: counters.dropped_version,
            dropped_invalid: counters.dropped_invalid,
            dropped_time: counters.dropped_time,
            seq_gaps: counters.seq_gaps,
            counters: counters.stage.into(),
        };
        let seq = self.publisher.publish(h)?;
        let period_ns = u64::try_from(self.period.as_nanos()).unwrap_or(u64::MAX);
        self.next_due_ns = now.saturating_add(period_ns);
        match self.prefault.run_if_due(now) {
            Ok(Some(r)) if r.populated > 0 => tracing::debug!(
                "prefault: {} of {} shared-memory mappings populated ({} KiB)",
                r.populated,
                r.mappings,
                r.bytes / 1024
            ),
            Ok(_) => {}
            Err(e @ PrefaultError::Unsupported(_)) => {
                tracing::info!("{e}; shared memory is paged in on first use");
            }
            Err(e) => tracing::debug!("prefault: {e}"),
        }
        Ok(seq)
    }

    /// Publishes a heartbeat when one period has passed since the last
    /// (for loops that do not attach an interval); `Ok(None)` when not due.
    pub fn report_if_due(
        &mut self,
        now_ns: u64,
        counters: &HealthCounters,
        state: HealthState,
    ) -> Result<Option<u64>, PublishError> {
        if now_ns < self.next_due_ns {
            return Ok(None);
        }
        self.report(counters, state).map(Some)
    }
}
