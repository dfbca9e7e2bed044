//! The INS stage: mechanisation of the IMU samples and the correction
//! protocol (see `insuwb_fusion::ins_engine`). A restarted INS
//! re-initialises from the latest fused state and its predecessor's sensor
//! bias estimates (a checkpoint in the run directory, written once a second
//! by a thread of its own), and ignores IMU samples older than that state.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::Result;
use insuwb_fusion::ins_engine::{InsBiases, InsEngine};
use insuwb_msg::{
    topics, FusedState, HealthState, ImuSample, InsCorrection, InsCounters, NavState,
    StageCounters, StageRole,
};
use insuwb_runtime::{monotonic_ns, HealthCounters, Stage, Wake};

use insuwb_group::robot::RobotConfig;

/// How often the INS writes its bias estimates, ns.
const CHECKPOINT_PERIOD_NS: u64 = 1_000_000_000;

/// Path of the INS checkpoint (its sensor bias estimates) in the run directory.
#[must_use]
pub fn checkpoint_path(run_dir: &Path) -> PathBuf {
    run_dir.join("ins.ckpt.toml")
}

/// Runs the INS stage until SIGINT/SIGTERM.
pub fn run(cfg: &RobotConfig) -> Result<()> {
    let stage = Stage::new(cfg.runtime(StageRole::Ins.name()))?;
    let fcfg = cfg.fusion_config()?;
    let mut ins = InsEngine::new(fcfg.ins_engine_config())?;
    let imu_sub = stage.subscriber::<ImuSample>(topics::IMU)?;
    let corr_sub = stage.subscriber::<InsCorrection>(topics::CORRECTION)?;
    let mut nav_pub = stage.publisher::<NavState>(topics::NAV)?;
    let mut health = stage.health_reporter()?;
    let waiter = stage.waiter()?;
    let imu_a = waiter.attach(&imu_sub)?;
    let corr_a = waiter.attach(&corr_sub)?;
    let hb = waiter.attach_interval(health.period())?;
    let mut renav: Vec<NavState> = Vec::with_capacity(4096);
    let ckpt_path = checkpoint_path(&cfg.group.run_dir);
    if stage.generation() == 0 {
        // A checkpoint of an earlier run of the group is not this one's.
        let _ = std::fs::remove_file(&ckpt_path);
    }
    // A restarted INS takes its state from the latest fused state of the
    // filter (history of the fused topic) and skips the IMU samples before
    // it. The UWB-only poses published while the INS was down carry the
    // fix's position and no filter state: one is taken only when the
    // history holds no filter state at all.
    let mut min_imu_t: u64 = 0;
    if stage.generation() > 0 {
        // Only a restart reads the fused topic (its history): a subscriber
        // held for good would add a listener every fused publish notifies.
        let fused_sub = stage.subscriber::<FusedState>(topics::FUSED)?;
        let mut last: Option<FusedState> = None;
        let mut last_uwb_only: Option<FusedState> = None;
        let mut max_id = 0u64;
        for _ in 0..20 {
            fused_sub.drain(|f| {
                let flags = f.header.flags;
                if flags & FusedState::FLAG_VALID == 0 {
                    return;
                }
                if flags & FusedState::FLAG_UWB_ONLY != 0 {
                    last_uwb_only = Some(f);
                } else {
                    last = Some(f);
                }
            })?;
            corr_sub.drain(|c| max_id = max_id.max(c.correction_id))?;
            if last.is_some() || last_uwb_only.is_some() {
                break;
            }
            if stage.sleep(Duration::from_millis(25)).is_err() {
                return Ok(());
            }
        }
        if let Some(f) = last.or(last_uwb_only) {
            // The fusion stage sends no correction while no INS state comes,
            // so a restarted INS may not learn the last id (it reads 0 from a
            // history that holds none): it starts above any id of an earlier
            // generation instead (2^32 corrections apart, 13 years at 10 Hz),
            // which the fusion stage adopts as a restart's, rather than
            // dropping every state as stale.
            let max_id = max_id.max(u64::from(stage.generation()) << 32);
            // Biases are the INS's alone (alignment, corrections): without
            // them a restarted INS drifts from its first second while the
            // fusion filter believes them still removed.
            let biases = crate::checkpoint::read::<InsBiases>(&ckpt_path);
            ins.reinit_from(f.pos_m, f.vel_mps, f.quat, biases, max_id);
            min_imu_t = f.header.meas_time_ns;
            tracing::warn!(
                "generation {}: re-initialised from the fused state at {} ns, correction id {max_id}, {}",
                stage.generation(),
                min_imu_t,
                if biases.is_some() { "sensor biases from the checkpoint" } else { "no bias checkpoint: biases zero" }
            );
        }
    }
    let mut counters = HealthCounters::default();
    let writer = crate::checkpoint::Writer::spawn(ckpt_path.clone(), |b: InsBiases| b)?;
    let mut last_ckpt = 0u64;
    loop {
        match waiter.wait_timeout(Duration::from_millis(500))? {
            Wake::Shutdown => break,
            Wake::Timeout => {}
            Wake::Fired(f) => {
                if f.contains(&imu_a) || f.contains(&corr_a) {
                    // Corrections first: they may name samples about to be re-propagated.
                    let mut err = None;
                    corr_sub.drain(|c| {
                        ins.on_correction(&c, &mut renav);
                        for n in &renav {
                            if let Err(e) = nav_pub.publish(*n) {
                                err = Some(e);
                            }
                        }
                    })?;
                    imu_sub.drain(|s| {
                        if s.header.meas_time_ns <= min_imu_t {
                            return;
                        }
                        if let Some(n) = ins.on_imu(&s) {
                            if let Err(e) = nav_pub.publish(n) {
                                err = Some(e);
                            }
                        }
                    })?;
                    if let Some(e) = err {
                        return Err(e.into());
                    }
                }
                let now = monotonic_ns();
                if now.saturating_sub(last_ckpt) >= CHECKPOINT_PERIOD_NS {
                    if let Some(b) = ins.biases() {
                        // Full: the previous one is still being written; skip.
                        writer.offer(b);
                        last_ckpt = now;
                    }
                }
                if f.contains(&hb) {
                    let c = ins.counters();
                    counters = HealthCounters::default();
                    counters.add_sub(&imu_sub.stats());
                    counters.published = nav_pub.published();
                    counters.dropped_invalid = c.dropped_invalid;
                    counters.dropped_time = c.dropped_time;
                    counters.dropped_version += c.dropped_version;
                    counters.stage = StageCounters::Ins(InsCounters {
                        corrections: c.corrections,
                        repropagated: c.repropagated,
                        corrections_too_old: c.corrections_too_old,
                        imu_restarts: c.imu_restarts,
                    });
                    health.report(&counters, HealthState::Ok)?;
                    nav_pub.update_connections()?;
                }
            }
        }
    }
    writer.finish();
    health.report(&counters, HealthState::Stopping)?;
    Ok(())
}
