//! The UWB driver over a recorded source: publishes `uwb_tdoa` or, with
//! `[uwb] kind = "twr"`, `uwb_range` (checked), and the fixes the fix
//! builder completes on `uwb_fix`, each fix before the measurement that
//! completed it (the fusion stage relies on that order). A range is
//! published less the tag's range offset the fix builder has estimated so
//! far ([`take_range`], the path a ranging device takes too). With a site calibration (`[uwb] calibration`) the differences
//! are corrected before the fix builder uses them and published corrected
//! and flagged (`UwbTdoa::FLAG_CALIBRATED`): what fusion uses, and what a
//! log records.

use anyhow::bail;
use anyhow::Result;
use insuwb_msg::check::{RangeGate, TdoaGate};
use insuwb_msg::{topics, StageCounters, UwbDriverCounters, UwbFix, UwbKind, UwbRange, UwbTdoa};
use insuwb_runtime::{monotonic_ns, HealthCounters, Pub, Stage};
use insuwb_uwb::fix::{FixBuilder, FixStats, PushError};

use super::pacing::{self, Paced, Progress};
use crate::source::{self, Item, Want};
use insuwb_group::robot::RobotConfig;
use insuwb_group::sources::Source;

/// Shortest interval between two log lines about skipped epochs (and
/// between two about measurements the fix builder refused), ns.
pub const SKIP_LOG_PERIOD_NS: u64 = 5_000_000_000;

/// The UWB driver's heartbeat counters: the fix builder's figures.
fn uwb_counters(s: &FixStats) -> UwbDriverCounters {
    UwbDriverCounters {
        fixes: s.fixes,
        skipped_too_few_pairs: s.skipped_too_few_pairs,
        skipped_geometry: s.skipped_too_few_anchors + s.skipped_degenerate,
        skipped_solver: s.skipped_no_convergence + s.skipped_runaway + s.skipped_other,
    }
}

/// Measurements the fix builder refused after the gate passed them (a
/// difference too long once calibrated, a full pair table), by reason:
/// `(impossible, pair table full, other)`.
fn builder_refusals(s: &FixStats) -> (u64, u64, u64) {
    (
        s.dropped_impossible,
        s.dropped_capacity,
        s.dropped_non_finite + s.dropped_same_anchor + s.dropped_time_backwards,
    )
}

/// A two-way range's path into the group, the one every source takes (a
/// recorded log, the simulator, a ranging device), as `insuwb eval`'s
/// runner takes it: the gate ([`RangeGate`], which counts what it
/// refuses), the tag's range offset estimated so far removed
/// ([`FixBuilder::correct_range`]), the fix builder. `None`: the gate
/// refused it. Else the builder's answer (the fix the range completed, to
/// be published before the range; a refusal, counted in the builder's
/// stats) and the range as fusion and the log get it.
pub(crate) fn take_range(
    gate: &mut RangeGate,
    fixes: &mut FixBuilder,
    r: &UwbRange,
) -> Option<(Result<Option<UwbFix>, PushError>, UwbRange)> {
    gate.check(r).ok()?;
    let r = fixes.correct_range(r);
    Some((fixes.push_range(&r), r))
}

/// The UWB driver's part of the pacing loop.
struct UwbDriver {
    tdoa: Pub<UwbTdoa>,
    /// With `[uwb] kind = "twr"`.
    range: Option<Pub<UwbRange>>,
    fix: Pub<UwbFix>,
    fixes: FixBuilder,
    /// In lockstep, at most this many fixes ahead of fusion.
    ahead_limit: u64,
    fixes_published: u64,
    generation: u32,
    source_id: u16,
    /// Values, time order and repeated pairs ([`insuwb_msg::check`]), as
    /// `insuwb eval`.
    gate: TdoaGate,
    /// The ranges' gate.
    range_gate: RangeGate,
    counters: HealthCounters,
    skips_logged: u64,
    skip_logged_at: u64,
    /// The latest measurement the fix builder refused, and the refusals
    /// logged so far and when.
    last_builder_refusal: Option<PushError>,
    builder_refusals_logged: u64,
    builder_refusal_logged_at: u64,
    /// A measurement the calibration could not correct was warned about.
    calibration_warned: bool,
}

impl Paced for UwbDriver {
    const FOLLOWS_FIXES: bool = false;
    const GIVES_WAY: bool = true;

    fn held(&self, _t_ns: u64, p: &Progress) -> bool {
        self.fixes_published >= p.fixes_consumed + self.ahead_limit
    }

    fn publish(&mut self, item: Item, t_ns: u64) -> Result<()> {
        match item {
            Item::Tdoa(s) => self.publish_tdoa(s, t_ns),
            Item::Range(r) => self.publish_range(r, t_ns),
            Item::Imu(_) | Item::Truth(_) | Item::Velocity(_) | Item::Height(_) => Ok(()),
        }
    }

    fn heartbeat(&mut self) -> Result<HealthCounters> {
        self.beat()
    }

    fn published(&self) -> u64 {
        self.counters.published
    }
}

impl UwbDriver {
    /// A TDOA difference at `t_ns`: checked, calibrated, to the fix
    /// builder, published after the fix it completed.
    fn publish_tdoa(&mut self, mut s: UwbTdoa, t_ns: u64) -> Result<()> {
        s.header.meas_time_ns = t_ns;
        s.header.generation = self.generation;
        s.header.source_id = self.source_id;
        // Refused and counted by the gate (the heartbeat reports it).
        if self.gate.check(&s).is_err() {
            return Ok(());
        }
        // Corrected by the site calibration (if any), then used and
        // published so: the fix and the tight filter use the same value.
        let s = self.fixes.calibrate(&s);
        if !self.calibration_warned
            && self.fixes.calibration().is_some()
            && s.header.flags & UwbTdoa::FLAG_CALIBRATED == 0
        {
            self.calibration_warned = true;
            tracing::warn!(
                "uwb driver: anchors {} and {} are not those of the site calibration: their differences go uncorrected",
                s.anchor_a,
                s.anchor_b
            );
        }
        // The fixes this measurement completes go out before it. A
        // measurement the builder refuses is counted in its stats (logged
        // by the heartbeat) and published all the same, as `insuwb eval`
        // hands it to the tight filter.
        match self.fixes.push(&s) {
            Ok(Some(f)) => {
                self.fix.publish(f)?;
                self.fixes_published += 1;
            }
            Ok(None) => {}
            Err(e) => self.last_builder_refusal = Some(e),
        }
        self.tdoa.publish_raw(s)?;
        self.counters.published += 1;
        Ok(())
    }

    /// A two-way range at `t_ns` ([`take_range`]), published after the fix
    /// it completed.
    fn publish_range(&mut self, mut r: UwbRange, t_ns: u64) -> Result<()> {
        let Some(range_pub) = self.range.as_mut() else {
            return Ok(());
        };
        r.header.meas_time_ns = t_ns;
        r.header.generation = self.generation;
        r.header.source_id = self.source_id;
        let Some((pushed, r)) = take_range(&mut self.range_gate, &mut self.fixes, &r) else {
            return Ok(());
        };
        match pushed {
            Ok(Some(f)) => {
                self.fix.publish(f)?;
                self.fixes_published += 1;
            }
            Ok(None) => {}
            Err(e) => self.last_builder_refusal = Some(e),
        }
        range_pub.publish_raw(r)?;
        self.counters.published += 1;
        Ok(())
    }

    /// The heartbeat's counters, and the log lines about skipped epochs
    /// and refused measurements.
    fn beat(&mut self) -> Result<HealthCounters> {
        let fix = uwb_counters(self.fixes.stats());
        let skips = fix.skipped_too_few_pairs + fix.skipped_geometry + fix.skipped_solver;
        let t = monotonic_ns();
        if skips > self.skips_logged && t >= self.skip_logged_at + SKIP_LOG_PERIOD_NS {
            tracing::warn!(
                "uwb driver: {} epochs skipped without a fix (too few pairs {}, geometry {}, solver {}); last: {}",
                skips - self.skips_logged,
                fix.skipped_too_few_pairs,
                fix.skipped_geometry,
                fix.skipped_solver,
                self.fixes
                    .last_skip()
                    .map_or_else(|| "-".to_owned(), ToString::to_string)
            );
            self.skips_logged = skips;
            self.skip_logged_at = t;
        }
        let (impossible, capacity, other) = builder_refusals(self.fixes.stats());
        let refused = impossible + capacity + other;
        if refused > self.builder_refusals_logged
            && t >= self.builder_refusal_logged_at + SKIP_LOG_PERIOD_NS
        {
            tracing::warn!(
                "uwb driver: {} measurements refused by the fix builder, published all the same (longer than the anchors' distance once calibrated {impossible}, pair table full {capacity}, other {other}); last: {}",
                refused - self.builder_refusals_logged,
                self.last_builder_refusal
                    .map_or_else(|| "-".to_owned(), |e| e.to_string())
            );
            self.builder_refusals_logged = refused;
            self.builder_refusal_logged_at = t;
        }
        let gate = self.gate.refusals();
        let ranges = self.range_gate.refusals();
        self.counters.dropped_invalid = gate.invalid() + ranges.invalid();
        self.counters.dropped_time = gate.time() + ranges.time();
        self.counters.stage = StageCounters::UwbDriver(fix);
        // Late subscribers get history only when the publisher acts.
        self.tdoa.update_connections()?;
        if let Some(r) = self.range.as_mut() {
            r.update_connections()?;
        }
        Ok(self.counters)
    }
}

/// Runs the UWB driver on the recorded source `source` (`sim` or
/// `replay:FILE`) until SIGINT/SIGTERM, building fixes with the `[fusion.fix]`
/// table of the estimator's settings ([`RobotConfig::fusion_config`]) from
/// the measurements of `[uwb] kind`.
///
/// # Errors
/// The source or the fix settings are refused, a port or the waiter fails.
pub fn run(cfg: &RobotConfig, source: &Source, speed: f64, epoch_ns: u64) -> Result<()> {
    let name = Want::Uwb.role().name();
    let stage = Stage::new(cfg.runtime(name))?;
    let src = source::open(source, &cfg.sources.scenario, cfg.sources.seed, Want::Uwb)?;
    tracing::info!("{name} driver: source {source}");
    let kind = cfg.uwb.kind;
    let (tdoa, ranges) = src.uwb_counts();
    let (held, other) = match kind {
        UwbKind::Tdoa => (tdoa, UwbKind::Twr),
        UwbKind::Twr => (ranges, UwbKind::Tdoa),
    };
    if held == 0 && tdoa + ranges > 0 {
        bail!(
            "{name} driver: [uwb] kind is \"{kind}\", but the source {source} holds {} UWB measurements of kind \"{other}\" and none of kind \"{kind}\": set [uwb] kind = \"{other}\"",
            tdoa + ranges
        );
    }
    let fcfg = cfg.fusion_config()?;
    let mut fixes = FixBuilder::new(fcfg.fix.clone())?.with_calibration(fcfg.calibration.clone());
    // Samples are stamped `epoch + t`: the fix epochs fall as for `t`.
    fixes.align_to(epoch_ns);
    let mut driver = UwbDriver {
        tdoa: stage.publisher(topics::UWB_TDOA)?,
        range: if kind == UwbKind::Twr {
            Some(stage.publisher(topics::UWB_RANGE)?)
        } else {
            None
        },
        fix: stage.publisher(topics::UWB_FIX)?,
        fixes,
        ahead_limit: (insuwb_msg::qos::for_topic(topics::UWB_FIX).subscriber_max_buffer_size / 4)
            as u64,
        fixes_published: 0,
        generation: stage.generation(),
        source_id: stage.source_id(),
        gate: TdoaGate::new(),
        range_gate: RangeGate::new(),
        counters: HealthCounters::default(),
        skips_logged: 0,
        skip_logged_at: 0,
        last_builder_refusal: None,
        builder_refusals_logged: 0,
        builder_refusal_logged_at: 0,
        calibration_warned: false,
    };
    pacing::run(&stage, name, src, speed, epoch_ns, &mut driver)
}
