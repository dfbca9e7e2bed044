//! The IMU and UWB driver stages: read a source, check each sample, pace
//! recorded samples against the group's start epoch, publish.
//!
//! Recorded times are mapped onto CLOCK_MONOTONIC as `start_epoch + t`
//! (an offset, never a scale: every interval the algorithms see is the
//! recorded one); a sample is published at `start_epoch + t / speed`. The
//! chosen epoch is a whole second plus 2.5 ms, off the kernel's tick
//! ([`insuwb_runtime::epoch`]); the fix builder aligns its epoch windows to
//! it, so the fix epochs fall as in the recording.
//! At speed 1 the measurement times are real monotonic times, so ages and
//! latencies are meaningful. A restarted driver resumes at the sample the
//! recording has reached, so its consumers see a sequence gap.
//!
//! # What the heartbeat reports
//!
//! Both drivers drop and count (`Health::dropped_invalid`) samples with a
//! NaN, infinite or out-of-range value (accelerometer >= 400 m/s^2, gyro >=
//! 70 rad/s, TDOA |difference| >= 1000 m, equal anchor ids) and
//! (`Health::dropped_time`) samples whose time goes backwards; an IMU sample
//! at the time of the previous one, or a TDOA of the same anchor pair at the
//! time of an earlier one, is a duplicate and counted there too (several
//! pairs of one epoch share a time). The UWB driver's `Health::extra` holds
//! the fix builder's figures ([`UWB_EXTRA`]): `[0]` fixes published, `[1]`
//! epochs skipped for too few pairs, `[2]` epochs skipped for their
//! geometry (too few distinct anchors or independent pairs, collinear or
//! coincident anchors), `[3]` epochs the solver failed on (no convergence,
//! a solution run away from the anchors, another solver error). Skips are
//! also logged with their last reason, at most every [`SKIP_LOG_PERIOD_NS`].

use anyhow::Result;
use insuwb_msg::{topics, FusedState, GroundTruth, Health, ImuSample, UwbFix, UwbTdoa};
use insuwb_runtime::{monotonic_ns, HealthCounters, Stage, Wake};

use crate::group::RobotConfig;
use crate::source::{self, Item, Source, Want};

/// Samples dropped at the driver, by reason.
#[derive(Debug, Default, Clone, Copy)]
struct Drops {
    invalid: u64,
    time: u64,
}

/// Meaning of the UWB driver's `Health::extra` counters, in order.
pub const UWB_EXTRA: [&str; 4] = [
    "fixes",
    "skipped_too_few_pairs",
    "skipped_geometry",
    "skipped_solver",
];

/// Shortest interval between two log lines about skipped epochs, ns.
pub const SKIP_LOG_PERIOD_NS: u64 = 5_000_000_000;

/// The UWB driver's `Health::extra` (see [`UWB_EXTRA`]).
fn uwb_extra(s: &insuwb_uwb::fix::FixStats) -> [u64; 4] {
    [
        s.fixes,
        s.skipped_too_few_pairs,
        s.skipped_too_few_anchors + s.skipped_degenerate,
        s.skipped_no_convergence + s.skipped_runaway + s.skipped_other,
    ]
}

/// Anchor pairs seen at the time of the latest TDOA (duplicate detection);
/// beyond this many, further pairs of that time are not checked.
const MAX_PAIRS_PER_TIME: usize = 64;

/// Largest plausible accelerometer (m/s^2) and gyro (rad/s) magnitudes.
const MAX_ACCEL_MPS2: f64 = 400.0;
const MAX_RATE_RPS: f64 = 70.0;

/// Whether an IMU sample's values are finite and plausible.
pub(crate) fn imu_ok(s: &ImuSample) -> bool {
    s.accel_mps2
        .iter()
        .all(|v| v.is_finite() && v.abs() < MAX_ACCEL_MPS2)
        && s.gyro_rps
            .iter()
            .all(|v| v.is_finite() && v.abs() < MAX_RATE_RPS)
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

/// Runs a driver stage until SIGINT/SIGTERM. Source `device`: the live
/// loop of [`crate::device`] (speed and epoch do not apply).
pub fn run(
    want: Want,
    cfg: &RobotConfig,
    source_spec: &str,
    speed: f64,
    epoch_ns: u64,
) -> Result<()> {
    if source_spec == "device" {
        return crate::device::run(want, cfg);
    }
    let name = want.role().name();
    let stage = Stage::new(cfg.runtime(name))?;
    let gen = stage.generation();
    let mut src = source::open(source_spec, &cfg.sources.scenario, cfg.sources.seed, want)?;
    let now = monotonic_ns();
    // In real time (or a finite factor of it) a driver that starts after the
    // epoch, a restarted one above all, resumes where the recording is now.
    // At "max" no clock says where that is: it plays from the start.
    if now > epoch_ns && speed.is_finite() {
        let reached = ((now - epoch_ns) as f64 * speed) as u64;
        let skipped = src.skip_before(reached);
        if skipped > 0 {
            tracing::warn!(
                "generation {gen}: resuming the recording at {:.3} s ({skipped} samples skipped)",
                reached as f64 * 1e-9
            );
        }
    }
    let fcfg = cfg.fusion_config()?;
    // Each driver opens only the topics it publishes.
    let (mut imu_pub, mut truth_pub, mut tdoa_pub, mut fix_pub) = match want {
        Want::Imu => (
            Some(stage.publisher::<ImuSample>(topics::IMU)?),
            Some(stage.publisher::<GroundTruth>(topics::TRUTH)?),
            None,
            None,
        ),
        Want::Uwb => (
            None,
            None,
            Some(stage.publisher::<UwbTdoa>(topics::UWB_TDOA)?),
            Some(stage.publisher::<UwbFix>(topics::UWB_FIX)?),
        ),
    };
    let mut fixes = insuwb_uwb::fix::FixBuilder::new(fcfg.fix.clone())?;
    // Samples are stamped `epoch + t`: the fix epochs fall as for `t`.
    fixes.align_to(epoch_ns);
    let mut health = stage.health_reporter()?;
    // `--speed max`: publish as fast as the consumers keep up, never further
    // ahead than their buffers hold (lockstep: nothing is ever dropped).
    let lockstep = speed.is_infinite();
    // IMU: stay a quarter second of data ahead of fusion (enough to cover the
    // next fixes, little to re-propagate after a correction); UWB: stay a
    // bounded number of fixes ahead of fusion.
    // Only lockstep follows the consumers: in real time these subscribers
    // would just add a listener that every fix and fused publish notifies.
    let fixes_seen = match (lockstep, want) {
        (true, Want::Imu) => Some(stage.subscriber::<UwbFix>(topics::UWB_FIX)?),
        _ => None,
    };
    let fused_sub = if lockstep {
        Some(stage.subscriber::<FusedState>(topics::FUSED)?)
    } else {
        None
    };
    let mut consumed = 0u64;
    let mut fix_time_seen = epoch_ns;
    let mut fused_time_seen: Option<u64> = None;
    const LEAD_NS: u64 = 250_000_000;
    let waiter = stage.waiter()?;
    let hb = waiter.attach_interval(health.period())?;
    let _progress = match &fused_sub {
        Some(s) => Some(waiter.attach(s)?),
        None => None,
    };
    let ahead_limit =
        (insuwb_msg::qos::for_topic(topics::UWB_FIX).subscriber_max_buffer_size / 4) as u64;
    let mut fixes_published = 0u64;
    let mut counters = HealthCounters::default();
    let mut drops = Drops::default();
    let mut last_t: Option<u64> = None;
    let mut pairs_at_last_t: Vec<(u32, u32)> = Vec::with_capacity(MAX_PAIRS_PER_TIME);
    let mut skips_logged = 0u64;
    let mut skip_logged_at = 0u64;
    let mut pending = src.next_item();
    // When a sample is due: `start_epoch + t / speed`.
    let due_of = |i: &Item| epoch_ns + (i.time_ns() as f64 / speed) as u64;
    let source_id = stage.source_id();
    tracing::info!(
        "{name} driver: source {source_spec}, speed {speed}, epoch {epoch_ns} ns, generation {gen}"
    );
    loop {
        let now = monotonic_ns();
        if let Some(fixes_seen) = &fixes_seen {
            fixes_seen.drain(|f| fix_time_seen = fix_time_seen.max(f.header.meas_time_ns))?;
        }
        if let Some(fused_sub) = &fused_sub {
            match want {
                Want::Imu => fused_sub.drain(|f| {
                    fused_time_seen = Some(fused_time_seen.unwrap_or(0).max(f.header.meas_time_ns));
                })?,
                Want::Uwb => fused_sub.drain(|f| {
                    if f.header.flags & FusedState::FLAG_DEGRADED == 0 {
                        consumed = consumed.max(f.uwb_seq + 1);
                    }
                })?,
            };
        }
        // A fix epoch is also an IMU sample's instant (both sources count
        // from the start epoch), so both drivers' timers expire together.
        // The fused state needs the INS state of that instant, and the IMU
        // driver can only wait while this one runs (the kernel preempts
        // neither): give way once first.
        if want == Want::Uwb && !lockstep && pending.is_some_and(|i| due_of(&i) <= now) {
            std::thread::yield_now();
        }
        while let Some(item) = pending {
            let due = due_of(&item);
            if due > now {
                break;
            }
            if lockstep {
                let held = match want {
                    // Before the first fused state, follow the fixes (the INS may
                    // still be aligning); then follow fusion itself.
                    Want::Imu => {
                        epoch_ns + item.time_ns()
                            > fused_time_seen.unwrap_or(fix_time_seen) + LEAD_NS
                    }
                    Want::Uwb => fixes_published >= consumed + ahead_limit,
                };
                if held {
                    break;
                }
            }
            pending = src.next_item();
            let t = epoch_ns + item.time_ns();
            match item {
                Item::Truth(mut s) => {
                    s.header.meas_time_ns = t;
                    s.header.generation = gen;
                    s.header.source_id = source_id;
                    if let Some(p) = truth_pub.as_mut() {
                        p.publish_raw(s)?;
                    }
                }
                Item::Imu(mut s) => {
                    if !imu_ok(&s) {
                        drops.invalid += 1;
                        continue;
                    }
                    if last_t.is_some_and(|l| t <= l) {
                        drops.time += 1;
                        continue;
                    }
                    last_t = Some(t);
                    s.header.meas_time_ns = t;
                    s.header.generation = gen;
                    s.header.source_id = source_id;
                    if let Some(p) = imu_pub.as_mut() {
                        p.publish_raw(s)?;
                    }
                    counters.published += 1;
                }
                Item::Tdoa(mut s) => {
                    if !tdoa_ok(&s) {
                        drops.invalid += 1;
                        continue;
                    }
                    if last_t.is_some_and(|l| t < l) {
                        drops.time += 1;
                        continue;
                    }
                    let pair = (s.anchor_a.min(s.anchor_b), s.anchor_a.max(s.anchor_b));
                    if last_t != Some(t) {
                        pairs_at_last_t.clear();
                    } else if pairs_at_last_t.contains(&pair) {
                        drops.time += 1;
                        continue;
                    }
                    if pairs_at_last_t.len() < MAX_PAIRS_PER_TIME {
                        pairs_at_last_t.push(pair);
                    }
                    last_t = Some(t);
                    s.header.meas_time_ns = t;
                    s.header.generation = gen;
                    s.header.source_id = source_id;
                    // The fixes this measurement completes go out before it (the
                    // fusion stage relies on that order).
                    if let (Ok(Some(f)), Some(p)) = (fixes.push(&s), fix_pub.as_mut()) {
                        p.publish(f)?;
                        fixes_published += 1;
                    }
                    if let Some(p) = tdoa_pub.as_mut() {
                        p.publish_raw(s)?;
                    }
                    counters.published += 1;
                }
            }
        }
        // Wait for the next sample's due time (the waiter's timer ends the
        // wait within microseconds of it, in one wake-up), a heartbeat or a
        // shutdown; lockstep is woken by the consumers' progress and the
        // deadline only bounds a stall.
        let now = monotonic_ns();
        let deadline = match pending {
            Some(_) if lockstep => now + 20_000_000,
            Some(item) => due_of(&item).min(now + 200_000_000),
            None => now + 200_000_000,
        };
        match waiter.wait_deadline(deadline)? {
            Wake::Shutdown => break,
            Wake::Fired(f) if f.contains(&hb) => {
                counters.dropped_invalid = drops.invalid;
                counters.dropped_time = drops.time;
                let extra = uwb_extra(fixes.stats());
                let skips = extra[1..].iter().sum::<u64>();
                let t = monotonic_ns();
                if skips > skips_logged && t >= skip_logged_at + SKIP_LOG_PERIOD_NS {
                    tracing::warn!(
                        "{name} driver: {} epochs skipped without a fix (too few pairs {}, geometry {}, solver {}); last: {}",
                        skips - skips_logged,
                        extra[1],
                        extra[2],
                        extra[3],
                        fixes
                            .last_skip()
                            .map_or_else(|| "-".to_owned(), ToString::to_string)
                    );
                    skips_logged = skips;
                    skip_logged_at = t;
                }
                if want == Want::Uwb {
                    counters.extra = extra;
                }
                let state = if pending.is_none() {
                    Health::STATE_DEGRADED
                } else {
                    Health::STATE_OK
                };
                health.report(&counters, state)?;
                // Late subscribers get history only when the publisher acts.
                for p in imu_pub.iter() {
                    p.update_connections()?;
                }
                for p in tdoa_pub.iter() {
                    p.update_connections()?;
                }
            }
            _ => {}
        }
    }
    health.report(&counters, Health::STATE_STOPPING)?;
    tracing::info!(
        "{name} driver: stopped after {} samples",
        counters.published
    );
    Ok(())
}
