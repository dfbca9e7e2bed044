//! The loop of a stage that shows the fused state outside insuwb and
//! reports on the whole group (the ROS 2 bridge, the Foxglove live view):
//! it sleeps in the stage's `Waiter`, wakes for each fused state, drains
//! its inputs then (or [`DRAIN_PERIOD_NS`] after the last drain while no
//! fused state comes), makes its periodic report of the group's health on
//! its own interval (with the stamp clock's offset measured again), and
//! beats on `health` like every stage, `stopping` last. What it drains
//! and publishes is the stage's own ([`ReportOutputs`]). No DDS: the
//! Foxglove live view builds it without the `dds` feature.

use std::time::Duration;

use insuwb_msg::{FusedState, HealthState};
use insuwb_runtime::drain::DrainClock;
use insuwb_runtime::{
    monotonic_ns, HealthCounters, HealthReporter, PublishError, ReceiveError, Stage, Sub,
    WaitError, Wake,
};

use crate::clock::{ClockOffset, StampClock};
use crate::health::GroupSeen;

/// Longest time the other inputs wait undrained while no fused state wakes
/// the loop.
pub const DRAIN_PERIOD_NS: u64 = 20_000_000;

/// Why a report loop ended: the run error of every stage it runs (the
/// ROS 2 bridge, the Foxglove live view, the Zenoh bridge).
#[derive(Debug, thiserror::Error)]
pub enum ReportLoopError {
    /// Waiting (epoll, timers, signals).
    #[error("ReportLoopError::Wait: {0}")]
    Wait(#[from] WaitError),
    /// Receiving from iceoryx2.
    #[error("ReportLoopError::Receive: {0}")]
    Receive(#[from] ReceiveError),
    /// Publishing the heartbeat.
    #[error("ReportLoopError::Heartbeat: {0}")]
    Heartbeat(#[from] PublishError),
    /// Publishing a sample of the stage's own on iceoryx2 (the ROS 2
    /// bridge's body velocities).
    #[error("ReportLoopError::Publish: {0}")]
    Publish(PublishError),
}

/// The outputs of a stage run by [`ReportLoop::run`]: what it does at each
/// wake.
pub trait ReportOutputs {
    /// The stage's subscribers.
    type Inputs;
    /// The loop's error: waiting, receiving (from [`ReportOutputs::drain`])
    /// or publishing the heartbeat failed.
    type Error: From<WaitError> + From<PublishError>;

    /// Makes the report once before the first wait too (for a client that
    /// connects early).
    const REPORT_AT_START: bool = false;

    /// Drains the inputs and publishes what they held, noting the fused
    /// states and the heartbeats in `group`.
    ///
    /// # Errors
    /// The stage's error when receiving fails.
    fn drain(
        &mut self,
        inputs: &Self::Inputs,
        clock: &ClockOffset,
        group: &mut GroupSeen,
    ) -> Result<(), Self::Error>;

    /// The periodic report: the health of every stage of `group` at
    /// `now_ns` (CLOCK_MONOTONIC), each stale when its last heartbeat is
    /// older than `stale_after_ns`.
    fn report(&mut self, clock: &ClockOffset, group: &GroupSeen, now_ns: u64, stale_after_ns: u64);

    /// At a wake that is not the report's, after the drain (nothing by
    /// default).
    fn between_reports(&mut self, _clock: &ClockOffset) {}

    /// The counters of the stage's next heartbeat.
    fn counters(&self, inputs: &Self::Inputs) -> HealthCounters;
}

/// What the loop needs besides the stage and its ports.
#[derive(Debug, Clone, Copy)]
pub struct ReportLoop<'a> {
    /// The stages of the group, each in the report.
    pub stages: &'a [String],
    /// Period of the report, s (validated by the stage's config).
    pub report_period_s: f64,
    /// A stage whose last heartbeat is older than this is stale, s.
    pub stale_after_s: f64,
    /// Clock of the stamps.
    pub stamp_clock: StampClock,
}

impl ReportLoop<'_> {
    /// Runs until SIGINT/SIGTERM (the stage's waiter says so), then beats
    /// [`HealthState::Stopping`].
    ///
    /// # Errors
    /// `O::Error` when waiting, receiving or the heartbeat fails (a report
    /// period that is not a positive duration is a [`WaitError`]).
    pub fn run<O: ReportOutputs>(
        &self,
        stage: &Stage,
        fused: &Sub<FusedState>,
        inputs: &O::Inputs,
        health: &mut HealthReporter,
        out: &mut O,
    ) -> Result<(), O::Error> {
        let waiter = stage.waiter()?;
        let fused_a = waiter.attach(fused)?;
        let hb = waiter.attach_interval(health.period())?;
        // Zero (refused by `attach_interval`) for a period no duration holds.
        let period = Duration::try_from_secs_f64(self.report_period_s).unwrap_or(Duration::ZERO);
        let report_a = waiter.attach_interval(period)?;
        let stale_after_ns = (self.stale_after_s * 1e9) as u64;
        let mut clock = ClockOffset::measure(self.stamp_clock);
        let mut drain = DrainClock::new(DRAIN_PERIOD_NS, monotonic_ns());
        let mut group = GroupSeen::new(self.stages);
        let mut counters = HealthCounters::default();
        if O::REPORT_AT_START {
            out.report(&clock, &group, monotonic_ns(), stale_after_ns);
        }
        let result = loop {
            let wake = match waiter.wait_deadline(drain.deadline()) {
                Ok(w) => w,
                Err(e) => break Err(e.into()),
            };
            let now = monotonic_ns();
            let Some(next) = drain.after(&wake, &fused_a, &hb, now) else {
                break Ok(());
            };
            if next.drain {
                if let Err(e) = out.drain(inputs, &clock, &mut group) {
                    break Err(e);
                }
                drain.drained(monotonic_ns());
            }
            if matches!(&wake, Wake::Fired(f) if f.contains(&report_a)) {
                clock = ClockOffset::measure(self.stamp_clock);
                out.report(&clock, &group, monotonic_ns(), stale_after_ns);
            } else {
                out.between_reports(&clock);
            }
            if next.beat {
                counters = out.counters(inputs);
                if let Err(e) = health.report(&counters, HealthState::Ok) {
                    break Err(e.into());
                }
            }
        };
        let _ = health.report(&counters, HealthState::Stopping);
        result
    }
}
