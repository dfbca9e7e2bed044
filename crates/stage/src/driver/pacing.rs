//! What both recorded-source drivers share: resuming where the recording
//! is after a restart, publishing each sample at `start_epoch + t / speed`,
//! following the consumers at `speed = "max"` (lockstep), the wait loop and
//! the heartbeat. What a driver publishes and checks is its [`Paced`].

use anyhow::Result;
use insuwb_msg::{topics, FusedState, HealthState, UwbFix};
use insuwb_runtime::{monotonic_ns, HealthCounters, Stage, Sub, Wake};

use crate::source::{Item, Recorded, Source};

/// Longest wait without a due sample, ns (bounds a stall and the shutdown
/// latency).
const IDLE_WAIT_NS: u64 = 200_000_000;

/// Longest wait in lockstep, ns: the consumers' progress wakes the driver;
/// this only bounds a stall.
const LOCKSTEP_WAIT_NS: u64 = 20_000_000;

/// What the consumers have taken so far (lockstep only).
#[derive(Debug, Clone, Copy)]
pub struct Progress {
    /// Latest fix time seen on `uwb_fix` (the start epoch before any).
    pub fix_time_ns: u64,
    /// Latest fused state's time, once there is one.
    pub fused_time_ns: Option<u64>,
    /// Fixes fusion has used: one more than the highest `uwb_seq` of an
    /// undegraded fused state.
    pub fixes_consumed: u64,
}

/// One driver's part: what it publishes, checks and reports.
pub trait Paced {
    /// Whether lockstep follows the fixes until the first fused state
    /// (the IMU driver: the INS may still be aligning).
    const FOLLOWS_FIXES: bool;
    /// Whether to give way once before publishing due samples in real
    /// time (the UWB driver: a fix epoch is also an IMU sample's instant,
    /// and the fused state needs the INS state of that instant).
    const GIVES_WAY: bool;

    /// Lockstep: whether a sample stamped `t_ns` must wait for the consumers.
    fn held(&self, t_ns: u64, progress: &Progress) -> bool;
    /// Checks, stamps (`t_ns`, the generation, the source id) and publishes
    /// one due sample, counting it or its drop.
    ///
    /// # Errors
    /// A publish that fails.
    fn publish(&mut self, item: Item, t_ns: u64) -> Result<()>;
    /// The heartbeat's counters (also logs what is due and lets late
    /// subscribers connect).
    ///
    /// # Errors
    /// A port that fails.
    fn heartbeat(&mut self) -> Result<HealthCounters>;
    /// Samples published so far.
    fn published(&self) -> u64;
}

/// Paces `src` into `driver` until SIGINT/SIGTERM: resumes where the
/// recording is when the driver starts after the epoch (at a finite speed),
/// publishes each sample when due (or as the consumers follow, at an
/// infinite speed), reports health at the reporter's period.
///
/// # Errors
/// A port, the waiter or the driver failing.
pub fn run<D: Paced>(
    stage: &Stage,
    name: &str,
    mut src: Recorded,
    speed: f64,
    epoch_ns: u64,
    driver: &mut D,
) -> Result<()> {
    let gen = stage.generation();
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
    let mut health = stage.health_reporter()?;
    // `--speed max`: publish as fast as the consumers keep up, never further
    // ahead than their buffers hold (lockstep: nothing is ever dropped).
    // Only lockstep follows the consumers: in real time these subscribers
    // would just add a listener that every fix and fused publish notifies.
    let lockstep = speed.is_infinite();
    let fixes_seen: Option<Sub<UwbFix>> = if lockstep && D::FOLLOWS_FIXES {
        Some(stage.subscriber(topics::UWB_FIX)?)
    } else {
        None
    };
    let fused_sub: Option<Sub<FusedState>> = if lockstep {
        Some(stage.subscriber(topics::FUSED)?)
    } else {
        None
    };
    let waiter = stage.waiter()?;
    let hb = waiter.attach_interval(health.period())?;
    let _progress_wakes = match &fused_sub {
        Some(s) => Some(waiter.attach(s)?),
        None => None,
    };
    let mut progress = Progress {
        fix_time_ns: epoch_ns,
        fused_time_ns: None,
        fixes_consumed: 0,
    };
    let mut pending = src.next_item();
    // When a sample is due: `start_epoch + t / speed`.
    let due_of = |i: &Item| epoch_ns + (i.time_ns() as f64 / speed) as u64;
    tracing::info!("{name} driver: speed {speed}, epoch {epoch_ns} ns, generation {gen}");
    loop {
        let now = monotonic_ns();
        if let Some(s) = &fixes_seen {
            s.drain(|f| progress.fix_time_ns = progress.fix_time_ns.max(f.header.meas_time_ns))?;
        }
        if let Some(s) = &fused_sub {
            s.drain(|f| {
                let t = f.header.meas_time_ns;
                progress.fused_time_ns = Some(progress.fused_time_ns.unwrap_or(0).max(t));
                // Coasting and UWB-only poses consumed no fix of the filter.
                if f.header.flags & (FusedState::FLAG_DEGRADED | FusedState::FLAG_UWB_ONLY) == 0 {
                    progress.fixes_consumed = progress.fixes_consumed.max(f.uwb_seq + 1);
                }
            })?;
        }
        if D::GIVES_WAY && !lockstep && pending.is_some_and(|i| due_of(&i) <= now) {
            std::thread::yield_now();
        }
        while let Some(item) = pending {
            if due_of(&item) > now {
                break;
            }
            let t = epoch_ns + item.time_ns();
            if lockstep && driver.held(t, &progress) {
                break;
            }
            pending = src.next_item();
            driver.publish(item, t)?;
        }
        // Wait for the next sample's due time (the waiter's timer ends the
        // wait within microseconds of it, in one wake-up), a heartbeat or a
        // shutdown; lockstep is woken by the consumers' progress and the
        // deadline only bounds a stall.
        let now = monotonic_ns();
        let deadline = match pending {
            Some(_) if lockstep => now + LOCKSTEP_WAIT_NS,
            Some(item) => due_of(&item).min(now + IDLE_WAIT_NS),
            None => now + IDLE_WAIT_NS,
        };
        match waiter.wait_deadline(deadline)? {
            Wake::Shutdown => break,
            Wake::Fired(f) if f.contains(&hb) => {
                let counters = driver.heartbeat()?;
                let state = if pending.is_none() {
                    HealthState::Degraded
                } else {
                    HealthState::Ok
                };
                health.report(&counters, state)?;
            }
            _ => {}
        }
    }
    health.report(&driver.heartbeat()?, HealthState::Stopping)?;
    tracing::info!(
        "{name} driver: stopped after {} samples",
        driver.published()
    );
    Ok(())
}
