//! The logger stage: records every topic into segment files. The receive
//! loop only copies samples into a bounded channel; a writer thread does the
//! disk I/O, so a slow disk never stalls a receive (and never back-pressures
//! a producer: iceoryx2's safe overflow drops the oldest sample of a full
//! subscriber buffer instead of blocking the publisher). A write error (disk
//! full, unwritable directory) ends the logger with a non-zero exit; the rest
//! of the group keeps running.

use std::time::Duration;

use anyhow::{bail, Context, Result};
use crossbeam_channel::{bounded, TrySendError};
use insuwb_log::{Metadata, Record, SegmentWriter};
use insuwb_msg::{
    topics, FilterDiag, FusedState, GroundTruth, Health, ImuSample, InsCorrection, NavState,
    UwbFix, UwbTdoa,
};
use insuwb_runtime::{monotonic_ns, HealthCounters, Stage, Wake};

use crate::group::RobotConfig;

/// Runs the logger stage until SIGINT/SIGTERM.
pub fn run(cfg: &RobotConfig) -> Result<()> {
    let stage = Stage::new(cfg.runtime("logger"))?;
    let dir = cfg
        .group
        .run_dir
        .join(cfg.logger.dir.clone().unwrap_or_else(|| "log".into()));
    let meta = Metadata::new(format!(
        "insuwb logger {} generation {}",
        cfg.group.name,
        stage.generation()
    ))
    .with(
        "fusion_config",
        toml::to_string(&FusionWrap {
            fusion: cfg.fusion_config()?,
        })?,
    );
    let writer = SegmentWriter::open(&dir, meta, cfg.logger.segments.clone(), monotonic_ns())
        .with_context(|| format!("{}: cannot open a log segment", dir.display()))?;
    tracing::info!("recording into {}", dir.display());
    let (tx, rx) = bounded::<Record>(65_536);
    let thread = std::thread::Builder::new()
        .name("log-writer".into())
        .spawn(move || -> Result<u64> {
            let mut w = writer;
            let mut n = 0u64;
            loop {
                match rx.recv_timeout(Duration::from_millis(200)) {
                    Ok(r) => {
                        w.append(&r, monotonic_ns())?;
                        n += 1;
                    }
                    Err(crossbeam_channel::RecvTimeoutError::Timeout) => {
                        w.tick(monotonic_ns())?;
                    }
                    Err(crossbeam_channel::RecvTimeoutError::Disconnected) => break,
                }
            }
            w.finish()?;
            Ok(n)
        })?;
    let imu = stage.subscriber::<ImuSample>(topics::IMU)?;
    let tdoa = stage.subscriber::<UwbTdoa>(topics::UWB_TDOA)?;
    let fix = stage.subscriber::<UwbFix>(topics::UWB_FIX)?;
    let nav = stage.subscriber::<NavState>(topics::NAV)?;
    let corr = stage.subscriber::<InsCorrection>(topics::CORRECTION)?;
    let fused = stage.subscriber::<FusedState>(topics::FUSED)?;
    let diag = stage.subscriber::<FilterDiag>(topics::DIAG)?;
    let truth = stage.subscriber::<GroundTruth>(topics::TRUTH)?;
    let hsub = stage.subscriber::<Health>(topics::HEALTH)?;
    let mut health = stage.health_reporter()?;
    let waiter = stage.waiter()?;
    let a = [
        waiter.attach(&imu)?,
        waiter.attach(&tdoa)?,
        waiter.attach(&fix)?,
        waiter.attach(&nav)?,
        waiter.attach(&corr)?,
        waiter.attach(&fused)?,
        waiter.attach(&diag)?,
        waiter.attach(&truth)?,
        waiter.attach(&hsub)?,
    ];
    let hb = waiter.attach_interval(health.period())?;
    let mut dropped = 0u64;
    let mut sent = 0u64;
    let mut counters = HealthCounters::default();
    let mut result = Ok(());
    loop {
        let wake = waiter.wait_timeout(Duration::from_millis(500))?;
        if thread.is_finished() {
            break;
        }
        let Wake::Fired(f) = wake else {
            if matches!(wake, Wake::Shutdown) {
                break;
            }
            continue;
        };
        if a.iter().any(|x| f.contains(x)) {
            let mut send = |r: Record| match tx.try_send(r) {
                Ok(()) => sent += 1,
                Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) => dropped += 1,
            };
            imu.drain(|s| send(Record::Imu(s)))?;
            tdoa.drain(|s| send(Record::Tdoa(s)))?;
            fix.drain(|s| send(Record::Fix(s)))?;
            nav.drain(|s| send(Record::Nav(s)))?;
            corr.drain(|s| send(Record::Correction(s)))?;
            fused.drain(|s| send(Record::Fused(s)))?;
            diag.drain(|s| send(Record::Diag(s)))?;
            truth.drain(|s| send(Record::Truth(s)))?;
            hsub.drain(|s| send(Record::Health(s)))?;
        }
        if f.contains(&hb) {
            counters = HealthCounters::default();
            for st in [imu.stats(), tdoa.stats(), fused.stats(), nav.stats()] {
                counters.add_sub(&st);
            }
            counters.extra = [sent, dropped, 0, 0];
            if let Err(e) = health.report(&counters, Health::STATE_OK) {
                result = Err(e.into());
                break;
            }
        }
    }
    let _ = health.report(&counters, Health::STATE_STOPPING);
    drop(tx);
    match thread.join() {
        Ok(Ok(n)) => tracing::info!("logger: {n} records written, {dropped} dropped"),
        Ok(Err(e)) => bail!("logger: writing failed: {e:#}"),
        Err(_) => bail!("logger: the writer thread panicked"),
    }
    result
}

#[derive(serde::Serialize)]
struct FusionWrap {
    fusion: insuwb_fusion::offline::FusionConfig,
}
