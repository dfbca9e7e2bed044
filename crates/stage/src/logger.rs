//! The logger stage: records every topic into segment files. It wakes for
//! each fused state and then drains every topic; when no fused state comes,
//! it drains them `BULK_PERIOD_NS` (50 ms) after the last drain
//! ([`DrainClock`]). The receive loop only copies samples into a bounded
//! channel (a full channel drops the record and counts it in the
//! heartbeat's `dropped` counter, [`insuwb_msg::LoggerCounters`]) and, after each drain, wakes a writer thread,
//! which appends what the channel holds to the current segment
//! ([`SegmentWriter`]: framed records in a 64 KiB buffer that reaches the
//! file when it fills, on rotation, and as `[logger.segments.flush]` says,
//! by default once a second); without a wake-up for `WRITER_IDLE` (200 ms)
//! it looks at the channel anyway. So a slow disk never stalls a receive
//! (and never back-pressures a producer: iceoryx2's safe overflow drops the
//! oldest sample of a full subscriber buffer instead of blocking the
//! publisher). A write error (disk full, file size limit, unwritable
//! directory) ends the logger with an error line naming the path and the
//! operating system's error, and a non-zero exit; the rest of the group
//! keeps running (the launcher restarts the logger, and gives it up alone
//! when its restart budget is spent: it is an optional stage by default,
//! `[launch] optional`).
//!
//! For the latency benchmark, [`FUSED_TRACE_ENV`] makes the logger note when
//! each fused state arrived (in a buffer allocated at start) and write the
//! notes to a file when it stops.

use std::time::Duration;

use anyhow::{bail, Context, Result};
use crossbeam_channel::{bounded, RecvTimeoutError, TryRecvError, TrySendError};
use insuwb_log::{Metadata, Record, SegmentWriter};
use insuwb_msg::{
    topics, BodyVelocity, FilterDiag, FusedState, GroundTruth, Health, HealthState, Height,
    ImuSample, InsCorrection, LoggerCounters, NavState, StageCounters, StageRole, UwbFix, UwbRange,
    UwbTdoa,
};
use insuwb_runtime::drain::DrainClock;
use insuwb_runtime::{monotonic_ns, HealthCounters, Stage};

use insuwb_group::robot::RobotConfig;

/// Environment variable naming a file: when set, the logger notes the
/// receive time of every fused state and writes one line
/// `seq pub_time_ns receive_ns` per state to that file when it stops (the
/// format of `insuwb_bench::trace`). At most [`FUSED_TRACE_MAX`] states,
/// preallocated at start: nothing is allocated per sample.
pub const FUSED_TRACE_ENV: &str = "INSUWB_LOGGER_FUSED_TRACE";
/// The writer thread writes after each drain of the logger's loop; without
/// one for this long it looks at the channel anyway.
const WRITER_IDLE: Duration = Duration::from_millis(200);
/// Longest time the logger leaves the topics that do not wake it (all but
/// `fused`) undrained ([`DrainClock`]); the smallest subscriber buffer
/// (`health`, 256 samples at 5 Hz per stage) holds far more.
const BULK_PERIOD_NS: u64 = 50_000_000;

/// Fused states [`FUSED_TRACE_ENV`] notes at most (3 hours at 10 Hz).
pub const FUSED_TRACE_MAX: usize = 1 << 17;

/// The fused receive trace (see [`FUSED_TRACE_ENV`]).
struct FusedTrace {
    path: std::path::PathBuf,
    stamps: Vec<[u64; 3]>,
}

impl FusedTrace {
    fn from_env() -> Option<Self> {
        let path = std::env::var_os(FUSED_TRACE_ENV).filter(|p| !p.is_empty())?;
        Some(Self {
            path: path.into(),
            stamps: Vec::with_capacity(FUSED_TRACE_MAX),
        })
    }

    fn note(&mut self, s: &FusedState, receive_ns: u64) {
        if self.stamps.len() < self.stamps.capacity() {
            self.stamps
                .push([s.header.seq, s.header.pub_time_ns, receive_ns]);
        }
    }

    fn write(&self) -> Result<()> {
        use std::io::Write;
        let mut w = std::io::BufWriter::new(
            std::fs::File::create(&self.path)
                .with_context(|| format!("{}: cannot create", self.path.display()))?,
        );
        writeln!(w, "# seq pub_time_ns receive_ns")?;
        for [a, b, c] in &self.stamps {
            writeln!(w, "{a} {b} {c}")?;
        }
        w.flush()?;
        Ok(())
    }
}

/// Runs the logger stage until SIGINT/SIGTERM.
pub fn run(cfg: &RobotConfig) -> Result<()> {
    let stage = Stage::new(cfg.runtime(StageRole::Logger.name()))?;
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
    )
    .with(insuwb_group::robot::LOG_UWB_KIND, cfg.uwb.kind.name());
    let writer = SegmentWriter::open(&dir, meta, cfg.logger.segments.clone(), monotonic_ns())
        .map_err(|e| {
            let full = if e.io_kind() == Some(std::io::ErrorKind::StorageFull) {
                " (the disk is full)"
            } else {
                ""
            };
            anyhow::anyhow!("logger: cannot open a log segment{full}: {e}; nothing is recorded")
        })?;
    tracing::info!("recording into {}", dir.display());
    let (tx, rx) = bounded::<Record>(65_536);
    let (kick_tx, kick_rx) = bounded::<()>(1);
    let thread = std::thread::Builder::new()
        .name("log-writer".into())
        .spawn(move || -> Result<u64> {
            let mut w = writer;
            let mut n = 0u64;
            // Write what the channel holds when the loop kicks (after each
            // drain: just after a fused state, in the quiet part of the
            // 10 Hz cycle), never once per record: the writer stays off the
            // CPU while the stages of the fix path run (the channel holds
            // far more than one period of every topic).
            loop {
                let mut done = matches!(
                    kick_rx.recv_timeout(WRITER_IDLE),
                    Err(RecvTimeoutError::Disconnected)
                );
                loop {
                    match rx.try_recv() {
                        Ok(r) => {
                            w.append(&r, monotonic_ns())?;
                            n += 1;
                        }
                        Err(TryRecvError::Empty) => break,
                        Err(TryRecvError::Disconnected) => {
                            done = true;
                            break;
                        }
                    }
                }
                if done {
                    break;
                }
                w.tick(monotonic_ns())?;
            }
            w.finish()?;
            Ok(n)
        })?;
    let imu = stage.subscriber::<ImuSample>(topics::IMU)?;
    let tdoa = stage.subscriber::<UwbTdoa>(topics::UWB_TDOA)?;
    let range = stage.subscriber::<UwbRange>(topics::UWB_RANGE)?;
    let fix = stage.subscriber::<UwbFix>(topics::UWB_FIX)?;
    let nav = stage.subscriber::<NavState>(topics::NAV)?;
    let corr = stage.subscriber::<InsCorrection>(topics::CORRECTION)?;
    let fused = stage.subscriber::<FusedState>(topics::FUSED)?;
    let diag = stage.subscriber::<FilterDiag>(topics::DIAG)?;
    let truth = stage.subscriber::<GroundTruth>(topics::TRUTH)?;
    let hsub = stage.subscriber::<Health>(topics::HEALTH)?;
    let body_vel = stage.subscriber::<BodyVelocity>(topics::BODY_VEL)?;
    let height = stage.subscriber::<Height>(topics::HEIGHT)?;
    let mut health = stage.health_reporter()?;
    let waiter = stage.waiter()?;
    // Fused states wake the logger at once (the fusion -> logger hop stays
    // event-driven); every other topic is drained then, or BULK_PERIOD_NS
    // after the last drain when no fused state came (its subscriber buffer
    // holds seconds of it): the logger does not wake for each of the ~400
    // samples a second, and it and its writer stay off the CPU while the
    // stages of the next fix's path run.
    let fused_a = waiter.attach(&fused)?;
    let mut bulk = DrainClock::new(BULK_PERIOD_NS, monotonic_ns());
    let hb = waiter.attach_interval(health.period())?;
    let mut dropped = 0u64;
    let mut sent = 0u64;
    let mut counters = HealthCounters::default();
    let mut result = Ok(());
    let mut fused_trace = FusedTrace::from_env();
    loop {
        let wake = waiter.wait_deadline(bulk.deadline())?;
        if thread.is_finished() {
            break;
        }
        let Some(next) = bulk.after(&wake, &fused_a, &hb, monotonic_ns()) else {
            break;
        };
        if next.drain {
            let mut send = |r: Record| match tx.try_send(r) {
                Ok(()) => sent += 1,
                Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) => dropped += 1,
            };
            fused.drain(|s| {
                if let Some(t) = fused_trace.as_mut() {
                    t.note(&s, fused.last_receive_ns().unwrap_or_else(monotonic_ns));
                }
                send(Record::Fused(s));
            })?;
            imu.drain(|s| send(Record::Imu(s)))?;
            tdoa.drain(|s| send(Record::Tdoa(s)))?;
            range.drain(|s| send(Record::Range(s)))?;
            fix.drain(|s| send(Record::Fix(s)))?;
            nav.drain(|s| send(Record::Nav(s)))?;
            corr.drain(|s| send(Record::Correction(s)))?;
            diag.drain(|s| send(Record::Diag(s)))?;
            truth.drain(|s| send(Record::Truth(s)))?;
            hsub.drain(|s| send(Record::Health(s)))?;
            body_vel.drain(|s| send(Record::BodyVel(s)))?;
            height.drain(|s| send(Record::Height(s)))?;
            bulk.drained(monotonic_ns());
            // Full: a kick is pending already.
            let _ = kick_tx.try_send(());
        }
        if next.beat {
            counters = HealthCounters::default();
            for st in [
                imu.stats(),
                tdoa.stats(),
                range.stats(),
                fused.stats(),
                nav.stats(),
            ] {
                counters.add_sub(&st);
            }
            counters.stage = StageCounters::Logger(LoggerCounters { sent, dropped });
            if let Err(e) = health.report(&counters, HealthState::Ok) {
                result = Err(e.into());
                break;
            }
        }
    }
    let _ = health.report(&counters, HealthState::Stopping);
    if let Some(t) = &fused_trace {
        if let Err(e) = t.write() {
            tracing::warn!("fused receive trace: {e:#}");
        }
    }
    drop(tx);
    drop(kick_tx);
    match thread.join() {
        Ok(Ok(n)) => tracing::info!("logger: {n} records written, {dropped} dropped"),
        Ok(Err(e)) => {
            let full = e
                .downcast_ref::<insuwb_log::WriteError>()
                .is_some_and(insuwb_log::WriteError::is_storage_full);
            bail!(
                "logger: writing the recording failed{}: {e:#}",
                if full { " (the disk is full)" } else { "" }
            )
        }
        Err(_) => bail!("logger: the writer thread panicked"),
    }
    result
}

#[derive(serde::Serialize)]
struct FusionWrap {
    fusion: insuwb_fusion::config::FusionConfig,
}
