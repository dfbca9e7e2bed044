//! The UWB driver over a recorded source: publishes `uwb_tdoa` (checked)
//! and the fixes the fix builder completes on `uwb_fix`, each fix before
//! the measurement that completed it (the fusion stage relies on that
//! order). With a site calibration (`[uwb] calibration`) the differences
//! are corrected before the fix builder uses them and published corrected
//! and flagged (`UwbTdoa::FLAG_CALIBRATED`): what fusion uses, and what a
//! log records.

use anyhow::Result;
use insuwb_msg::{topics, UwbFix, UwbTdoa};
use insuwb_runtime::{monotonic_ns, HealthCounters, Pub, Stage};
use insuwb_uwb::fix::{FixBuilder, FixStats};

use super::pacing::{self, Paced, Progress};
use crate::source::{self, Item, Want};
use insuwb_group::robot::RobotConfig;

/// Meaning of the UWB driver's `Health::extra` counters, in order.
pub const UWB_EXTRA: [&str; 4] = [
    "fixes",
    "skipped_too_few_pairs",
    "skipped_geometry",
    "skipped_solver",
];

/// Shortest interval between two log lines about skipped epochs, ns.
pub const SKIP_LOG_PERIOD_NS: u64 = 5_000_000_000;

/// Anchor pairs seen at the time of the latest TDOA (duplicate detection);
/// beyond this many, further pairs of that time are not checked.
const MAX_PAIRS_PER_TIME: usize = 64;

/// The UWB driver's `Health::extra` (see [`UWB_EXTRA`]).
fn uwb_extra(s: &FixStats) -> [u64; 4] {
    [
        s.fixes,
        s.skipped_too_few_pairs,
        s.skipped_too_few_anchors + s.skipped_degenerate,
        s.skipped_no_convergence + s.skipped_runaway + s.skipped_other,
    ]
}

fn tdoa_ok(s: &UwbTdoa) -> bool {
    s.diff_m.is_finite()
        && s.diff_m.abs() < 1000.0
        && s.anchor_a_pos_m
            .iter()
            .chain(&s.anchor_b_pos_m)
            .all(|v| v.is_finite())
        && s.anchor_a != s.anchor_b
}

/// The UWB driver's part of the pacing loop.
struct UwbDriver {
    tdoa: Pub<UwbTdoa>,
    fix: Pub<UwbFix>,
    fixes: FixBuilder,
    /// In lockstep, at most this many fixes ahead of fusion.
    ahead_limit: u64,
    fixes_published: u64,
    generation: u32,
    source_id: u16,
    last_t: Option<u64>,
    pairs_at_last_t: Vec<(u32, u32)>,
    counters: HealthCounters,
    skips_logged: u64,
    skip_logged_at: u64,
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
        let Item::Tdoa(mut s) = item else {
            return Ok(());
        };
        if !tdoa_ok(&s) {
            self.counters.dropped_invalid += 1;
            return Ok(());
        }
        if self.last_t.is_some_and(|l| t_ns < l) {
            self.counters.dropped_time += 1;
            return Ok(());
        }
        let pair = (s.anchor_a.min(s.anchor_b), s.anchor_a.max(s.anchor_b));
        if self.last_t != Some(t_ns) {
            self.pairs_at_last_t.clear();
        } else if self.pairs_at_last_t.contains(&pair) {
            self.counters.dropped_time += 1;
            return Ok(());
        }
        if self.pairs_at_last_t.len() < MAX_PAIRS_PER_TIME {
            self.pairs_at_last_t.push(pair);
        }
        self.last_t = Some(t_ns);
        s.header.meas_time_ns = t_ns;
        s.header.generation = self.generation;
        s.header.source_id = self.source_id;
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
        // The fixes this measurement completes go out before it.
        if let Ok(Some(f)) = self.fixes.push(&s) {
            self.fix.publish(f)?;
            self.fixes_published += 1;
        }
        self.tdoa.publish_raw(s)?;
        self.counters.published += 1;
        Ok(())
    }

    fn heartbeat(&mut self) -> Result<HealthCounters> {
        let extra = uwb_extra(self.fixes.stats());
        let skips = extra[1..].iter().sum::<u64>();
        let t = monotonic_ns();
        if skips > self.skips_logged && t >= self.skip_logged_at + SKIP_LOG_PERIOD_NS {
            tracing::warn!(
                "uwb driver: {} epochs skipped without a fix (too few pairs {}, geometry {}, solver {}); last: {}",
                skips - self.skips_logged,
                extra[1],
                extra[2],
                extra[3],
                self.fixes
                    .last_skip()
                    .map_or_else(|| "-".to_owned(), ToString::to_string)
            );
            self.skips_logged = skips;
            self.skip_logged_at = t;
        }
        self.counters.extra = extra;
        // Late subscribers get history only when the publisher acts.
        self.tdoa.update_connections()?;
        Ok(self.counters)
    }

    fn published(&self) -> u64 {
        self.counters.published
    }
}

/// Runs the UWB driver on the recorded source `source_spec` (`sim` or
/// `replay:FILE`) until SIGINT/SIGTERM, building fixes with the group's
/// `[fusion.fix]` settings.
///
/// # Errors
/// The source or the fix settings are refused, a port or the waiter fails.
pub fn run(cfg: &RobotConfig, source_spec: &str, speed: f64, epoch_ns: u64) -> Result<()> {
    let name = Want::Uwb.role().name();
    let stage = Stage::new(cfg.runtime(name))?;
    let src = source::open(
        source_spec,
        &cfg.sources.scenario,
        cfg.sources.seed,
        Want::Uwb,
    )?;
    tracing::info!("{name} driver: source {source_spec}");
    let fcfg = cfg.fusion_config()?;
    let mut fixes = FixBuilder::new(fcfg.fix.clone())?.with_calibration(fcfg.calibration.clone());
    // Samples are stamped `epoch + t`: the fix epochs fall as for `t`.
    fixes.align_to(epoch_ns);
    let mut driver = UwbDriver {
        tdoa: stage.publisher(topics::UWB_TDOA)?,
        fix: stage.publisher(topics::UWB_FIX)?,
        fixes,
        ahead_limit: (insuwb_msg::qos::for_topic(topics::UWB_FIX).subscriber_max_buffer_size / 4)
            as u64,
        fixes_published: 0,
        generation: stage.generation(),
        source_id: stage.source_id(),
        last_t: None,
        pairs_at_last_t: Vec::with_capacity(MAX_PAIRS_PER_TIME),
        counters: HealthCounters::default(),
        skips_logged: 0,
        skip_logged_at: 0,
        calibration_warned: false,
    };
    pacing::run(&stage, name, src, speed, epoch_ns, &mut driver)
}
