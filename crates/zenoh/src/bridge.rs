//! The bridge loop: subscribes to `fused` and `health` (and `uwb_fix`,
//! `diag` when asked) over iceoryx2 and publishes them to the fleet over
//! Zenoh, under the robot's keys ([`crate::payload`] for the encodings):
//!
//! | key | payload | from |
//! |---|---|---|
//! | `insuwb/<robot>/pose` | CDR `nav_msgs/msg/Odometry` | each fused state (valid ones only with `only_valid`) |
//! | `insuwb/<robot>/health` | JSON | every `health_period_s` (1 s): one entry per stage |
//! | `insuwb/<robot>/fix` | JSON | each UWB fix (`publish_fixes`) |
//! | `insuwb/<robot>/diag` | JSON | each filter update (`publish_diag`) |
//!
//! The loop ([`insuwb_report::report_loop`], the ROS 2 bridge's and the
//! Foxglove live view's) sleeps in the stage's `Waiter`: it wakes for each
//! fused state, drains the other topics then (or [`DRAIN_PERIOD_NS`] after
//! the last drain while no fused state comes), publishes the health on its
//! own interval (also once at the start) and its own heartbeat on
//! `health` like every stage. A put never blocks the loop: the publishers'
//! congestion control drops a sample that the network cannot take, and
//! the station counts it by the gap in the attachments' `seq`.
//!
//! Samples published (on iceoryx2) before the bridge opened are not
//! republished: a restarted bridge's subscribers first get the topics'
//! history, which its previous run published already.
//!
//! Heartbeat counters: `received` what the subscribers got, `published`
//! the Zenoh samples put, `dropped_invalid` samples no payload holds,
//! `dropped_time` samples too old to republish, and [`ZenohCounters`]
//! (poses, health reports, fixes and diagnostics put, put failures).

use insuwb_fleet::keys::Kind;
use insuwb_msg::{topics, FilterDiag, FusedState, Health, StageCounters, UwbFix, ZenohCounters};
use insuwb_report::clock::ClockOffset;
use insuwb_report::health::GroupSeen;
use insuwb_report::report_loop::{ReportLoop, ReportOutputs};
use insuwb_runtime::{
    monotonic_ns, HealthCounters, HealthReporter, PortError, RuntimeConfig, Stage, StageError, Sub,
};
use zenoh::pubsub::Publisher;
use zenoh::qos::CongestionControl;
use zenoh::{Session, Wait};

use crate::config::{ZenohConfig, ZenohConfigError};
use crate::payload::{self, DiagPayload, EncodeError, FixPayload, HealthPayload, Meta};
use crate::session::{self, SessionError};

pub use insuwb_report::report_loop::DRAIN_PERIOD_NS;

/// What the bridge needs besides `[zenoh]`.
#[derive(Debug, Clone)]
pub struct BridgeSetup {
    /// The iceoryx2 node of the stage (prefix, root, name `zenoh`).
    pub runtime: RuntimeConfig,
    /// `[zenoh]`.
    pub zenoh: ZenohConfig,
    /// The stages of the group, each an entry of the health payload.
    pub stages: Vec<String>,
}

/// Opening the bridge failed.
#[derive(Debug, thiserror::Error)]
pub enum BridgeOpenError {
    /// `[zenoh]` is invalid.
    #[error("BridgeOpenError::Config: {0}")]
    Config(#[from] ZenohConfigError),
    /// The iceoryx2 node.
    #[error("BridgeOpenError::Stage: {0}")]
    Stage(#[from] StageError),
    /// A subscriber or the heartbeat publisher.
    #[error("BridgeOpenError::Port: {0}")]
    Port(#[from] PortError),
    /// The Zenoh session.
    #[error("BridgeOpenError::Session: {0}")]
    Session(#[from] SessionError),
    /// A Zenoh publisher.
    #[error("BridgeOpenError::Publisher: {key}: {reason}")]
    Publisher {
        /// Its key.
        key: String,
        /// Zenoh's error.
        reason: String,
    },
}

/// The loop ended with an error (the report loop's, shared by the
/// stages it runs).
pub use insuwb_report::report_loop::ReportLoopError as BridgeRunError;

/// What the bridge published, for the log line at its end.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct BridgeStats {
    /// Poses put.
    pub poses: u64,
    /// Health samples put.
    pub health: u64,
    /// UWB fixes put.
    pub fixes: u64,
    /// Filter diagnostics put.
    pub diags: u64,
    /// Samples no payload holds.
    pub invalid: u64,
    /// Samples published before the bridge opened (the history a restarted
    /// bridge's subscribers get first): not republished.
    pub old: u64,
    /// Puts Zenoh refused.
    pub put_failures: u64,
}

/// The open bridge: iceoryx2 subscribers, the Zenoh session and its
/// publishers.
pub struct Bridge {
    stage: Stage,
    inputs: Inputs,
    health: HealthReporter,
    out: Outputs,
}

impl std::fmt::Debug for Bridge {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Bridge")
            .field("setup", &self.out.setup)
            .field("stats", &self.out.stats)
            .finish_non_exhaustive()
    }
}

/// The iceoryx2 subscribers (fixes and diagnostics only when published).
struct Inputs {
    fused: Sub<FusedState>,
    health: Sub<Health>,
    fix: Option<Sub<UwbFix>>,
    diag: Option<Sub<FilterDiag>>,
}

/// A publisher of one key and its count of samples.
struct Put {
    publisher: Publisher<'static>,
    seq: u64,
}

impl Put {
    /// Puts `bytes` with the attachment of the next sample; counts it in
    /// `ok` or, when Zenoh refuses it, in `failed`.
    fn put(&mut self, bytes: Vec<u8>, flags: u32, ok: &mut u64, failed: &mut u64) {
        let meta = Meta::new(self.seq, flags);
        self.seq += 1;
        match self
            .publisher
            .put(bytes)
            .attachment(meta.to_attachment())
            .wait()
        {
            Ok(()) => *ok += 1,
            Err(e) => {
                *failed += 1;
                // The first failure and then one in a thousand.
                if *failed % 1000 == 1 {
                    tracing::warn!(
                        "Zenoh put on {} failed ({failed} so far): {e}",
                        self.publisher.key_expr()
                    );
                }
            }
        }
    }
}

/// The Zenoh side: session, publishers, what was put.
struct Outputs {
    setup: BridgeSetup,
    /// When the bridge opened (CLOCK_MONOTONIC ns): samples published
    /// earlier are history.
    opened_ns: u64,
    stats: BridgeStats,
    // Fields drop in order: the publishers before the session.
    pose: Put,
    health: Put,
    fix: Option<Put>,
    diag: Option<Put>,
    _session: Session,
}

fn publisher(
    session: &Session,
    cfg: &ZenohConfig,
    kind: Kind,
    congestion: CongestionControl,
) -> Result<Put, BridgeOpenError> {
    let key = cfg.key(kind)?.to_string();
    let publisher = session
        .declare_publisher(key.clone())
        .encoding(payload::encoding(kind))
        .congestion_control(congestion)
        .wait()
        .map_err(|e| BridgeOpenError::Publisher {
            key,
            reason: e.to_string(),
        })?;
    Ok(Put { publisher, seq: 0 })
}

impl Bridge {
    /// Checks `[zenoh]`, opens the iceoryx2 node and its ports, the Zenoh
    /// session ([`session::open`]) and its publishers.
    ///
    /// # Errors
    /// [`BridgeOpenError`] naming what could not be opened.
    pub fn open(setup: BridgeSetup) -> Result<Self, BridgeOpenError> {
        let c = &setup.zenoh;
        c.validate_enabled()?;
        let stage = Stage::new(setup.runtime.clone())?;
        let inputs = Inputs {
            fused: stage.subscriber::<FusedState>(topics::FUSED)?,
            health: stage.subscriber::<Health>(topics::HEALTH)?,
            fix: c
                .publish_fixes
                .then(|| stage.subscriber::<UwbFix>(topics::UWB_FIX))
                .transpose()?,
            diag: c
                .publish_diag
                .then(|| stage.subscriber::<FilterDiag>(topics::DIAG))
                .transpose()?,
        };
        let health = stage.health_reporter()?;
        let session = session::open(&c.link())?;
        // Poses and health drop what the network cannot take: the loop
        // never waits for it. Fixes and diagnostics alike.
        let drop = CongestionControl::Drop;
        let out = insuwb_runtime::signal::with_signals_blocked(|| {
            Ok::<_, BridgeOpenError>(Outputs {
                pose: publisher(&session, c, Kind::Pose, drop)?,
                health: publisher(&session, c, Kind::Health, drop)?,
                fix: c
                    .publish_fixes
                    .then(|| publisher(&session, c, Kind::Fix, drop))
                    .transpose()?,
                diag: c
                    .publish_diag
                    .then(|| publisher(&session, c, Kind::Diag, drop))
                    .transpose()?,
                _session: session,
                stats: BridgeStats::default(),
                opened_ns: monotonic_ns(),
                setup: setup.clone(),
            })
        })?;
        tracing::info!(
            "Zenoh {} session for robot {}: connect {:?}, listen {:?}; publishing {}/{{{}}}",
            c.mode.name(),
            c.robot,
            c.connect,
            c.listen,
            insuwb_fleet::keys::ROOT.to_owned() + "/" + &c.robot,
            [
                Some("pose"),
                Some("health"),
                c.publish_fixes.then_some("fix"),
                c.publish_diag.then_some("diag"),
            ]
            .into_iter()
            .flatten()
            .collect::<Vec<_>>()
            .join(",")
        );
        Ok(Self {
            stage,
            inputs,
            health,
            out,
        })
    }

    /// Runs until SIGINT/SIGTERM; returns what it published.
    ///
    /// # Errors
    /// [`BridgeRunError`] when waiting, receiving or the heartbeat fails.
    pub fn run(self) -> Result<BridgeStats, BridgeRunError> {
        let Self {
            stage,
            inputs,
            mut health,
            mut out,
        } = self;
        let c = &out.setup.zenoh;
        let stages = out.setup.stages.clone();
        let looped = ReportLoop {
            stages: &stages,
            report_period_s: c.health_period_s,
            stale_after_s: c.stale_after_s,
            stamp_clock: c.stamp_clock,
        };
        looped.run(&stage, &inputs.fused, &inputs, &mut health, &mut out)?;
        Ok(out.stats)
    }
}

fn invalid(stats: &mut BridgeStats, what: &str, seq: u64, e: &EncodeError) {
    stats.invalid += 1;
    tracing::debug!("{what} {seq} not published: {e}");
}

impl ReportOutputs for Outputs {
    type Inputs = Inputs;
    type Error = BridgeRunError;

    // The health at once, for a station that shows the robot early.
    const REPORT_AT_START: bool = true;

    /// Drains the subscribers and puts what they held.
    fn drain(
        &mut self,
        inputs: &Inputs,
        clock: &ClockOffset,
        group: &mut GroupSeen,
    ) -> Result<(), BridgeRunError> {
        let Self {
            setup,
            opened_ns,
            stats,
            pose,
            fix,
            diag,
            ..
        } = self;
        let only_valid = setup.zenoh.only_valid;
        let opened_ns = *opened_ns;
        inputs.fused.drain(|s| {
            if s.header.pub_time_ns < opened_ns {
                stats.old += 1;
                return;
            }
            group.note_fused(&s);
            if only_valid && s.header.flags & FusedState::FLAG_VALID == 0 {
                return;
            }
            match payload::encode_pose(&s, pose.seq, clock) {
                Ok((bytes, meta)) => {
                    pose.put(bytes, meta.flags, &mut stats.poses, &mut stats.put_failures);
                }
                Err(e) => invalid(stats, "fused state", s.header.seq, &e),
            }
        })?;
        if let (Some(sub), Some(p)) = (&inputs.fix, fix) {
            sub.drain(|f| {
                if f.header.pub_time_ns < opened_ns {
                    stats.old += 1;
                    return;
                }
                match FixPayload::of(&f, clock).and_then(|j| j.encode()) {
                    Ok(bytes) => p.put(
                        bytes,
                        f.header.flags,
                        &mut stats.fixes,
                        &mut stats.put_failures,
                    ),
                    Err(e) => invalid(stats, "UWB fix", f.header.seq, &e),
                }
            })?;
        }
        if let (Some(sub), Some(p)) = (&inputs.diag, diag) {
            sub.drain(|d| {
                if d.header.pub_time_ns < opened_ns {
                    stats.old += 1;
                    return;
                }
                match DiagPayload::of(&d, clock).and_then(|j| j.encode()) {
                    Ok(bytes) => p.put(
                        bytes,
                        d.header.flags,
                        &mut stats.diags,
                        &mut stats.put_failures,
                    ),
                    Err(e) => invalid(stats, "filter diagnostics", d.header.seq, &e),
                }
            })?;
        }
        let now = monotonic_ns();
        inputs.health.drain(|h| group.note_heartbeat(h, now))?;
        Ok(())
    }

    /// Puts the health of every stage.
    fn report(&mut self, clock: &ClockOffset, group: &GroupSeen, now_ns: u64, stale_after_ns: u64) {
        let robot = &self.setup.zenoh.robot;
        match HealthPayload::of_group(robot, group, now_ns, stale_after_ns, clock)
            .and_then(|h| h.encode())
        {
            Ok(bytes) => self.health.put(
                bytes,
                0,
                &mut self.stats.health,
                &mut self.stats.put_failures,
            ),
            Err(e) => invalid(&mut self.stats, "health", 0, &e),
        }
    }

    fn counters(&self, inputs: &Inputs) -> HealthCounters {
        let mut c = HealthCounters::default();
        c.add_sub(&inputs.fused.stats());
        c.add_sub(&inputs.health.stats());
        if let Some(f) = &inputs.fix {
            c.add_sub(&f.stats());
        }
        if let Some(d) = &inputs.diag {
            c.add_sub(&d.stats());
        }
        let s = &self.stats;
        c.published = s.poses + s.health + s.fixes + s.diags;
        c.dropped_invalid = s.invalid;
        c.dropped_time = s.old;
        c.stage = StageCounters::Zenoh(ZenohCounters {
            poses: s.poses,
            health: s.health,
            fixes: s.fixes,
            diags: s.diags,
            put_failures: s.put_failures,
        });
        c
    }
}
