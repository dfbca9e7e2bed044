//! The fusion stage: runs the configured filter in the fusion engine (the
//! code `insuwb eval` runs), publishes fused states, diagnostics and INS
//! corrections; coasts (INS only, flagged degraded) when UWB is silent,
//! flags stale INS input and publishes UWB-only poses while the INS cannot
//! serve, as the engine's output policy (`insuwb_fusion::output`) says, and
//! checkpoints so a restart resumes.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Context, Result};
use insuwb_fusion::config::{build_estimator, FusionConfig};
use insuwb_fusion::engine::{FusionEngine, Measurement, Outputs};
use insuwb_fusion::output::{OutputPolicy, OutputPolicyConfig};
use insuwb_msg::{
    topics, BodyVelocity, FilterDiag, FusedState, FusionCounters, HealthState, Height,
    InsCorrection, NavState, StageCounters, StageRole, UwbFix, UwbKind, UwbRange, UwbTdoa,
};
use insuwb_runtime::anticipate::Anticipator;
use insuwb_runtime::{monotonic_ns, HealthCounters, Stage, Wake};
use serde::{Deserialize, Serialize};

use insuwb_group::robot::RobotConfig;

/// What a checkpoint holds: enough to resume without re-converging.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Checkpoint {
    /// Last correction id sent.
    pub correction_id: u64,
    /// Time the checkpoint was written (monotonic ns).
    pub written_ns: u64,
    /// The estimator's full error covariance (row-major).
    pub cov: Vec<f64>,
    /// What the estimator learnt from its innovations (the IAKF's and the
    /// SHAF's `R` and update count, the tight filter's noise scales);
    /// empty for an estimator without (and in checkpoints written before
    /// it was kept).
    #[serde(default)]
    pub adaptive: Vec<f64>,
}

/// Largest covariance a checkpoint carries (15 x 15: the tight filter's).
const MAX_COV: usize = 15 * 15;
/// Largest adaptive state a checkpoint carries (the Sage-Husa count and a
/// 4 x 4 `R`).
const MAX_ADAPTIVE: usize = 1 + 4 * 4;

/// A checkpoint on its way to the writer thread (fixed size: sending it
/// allocates nothing).
#[derive(Debug, Clone, Copy)]
struct CkptMsg {
    correction_id: u64,
    written_ns: u64,
    cov: [f64; MAX_COV],
    len: usize,
    adaptive: [f64; MAX_ADAPTIVE],
    adaptive_len: usize,
}

/// Path of the fusion checkpoint in the run directory.
#[must_use]
pub fn checkpoint_path(run_dir: &Path) -> PathBuf {
    run_dir.join("fusion.ckpt.toml")
}

/// The eager-update lag the stage runs with: the configured one in real
/// time (the drivers publish each sample at its time, so a fix is never far
/// behind the INS stream), none (lazy) at `speed = "max"`, where the drivers
/// run ahead, or when the configured lag is negative.
#[must_use]
pub fn eager_lag_s(cfg: &RobotConfig) -> Option<f64> {
    (cfg.fusion.eager_lag_s >= 0.0 && cfg.sources.speed.is_finite())
        .then_some(cfg.fusion.eager_lag_s)
}

/// The coasting and stale-input policy: the fusion settings'
/// `[fusion.output]`, the one the lockstep runner of `insuwb eval` and
/// replay applies, or its defaults where the settings have none.
#[must_use]
pub fn output_policy(fcfg: &FusionConfig) -> OutputPolicyConfig {
    fcfg.output.clone().unwrap_or_default()
}

/// The engine the stage runs: the configured filter, eager in real time
/// ([`eager_lag_s`]), tight epochs aligned to the group's epoch.
fn engine_for(cfg: &RobotConfig, fcfg: &FusionConfig, epoch_ns: u64) -> Result<FusionEngine> {
    let est = build_estimator(cfg.filter_kind(), fcfg)?;
    let mut ecfg = fcfg.engine.clone();
    ecfg.eager_lag_s = eager_lag_s(cfg);
    let mut engine = FusionEngine::new(ecfg, est).with_velocity_wait(fcfg.aiding.wait_s);
    engine.align_to(epoch_ns);
    Ok(engine)
}

/// A restarted stage (`generation` > 0) resumes from the checkpoint at
/// `path`, if there is one: correction ids and covariance.
fn resume(engine: &mut FusionEngine, path: &Path, generation: u32) {
    if let Some(c) = crate::checkpoint::read::<Checkpoint>(path) {
        engine.resume_correction_id(c.correction_id);
        let est = engine.estimator_mut();
        let restored = est.restore_covariance(&c.cov);
        // The adaptive state goes on the restored covariance (a restore
        // resets the estimators, which the state then resumes).
        let adaptive = restored && !c.adaptive.is_empty() && est.restore_adaptive(&c.adaptive);
        if restored {
            // The INS ran on, corrected: carry on from it.
            engine.resume_initialised();
        }
        let word = |ok: bool| if ok { "restored" } else { "not restored" };
        tracing::warn!(
            "generation {generation}: resumed from the checkpoint (correction id {}, covariance {}, adaptive noise {})",
            c.correction_id,
            word(restored),
            if c.adaptive.is_empty() { "none kept" } else { word(adaptive) }
        );
    }
}

/// The stage's end of the checkpoint writer ([`crate::checkpoint::Writer`]):
/// the engine's covariance copied into a fixed-size message (no allocation
/// on the loop), a [`Checkpoint`] made of it on the writer thread.
struct CheckpointWriter {
    writer: crate::checkpoint::Writer<CkptMsg>,
    cov_buf: Vec<f64>,
    adaptive_buf: Vec<f64>,
}

impl CheckpointWriter {
    fn spawn(path: PathBuf) -> Result<Self> {
        let writer = crate::checkpoint::Writer::spawn(path, |m: CkptMsg| Checkpoint {
            correction_id: m.correction_id,
            written_ns: m.written_ns,
            cov: m.cov.get(..m.len).unwrap_or_default().to_vec(),
            adaptive: m
                .adaptive
                .get(..m.adaptive_len)
                .unwrap_or_default()
                .to_vec(),
        })?;
        Ok(Self {
            writer,
            cov_buf: Vec::with_capacity(MAX_COV),
            adaptive_buf: Vec::with_capacity(MAX_ADAPTIVE),
        })
    }

    /// Hands the engine's correction id and covariance at `now_ns` over;
    /// skipped while the previous checkpoint is still being written.
    fn send(&mut self, engine: &FusionEngine, now_ns: u64) {
        engine.estimator().covariance_snapshot(&mut self.cov_buf);
        engine.estimator().adaptive_snapshot(&mut self.adaptive_buf);
        let mut msg = CkptMsg {
            correction_id: engine.correction_id(),
            written_ns: now_ns,
            cov: [0.0; MAX_COV],
            len: self.cov_buf.len().min(MAX_COV),
            adaptive: [0.0; MAX_ADAPTIVE],
            adaptive_len: self.adaptive_buf.len().min(MAX_ADAPTIVE),
        };
        for (d, s) in msg.cov.iter_mut().zip(&self.cov_buf) {
            *d = *s;
        }
        for (d, s) in msg.adaptive.iter_mut().zip(&self.adaptive_buf) {
            *d = *s;
        }
        self.writer.offer(msg);
    }

    /// Waits for the last checkpoint to be written.
    fn finish(self) {
        self.writer.finish();
    }
}

/// Runs the fusion stage until SIGINT/SIGTERM; `epoch_ns` is the group's
/// start epoch (the drivers stamp samples `epoch + t`).
pub fn run(cfg: &RobotConfig, epoch_ns: u64) -> Result<()> {
    let stage = Stage::new(cfg.runtime(StageRole::Fusion.name()))?;
    let fcfg = cfg.fusion_config()?;
    let policy_cfg = output_policy(&fcfg);
    let mut engine = engine_for(cfg, &fcfg, epoch_ns)?;
    let tight = engine.estimator().is_tight();
    std::fs::create_dir_all(&cfg.group.run_dir).with_context(|| {
        format!(
            "{}: cannot create the run directory",
            cfg.group.run_dir.display()
        )
    })?;
    let ckpt_path = checkpoint_path(&cfg.group.run_dir);
    if stage.generation() > 0 {
        resume(&mut engine, &ckpt_path, stage.generation());
    }
    let nav_sub = stage.subscriber::<NavState>(topics::NAV)?;
    let fix_sub = stage.subscriber::<UwbFix>(topics::UWB_FIX)?;
    // Only a tightly coupled filter reads the measurements of the robot's
    // kind (TDOA differences or two-way ranges): a loose one would be woken
    // by every one of them just to drop it, on the CPUs the INS needs at a
    // fix epoch.
    let ranging = cfg.uwb.kind == UwbKind::Twr;
    let tdoa_sub = if tight && !ranging {
        Some(stage.subscriber::<UwbTdoa>(topics::UWB_TDOA)?)
    } else {
        None
    };
    let range_sub = if tight && ranging {
        Some(stage.subscriber::<UwbRange>(topics::UWB_RANGE)?)
    } else {
        None
    };
    // Body velocities and heights only from the sources the robot config names.
    let vel_codes: Vec<u32> = cfg
        .fusion
        .aiding_sources
        .iter()
        .filter_map(|s| s.velocity_code())
        .collect();
    let vel_sub = if vel_codes.is_empty() {
        None
    } else {
        Some(stage.subscriber::<BodyVelocity>(topics::BODY_VEL)?)
    };
    let height_sub = if cfg.fusion.aiding_sources.iter().any(|s| s.gives_height()) {
        Some(stage.subscriber::<Height>(topics::HEIGHT)?)
    } else {
        None
    };
    let mut fused_pub = stage.publisher::<FusedState>(topics::FUSED)?;
    let mut diag_pub = stage.publisher::<FilterDiag>(topics::DIAG)?;
    let mut corr_pub = stage.publisher::<InsCorrection>(topics::CORRECTION)?;
    let mut health = stage.health_reporter()?;
    let waiter = stage.waiter()?;
    let nav_a = waiter.attach(&nav_sub)?;
    let fix_a = waiter.attach(&fix_sub)?;
    let tdoa_a = tdoa_sub.as_ref().map(|s| waiter.attach(s)).transpose()?;
    let range_a = range_sub.as_ref().map(|s| waiter.attach(s)).transpose()?;
    let vel_a = vel_sub.as_ref().map(|s| waiter.attach(s)).transpose()?;
    let height_a = height_sub.as_ref().map(|s| waiter.attach(s)).transpose()?;
    let tick_period = Duration::from_secs_f64((0.5 / policy_cfg.coast_rate_hz).min(0.05));
    let tick = waiter.attach_interval(tick_period)?;
    let tick_ns = u64::try_from(tick_period.as_nanos()).unwrap_or(u64::MAX);
    let hb = waiter.attach_interval(health.period())?;
    // Samples published before this process started (iceoryx2 history) were
    // already handled by the previous generation: never fold them in again.
    let started_ns = monotonic_ns();
    let mut out = Outputs::default();
    out.fused.reserve(64);
    out.diag.reserve(64);
    out.corrections.reserve(64);
    let mut uwb_only: Vec<FusedState> = Vec::with_capacity(64);
    // One drain of INS states: at most the subscriber's buffer.
    let mut navs: Vec<NavState> =
        Vec::with_capacity(insuwb_msg::qos::for_topic(topics::NAV).subscriber_max_buffer_size);
    let ckpt_ns = (cfg.fusion.checkpoint_period_s * 1e9) as u64;
    let mut policy = OutputPolicy::new(&policy_cfg, tick_ns, monotonic_ns())
        .map_err(|e| anyhow::anyhow!("fusion.output.{e}"))?;
    let mut last_ckpt = 0u64;
    let mut counters = HealthCounters::default();
    let mut writer = CheckpointWriter::spawn(ckpt_path)?;
    // Shortly before the next fix is due, run the update once on a scratch
    // copy: the real update then finds its code and data in the caches.
    let mut next_fix = Anticipator::new();
    loop {
        let wake = waiter.wait_deadline(next_fix.deadline_within(monotonic_ns(), 500_000_000))?;
        let Wake::Fired(f) = wake else {
            if matches!(wake, Wake::Shutdown) {
                break;
            }
            if next_fix.take_due(monotonic_ns()) {
                engine.warm_up();
            }
            continue;
        };
        let mut updated = false;
        if f.contains(&nav_a)
            || f.contains(&fix_a)
            || tdoa_a.as_ref().is_some_and(|a| f.contains(a))
            || range_a.as_ref().is_some_and(|a| f.contains(a))
            || vel_a.as_ref().is_some_and(|a| f.contains(a))
            || height_a.as_ref().is_some_and(|a| f.contains(a))
        {
            // The INS states are taken first and handed over last: a
            // measurement published before an INS state is then always
            // handled before it (the IMU driver's body velocities race the
            // INS states their IMU samples make). Fixes before the TDOA
            // measurements that completed them.
            let fresh = |pub_ns: u64| pub_ns >= started_ns;
            nav_sub.drain(|n| {
                if fresh(n.header.pub_time_ns) {
                    navs.push(n);
                }
            })?;
            fix_sub.drain(|m| {
                next_fix.observe(m.header.meas_time_ns, m.header.pub_time_ns);
                if fresh(m.header.pub_time_ns) {
                    engine.on_measurement(Measurement::Fix(m), &mut out);
                    // A dead or frozen INS: the fix alone still gives a pose.
                    if let Some(s) = policy.on_fix(|| engine.uwb_only_state(&m)) {
                        uwb_only.push(s);
                    }
                }
            })?;
            if let Some(tdoa_sub) = &tdoa_sub {
                tdoa_sub.drain(|m| {
                    if fresh(m.header.pub_time_ns) {
                        engine.on_measurement(Measurement::Tdoa(m), &mut out);
                    }
                })?;
            }
            if let Some(range_sub) = &range_sub {
                range_sub.drain(|m| {
                    if fresh(m.header.pub_time_ns) {
                        engine.on_measurement(Measurement::Range(m), &mut out);
                    }
                })?;
            }
            if let Some(vel_sub) = &vel_sub {
                vel_sub.drain(|v| {
                    if fresh(v.header.pub_time_ns) && vel_codes.contains(&v.source) {
                        engine.on_measurement(Measurement::Velocity(v), &mut out);
                    }
                })?;
            }
            if let Some(height_sub) = &height_sub {
                height_sub.drain(|h| {
                    if fresh(h.header.pub_time_ns) {
                        engine.on_measurement(Measurement::Height(h), &mut out);
                    }
                })?;
            }
            for n in navs.drain(..) {
                engine.on_nav(&n, &mut out);
            }
            // The fused state first, straight after the compute: publishing
            // the correction first wakes the INS, which would delay it. The correction protocol does not depend on when a
            // correction arrives, so the order changes no result.
            updated = !out.fused.is_empty();
            for s in &out.fused {
                fused_pub.publish(policy.on_update(*s, monotonic_ns()))?;
            }
            for s in uwb_only.drain(..) {
                fused_pub.publish(s)?;
            }
            for c in &out.corrections {
                corr_pub.publish(*c)?;
            }
            for d in &out.diag {
                diag_pub.publish(*d)?;
            }
            out.clear();
        }
        let now = monotonic_ns();
        if f.contains(&tick) {
            // Stale INS: the newest INS state received is too old to build
            // a pose on. Coasting: no update for the coasting timeout.
            if let Some(s) = policy.on_tick(now, nav_sub.age_ns(now), || engine.coasting_state()) {
                fused_pub.publish(s)?;
            }
        }
        // Checkpoint right after an update (the next fix is a period away)
        // or, while coasting, on the tick. The writer thread serialises and
        // writes it: no file I/O and no allocation on this loop.
        let coasting = policy.coasting(now);
        if (updated || (coasting && f.contains(&tick))) && now.saturating_sub(last_ckpt) >= ckpt_ns
        {
            if engine.last_fused().is_some() {
                writer.send(&engine, now);
            }
            last_ckpt = now;
        }
        if f.contains(&hb) {
            let c = engine.counters();
            counters = HealthCounters::default();
            counters.add_sub(&nav_sub.stats());
            counters.add_sub(&fix_sub.stats());
            if let Some(v) = &vel_sub {
                counters.add_sub(&v.stats());
            }
            counters.published = fused_pub.published();
            counters.dropped_invalid = c.dropped_invalid;
            counters.dropped_time = c.meas_late;
            counters.stage = StageCounters::Fusion(FusionCounters {
                updates: c.updates,
                outliers: c.outliers,
                resets: c.resets,
                corrections: c.corrections,
            });
            let state = if policy.stale() {
                HealthState::Degraded
            } else {
                HealthState::Ok
            };
            health.report(&counters, state)?;
            fused_pub.update_connections()?;
        }
        // Samples first: a warm-up due meanwhile runs after them.
        if next_fix.take_due(monotonic_ns()) {
            engine.warm_up();
        }
    }
    writer.finish();
    health.report(&counters, HealthState::Stopping)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use insuwb_msg::FilterKind;

    use super::*;

    fn engine(kind: FilterKind) -> FusionEngine {
        let mut fcfg = FusionConfig::default();
        // As the robots' presets: the INS takes its position from a fix.
        fcfg.engine.init_from_first_fix = true;
        let est = build_estimator(kind, &fcfg).unwrap();
        FusionEngine::new(fcfg.engine.clone(), est)
    }

    /// A checkpoint carries the IAKF's adaptive `R` and update count beside
    /// the covariance, and a restarted stage resumes both, initialised (it
    /// carries on from the INS instead of resetting it to the next fix); a
    /// checkpoint written before the adaptive state was kept still resumes
    /// the covariance.
    #[test]
    fn a_restart_resumes_the_adaptive_r_from_the_checkpoint() {
        let dir = std::env::temp_dir().join(format!("insuwb-fusion-ckpt-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = checkpoint_path(&dir);

        let mut before = engine(FilterKind::Iakf);
        let mut state = Vec::new();
        before.estimator().adaptive_snapshot(&mut state);
        assert_eq!(state.len(), MAX_ADAPTIVE);
        // 40 updates in, R twice R_0.
        state[0] = 40.0;
        for v in state.iter_mut().skip(1) {
            *v *= 2.0;
        }
        assert!(before.estimator_mut().restore_adaptive(&state));
        let mut writer = CheckpointWriter::spawn(path.clone()).unwrap();
        writer.send(&before, 1);
        writer.finish();

        let mut after = engine(FilterKind::Iakf);
        assert!(!after.is_initialised(), "waits for a first fix");
        resume(&mut after, &path, 1);
        let mut resumed = Vec::new();
        after.estimator().adaptive_snapshot(&mut resumed);
        assert_eq!(resumed, state);
        // The INS ran on: the first fix updates, it does not reset.
        assert!(after.is_initialised());

        // An older checkpoint: no `adaptive` key.
        let c: Checkpoint = crate::checkpoint::read(&path).unwrap();
        let old = format!(
            "correction_id = {}\nwritten_ns = 1\ncov = {:?}\n",
            c.correction_id, c.cov
        );
        std::fs::write(&path, old).unwrap();
        let c: Checkpoint = crate::checkpoint::read(&path).unwrap();
        assert!(c.adaptive.is_empty());
        let mut fresh = engine(FilterKind::Iakf);
        resume(&mut fresh, &path, 1);
        fresh.estimator().adaptive_snapshot(&mut resumed);
        assert_eq!(resumed[0], 0.0, "R_0 and a new count");

        // The tight filter's state has NaN where nothing is learnt: TOML
        // carries it.
        let tight = engine(FilterKind::IakfTdoa);
        let mut writer = CheckpointWriter::spawn(path.clone()).unwrap();
        writer.send(&tight, 2);
        writer.finish();
        let c: Checkpoint = crate::checkpoint::read(&path).unwrap();
        assert_eq!(c.adaptive.len(), 3);
        assert!(c.adaptive[1].is_nan());
        let mut after = engine(FilterKind::IakfTdoa);
        resume(&mut after, &path, 1);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
