//! The live-view loop: subscribes to `fused`, `uwb_fix`, `uwb_tdoa`,
//! `uwb_range`, `diag`, `truth`, `body_vel`, `height` and `health` over
//! iceoryx2 and serves them to the Foxglove app over the Foxglove WebSocket
//! protocol (the `foxglove` SDK's server, subprotocol `foxglove.sdk.v1`):
//!
//! | topic (prefix `/insuwb`) | schema | encoding | from |
//! |---|---|---|---|
//! | `/pose` | `foxglove.PoseInFrame` | protobuf | each fused state |
//! | `/tf` | `foxglove.FrameTransform` | protobuf | each fused state: `map -> base_link` |
//! | `/path` | `foxglove.PosesInFrame` | protobuf | the last `path_length` fused poses, with each one |
//! | `/uwb_fix` | `foxglove.PoseInFrame` | protobuf | each UWB fix (identity attitude) |
//! | `/truth` | `foxglove.PoseInFrame` | protobuf | ground truth, when the source has it |
//! | `/error` | `insuwb.PositionError` | json | fused minus truth, when the source has truth |
//! | `/anchors` | `foxglove.SceneUpdate` | protobuf | one entity per anchor, each health period |
//! | `/robot` | `foxglove.SceneUpdate` | protobuf | the robot's model in `base_link`, each health period |
//! | `/diag` | `insuwb.FilterDiag` | json | each filter update: innovations, outlier weights, fading |
//! | `/body_vel` | `insuwb.BodyVelocity` | json | each body velocity (odometry, optical flow) in `base_link`, once one came |
//! | `/height` | `insuwb.Height` | json | each height (a range finder's distance along body z) in `base_link`, once one came |
//! | `/uwb_range` | `insuwb.UwbRange` | json | each UWB two-way range: anchor, range, quality, offset removed, anchor position; once one came |
//! | `/health` | `insuwb.GroupHealth` | json | each health period: one entry per stage |
//!
//! The anchors are the configured ones ([`LiveSetup::anchors`]) and any
//! other a TDOA sample or a range names. The channels of truth and error
//! exist where the source publishes truth ([`LiveSetup::truth`]): every
//! channel is made before the server starts, so that each client gets them
//! all in its first advertisement. The exceptions are `body_vel`, `height`
//! and `uwb_range`: no setting says whether a velocity source, a range
//! finder or a two-way ranging tag publishes, so each channel is made (and
//! advertised to the clients connected then) at its first sample, and a
//! group without one shows no empty channel. Timestamps and log times: see
//! [`crate::convert`].
//!
//! The loop ([`insuwb_report::report_loop`], the ROS 2 bridge's) sleeps in
//! the stage's `Waiter`: it wakes for each fused state, drains every other
//! topic then (or [`DRAIN_PERIOD_NS`] after the last drain while no fused
//! state comes), and beats on `health`. Logging a message never blocks the loop: the
//! server queues it per client and drops the oldest for a slow one. The
//! server runs on a tokio runtime of one worker thread, started with the
//! signals blocked so that SIGTERM reaches the stage's own thread.
//!
//! Samples published before the view opened (a topic's history) are not
//! shown. Heartbeat counters: `received` what the subscribers got,
//! `published` the messages logged, `dropped_invalid` samples no
//! conversion accepts, `dropped_time` samples older than the view,
//! and [`FoxgloveCounters`] (poses, fixes and diagnostics logged, clients
//! connected).

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use foxglove::messages::{FrameTransform, PoseInFrame, PosesInFrame, SceneUpdate};
use foxglove::{Channel, Context, PartialMetadata, RawChannel, Schema, WebSocketServerHandle};
use insuwb_msg::{
    topics, BodyVelocity, FilterDiag, FoxgloveCounters, FusedState, GroundTruth, Health, Height,
    StageCounters, UwbFix, UwbRange, UwbTdoa,
};
use insuwb_runtime::{
    monotonic_ns, HealthCounters, HealthReporter, PortError, RuntimeConfig, Stage, StageError, Sub,
};
use serde::Serialize;

use crate::config::{FoxgloveConfig, FoxgloveConfigError, TOPICS};
use crate::convert::{self, Anchor, ConvertError, HealthJson, Path, TruthTrack};
use insuwb_report::clock::ClockOffset;
use insuwb_report::health::GroupSeen;
use insuwb_report::report_loop::{ReportLoop, ReportOutputs};

pub use insuwb_report::report_loop::DRAIN_PERIOD_NS;

/// Truth samples kept for the position error (20 s at 100 Hz).
const TRUTH_KEPT: usize = 2000;
/// Fused states kept while their truth has not come yet.
const PENDING_KEPT: usize = 64;
/// Most anchors shown.
const MAX_ANCHORS: usize = 256;

/// What the live view needs besides `[foxglove]`.
#[derive(Debug, Clone)]
pub struct LiveSetup {
    /// The iceoryx2 node of the stage (prefix, root, name `foxglove`).
    pub runtime: RuntimeConfig,
    /// `[foxglove]`.
    pub foxglove: FoxgloveConfig,
    /// The stages of the group, each an entry of the health message.
    pub stages: Vec<String>,
    /// The server's name in the Foxglove app (the group's name).
    pub server_name: String,
    /// The configured anchors (the simulated scenario's; empty when the
    /// source does not say): shown from the start.
    pub anchors: Vec<Anchor>,
    /// The source publishes ground truth (simulation, replay): serve
    /// `truth` and `error`.
    pub truth: bool,
}

/// Opening the live view failed.
#[derive(Debug, thiserror::Error)]
pub enum LiveOpenError {
    /// `[foxglove]` is invalid.
    #[error("LiveOpenError::Config: {0}")]
    Config(#[from] FoxgloveConfigError),
    /// The iceoryx2 node.
    #[error("LiveOpenError::Stage: {0}")]
    Stage(#[from] StageError),
    /// A subscriber or the heartbeat publisher.
    #[error("LiveOpenError::Port: {0}")]
    Port(#[from] PortError),
    /// The server's runtime.
    #[error("LiveOpenError::Runtime: {0}")]
    Runtime(std::io::Error),
    /// A channel or the WebSocket server (e.g. the address in use).
    #[error("LiveOpenError::Server: {what}: {reason}")]
    Server {
        /// What was being made.
        what: String,
        /// The SDK's error.
        reason: String,
    },
}

/// The loop ended with an error (the report loop's, shared by the
/// stages it runs).
pub use insuwb_report::report_loop::ReportLoopError as LiveRunError;

/// What the live view logged, for the line at its end.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LiveStats {
    /// Fused poses (`/pose`, with `/tf` and `/path`).
    pub poses: u64,
    /// UWB fixes.
    pub fixes: u64,
    /// Ground truth samples.
    pub truth: u64,
    /// Position errors against truth.
    pub errors: u64,
    /// Filter diagnostics.
    pub diags: u64,
    /// Body velocities.
    pub velocities: u64,
    /// Heights.
    pub heights: u64,
    /// UWB two-way ranges.
    pub ranges: u64,
    /// Health messages.
    pub health: u64,
    /// Samples no conversion accepted.
    pub invalid: u64,
    /// Samples published before the view opened: not shown.
    pub old: u64,
}

/// The open live view: iceoryx2 subscribers, the server and its channels.
pub struct LiveView {
    stage: Stage,
    inputs: Inputs,
    health: HealthReporter,
    out: Outputs,
}

impl std::fmt::Debug for LiveView {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LiveView")
            .field("setup", &self.out.setup)
            .field("addr", &self.out.addr)
            .field("stats", &self.out.stats)
            .finish_non_exhaustive()
    }
}

/// The iceoryx2 subscribers.
struct Inputs {
    fused: Sub<FusedState>,
    fix: Sub<UwbFix>,
    tdoa: Sub<UwbTdoa>,
    range: Sub<UwbRange>,
    diag: Sub<FilterDiag>,
    truth: Sub<GroundTruth>,
    body_vel: Sub<BodyVelocity>,
    height: Sub<Height>,
    health: Sub<Health>,
}

/// A channel of JSON messages with a JSON schema.
struct JsonChannel(Arc<RawChannel>);

/// What a [`LazyChannel`] is made as.
struct LazySpec {
    /// The topic, without the prefix (one of [`TOPICS`]).
    topic: &'static str,
    /// The JSON schema's name and text.
    schema_name: &'static str,
    schema: &'static str,
    /// What its messages are, for the warning when making it fails.
    what: &'static str,
}

const BODY_VEL_CHANNEL: LazySpec = LazySpec {
    topic: "body_vel",
    schema_name: "insuwb.BodyVelocity",
    schema: convert::BODY_VEL_SCHEMA,
    what: "body velocities",
};

const HEIGHT_CHANNEL: LazySpec = LazySpec {
    topic: "height",
    schema_name: "insuwb.Height",
    schema: convert::HEIGHT_SCHEMA,
    what: "heights",
};

const UWB_RANGE_CHANNEL: LazySpec = LazySpec {
    topic: "uwb_range",
    schema_name: "insuwb.UwbRange",
    schema: convert::UWB_RANGE_SCHEMA,
    what: "UWB ranges",
};

/// A channel made at its first message (`body_vel`, `height`, `uwb_range`).
enum LazyChannel {
    /// No message yet.
    NotYet,
    /// Made.
    Open(JsonChannel),
    /// Making it failed (said once): its messages are not shown.
    Failed,
}

/// The Foxglove side: channels, server, runtime, what was logged.
struct Outputs {
    setup: LiveSetup,
    addr: SocketAddr,
    opened_ns: u64,
    stats: LiveStats,
    path: Path,
    truth_track: TruthTrack,
    /// Fused states waiting for the truth around their time.
    pending: Vec<(u64, [f64; 3])>,
    anchors: Vec<Anchor>,
    anchors_changed: bool,
    /// The channels' context, held as long as they are.
    _ctx: Arc<Context>,
    pose: Channel<PoseInFrame>,
    tf: Channel<FrameTransform>,
    path_ch: Channel<PosesInFrame>,
    fix: Channel<PoseInFrame>,
    anchors_ch: Channel<SceneUpdate>,
    robot: Channel<SceneUpdate>,
    diag: JsonChannel,
    health: JsonChannel,
    /// Body velocities, from the first one on.
    body_vel: LazyChannel,
    /// Heights, from the first one on.
    height: LazyChannel,
    /// UWB two-way ranges, from the first one on.
    uwb_range: LazyChannel,
    /// Truth and position error, where the source has truth.
    truth: Option<(Channel<PoseInFrame>, JsonChannel)>,
    // Dropped in order: the server before its runtime.
    server: Option<WebSocketServerHandle>,
    runtime: Option<tokio::runtime::Runtime>,
}

fn server_err<E: std::fmt::Display>(what: &str) -> impl FnOnce(E) -> LiveOpenError + '_ {
    move |e| LiveOpenError::Server {
        what: what.to_owned(),
        reason: e.to_string(),
    }
}

fn json_channel(
    ctx: &Arc<Context>,
    topic: String,
    name: &str,
    schema: &'static str,
) -> Result<JsonChannel, LiveOpenError> {
    let what = format!("channel {topic}");
    ctx.channel_builder(topic)
        .message_encoding("json")
        .schema(Schema::new(name, "jsonschema", schema.as_bytes()))
        .build_raw()
        .map(JsonChannel)
        .map_err(server_err(&what))
}

impl JsonChannel {
    /// Logs `v` at `stamp_ns`; false when it could not be serialized.
    fn log<T: Serialize>(&self, v: &T, stamp_ns: u64) -> bool {
        if !self.0.has_sinks() {
            return true;
        }
        match serde_json::to_vec(v) {
            Ok(bytes) => {
                self.0
                    .log_with_meta(&bytes, PartialMetadata::with_log_time(stamp_ns));
                true
            }
            Err(_) => false,
        }
    }
}

impl LiveView {
    /// Checks `[foxglove]`, opens the subscribers and the heartbeat, and
    /// starts the WebSocket server on `bind`.
    ///
    /// # Errors
    /// [`LiveOpenError`] naming what could not be opened.
    pub fn open(setup: LiveSetup) -> Result<Self, LiveOpenError> {
        let c = &setup.foxglove;
        c.validate()?;
        let addr = c.socket_addr()?;
        let stage = Stage::new(setup.runtime.clone())?;
        let inputs = Inputs {
            fused: stage.subscriber::<FusedState>(topics::FUSED)?,
            fix: stage.subscriber::<UwbFix>(topics::UWB_FIX)?,
            tdoa: stage.subscriber::<UwbTdoa>(topics::UWB_TDOA)?,
            range: stage.subscriber::<UwbRange>(topics::UWB_RANGE)?,
            diag: stage.subscriber::<FilterDiag>(topics::DIAG)?,
            truth: stage.subscriber::<GroundTruth>(topics::TRUTH)?,
            body_vel: stage.subscriber::<BodyVelocity>(topics::BODY_VEL)?,
            height: stage.subscriber::<Height>(topics::HEIGHT)?,
            health: stage.subscriber::<Health>(topics::HEALTH)?,
        };
        let health = stage.health_reporter()?;
        let runtime = insuwb_runtime::signal::with_signals_blocked(|| {
            tokio::runtime::Builder::new_multi_thread()
                .worker_threads(1)
                .thread_name("foxglove-ws")
                .enable_all()
                .build()
        })
        .map_err(LiveOpenError::Runtime)?;
        let ctx = Context::new();
        let t = |n: &str| {
            debug_assert!(TOPICS.contains(&n), "{n} missing in TOPICS");
            c.topic(n)
        };
        let pose = ctx.channel_builder(t("pose")).build::<PoseInFrame>();
        let tf = ctx.channel_builder(t("tf")).build::<FrameTransform>();
        let path_ch = ctx.channel_builder(t("path")).build::<PosesInFrame>();
        let fix = ctx.channel_builder(t("uwb_fix")).build::<PoseInFrame>();
        let anchors_ch = ctx.channel_builder(t("anchors")).build::<SceneUpdate>();
        let robot = ctx.channel_builder(t("robot")).build::<SceneUpdate>();
        let diag = json_channel(&ctx, t("diag"), "insuwb.FilterDiag", convert::DIAG_SCHEMA)?;
        let health_ch = json_channel(
            &ctx,
            t("health"),
            "insuwb.GroupHealth",
            convert::HEALTH_SCHEMA,
        )?;
        let truth = if setup.truth {
            let pose = ctx.channel_builder(t("truth")).build::<PoseInFrame>();
            let error = json_channel(
                &ctx,
                t("error"),
                "insuwb.PositionError",
                convert::ERROR_SCHEMA,
            )?;
            Some((pose, error))
        } else {
            None
        };
        let server = foxglove::WebSocketServer::new()
            .name(setup.server_name.clone())
            .bind(addr.ip().to_string(), addr.port())
            .context(&ctx)
            .tokio_runtime(runtime.handle())
            .start_blocking()
            .map_err(server_err(&format!("WebSocket server on {addr}")))?;
        let addr = SocketAddr::new(addr.ip(), server.port());
        tracing::info!(
            "Foxglove live view on ws://{addr} (topics under {})",
            c.topic_prefix
        );
        let mut anchors = Vec::new();
        for a in &setup.anchors {
            note_anchor(&mut anchors, *a);
        }
        Ok(Self {
            stage,
            inputs,
            health,
            out: Outputs {
                addr,
                opened_ns: monotonic_ns(),
                stats: LiveStats::default(),
                path: Path::new(c.path_length),
                truth_track: TruthTrack::new(TRUTH_KEPT),
                pending: Vec::new(),
                anchors_changed: !anchors.is_empty(),
                anchors,
                _ctx: ctx,
                pose,
                tf,
                path_ch,
                fix,
                anchors_ch,
                robot,
                diag,
                health: health_ch,
                body_vel: LazyChannel::NotYet,
                height: LazyChannel::NotYet,
                uwb_range: LazyChannel::NotYet,
                truth,
                server: Some(server),
                runtime: Some(runtime),
                setup,
            },
        })
    }

    /// The address the server listens on (the port chosen when `bind`'s is 0).
    #[must_use]
    pub fn addr(&self) -> SocketAddr {
        self.out.addr
    }

    /// Runs until SIGINT/SIGTERM, then stops the server; returns what it
    /// logged.
    ///
    /// # Errors
    /// [`LiveRunError`] when waiting, receiving or the heartbeat fails.
    pub fn run(self) -> Result<LiveStats, LiveRunError> {
        let Self {
            stage,
            inputs,
            mut health,
            mut out,
        } = self;
        let c = &out.setup.foxglove;
        let stages = out.setup.stages.clone();
        let looped = ReportLoop {
            stages: &stages,
            report_period_s: c.health_period_s,
            stale_after_s: c.stale_after_s,
            stamp_clock: c.stamp_clock,
        };
        let result = looped.run(&stage, &inputs.fused, &inputs, &mut health, &mut out);
        out.stop();
        result.map(|()| out.stats)
    }
}

impl ReportOutputs for Outputs {
    type Inputs = Inputs;
    type Error = LiveRunError;

    // The scene at once, for a client that connects early.
    const REPORT_AT_START: bool = true;

    /// Drains the subscribers and logs what they held.
    fn drain(
        &mut self,
        inputs: &Inputs,
        clock: &ClockOffset,
        group: &mut GroupSeen,
    ) -> Result<(), LiveRunError> {
        let opened_ns = self.opened_ns;
        let frame = self.setup.foxglove.frame_id.clone();
        // Truth first: the fused states of this drain compare with it.
        let mut truth_seen = Vec::new();
        inputs.truth.drain(|t| {
            if t.header.pub_time_ns < opened_ns {
                self.stats.old += 1;
            } else {
                truth_seen.push(t);
            }
        })?;
        for t in truth_seen {
            self.truth_sample(&t, &frame, clock);
        }
        let only_valid = self.setup.foxglove.only_valid;
        let mut fused_seen = Vec::new();
        inputs.fused.drain(|s| {
            if s.header.pub_time_ns < opened_ns {
                self.stats.old += 1;
                return;
            }
            group.note_fused(&s);
            if !only_valid || s.header.flags & FusedState::FLAG_VALID != 0 {
                fused_seen.push(s);
            }
        })?;
        for s in fused_seen {
            self.fused_sample(&s, &frame, clock);
        }
        self.flush_pending(clock);
        let Self {
            stats, fix, diag, ..
        } = self;
        inputs.fix.drain(|f| {
            if f.header.pub_time_ns < opened_ns {
                stats.old += 1;
                return;
            }
            match convert::fix_pose(&f, &frame, clock) {
                Ok(p) => {
                    let t = p.timestamp.map_or(0, |t| t.total_nanos());
                    fix.log_with_time(&p, t);
                    stats.fixes += 1;
                }
                Err(e) => invalid(stats, "UWB fix", f.header.seq, &e),
            }
        })?;
        inputs.diag.drain(|d| {
            if d.header.pub_time_ns < opened_ns {
                stats.old += 1;
                return;
            }
            match convert::diag_json(&d, clock) {
                Ok(j) => {
                    let t =
                        u64::from(j.timestamp.sec) * 1_000_000_000 + u64::from(j.timestamp.nsec);
                    if diag.log(&j, t) {
                        stats.diags += 1;
                    }
                }
                Err(e) => invalid(stats, "filter diagnostics", d.header.seq, &e),
            }
        })?;
        let anchors = &mut self.anchors;
        let mut changed = false;
        inputs.tdoa.drain(|m| {
            for (id, pos_m) in [
                (m.anchor_a, m.anchor_a_pos_m),
                (m.anchor_b, m.anchor_b_pos_m),
            ] {
                changed |= note_anchor(anchors, Anchor { id, pos_m });
            }
        })?;
        let Self {
            stats,
            uwb_range,
            _ctx: ctx,
            setup,
            ..
        } = self;
        inputs.range.drain(|r| {
            changed |= note_anchor(
                anchors,
                Anchor {
                    id: r.anchor,
                    pos_m: r.anchor_pos_m,
                },
            );
            if r.header.pub_time_ns < opened_ns {
                stats.old += 1;
                return;
            }
            match convert::uwb_range_json(&r, clock) {
                Ok(j) => {
                    let t =
                        u64::from(j.timestamp.sec) * 1_000_000_000 + u64::from(j.timestamp.nsec);
                    if let Some(ch) = uwb_range.get(ctx, &setup.foxglove, &UWB_RANGE_CHANNEL) {
                        if ch.log(&j, t) {
                            stats.ranges += 1;
                        }
                    }
                }
                Err(e) => invalid(stats, "UWB range", r.header.seq, &e),
            }
        })?;
        self.anchors_changed |= changed;
        let Self {
            stats,
            body_vel,
            height,
            _ctx: ctx,
            setup,
            ..
        } = self;
        let body_frame = setup.foxglove.child_frame_id.as_str();
        inputs.body_vel.drain(|v| {
            if v.header.pub_time_ns < opened_ns {
                stats.old += 1;
                return;
            }
            match convert::body_velocity_json(&v, body_frame, clock) {
                Ok(j) => {
                    let t =
                        u64::from(j.timestamp.sec) * 1_000_000_000 + u64::from(j.timestamp.nsec);
                    if let Some(ch) = body_vel.get(ctx, &setup.foxglove, &BODY_VEL_CHANNEL) {
                        if ch.log(&j, t) {
                            stats.velocities += 1;
                        }
                    }
                }
                Err(e) => invalid(stats, "body velocity", v.header.seq, &e),
            }
        })?;
        inputs.height.drain(|h| {
            if h.header.pub_time_ns < opened_ns {
                stats.old += 1;
                return;
            }
            match convert::height_json(&h, body_frame, clock) {
                Ok(j) => {
                    let t =
                        u64::from(j.timestamp.sec) * 1_000_000_000 + u64::from(j.timestamp.nsec);
                    if let Some(ch) = height.get(ctx, &setup.foxglove, &HEIGHT_CHANNEL) {
                        if ch.log(&j, t) {
                            stats.heights += 1;
                        }
                    }
                }
                Err(e) => invalid(stats, "height", h.header.seq, &e),
            }
        })?;
        let now = monotonic_ns();
        inputs.health.drain(|h| group.note_heartbeat(h, now))?;
        Ok(())
    }

    /// The health of every stage, the anchors and the robot's model.
    fn report(&mut self, clock: &ClockOffset, group: &GroupSeen, now_ns: u64, stale_after_ns: u64) {
        let Ok(ts) = convert::stamp_ns(now_ns, clock) else {
            self.stats.invalid += 1;
            return;
        };
        let stamp = convert::timestamp(ts);
        let h = HealthJson {
            timestamp: stamp.into(),
            stages: group
                .stages()
                .map(|(name, seen, coasting)| {
                    convert::stage_health(name, seen, coasting, now_ns, stale_after_ns)
                })
                .collect(),
        };
        if self.health.log(&h, ts) {
            self.stats.health += 1;
        }
        let c = &self.setup.foxglove;
        self.robot
            .log_with_time(&convert::robot_scene(&c.child_frame_id, stamp), ts);
        self.publish_anchors(clock, now_ns);
    }

    fn between_reports(&mut self, clock: &ClockOffset) {
        if self.anchors_changed {
            self.publish_anchors(clock, monotonic_ns());
        }
    }

    fn counters(&self, inputs: &Inputs) -> HealthCounters {
        let mut c = HealthCounters::default();
        for st in [
            inputs.fused.stats(),
            inputs.fix.stats(),
            inputs.tdoa.stats(),
            inputs.range.stats(),
            inputs.diag.stats(),
            inputs.truth.stats(),
            inputs.body_vel.stats(),
            inputs.height.stats(),
            inputs.health.stats(),
        ] {
            c.add_sub(&st);
        }
        let s = &self.stats;
        c.published = s.poses
            + s.fixes
            + s.truth
            + s.errors
            + s.diags
            + s.velocities
            + s.heights
            + s.ranges
            + s.health;
        c.dropped_invalid = s.invalid;
        c.dropped_time = s.old;
        let clients = self.server.as_ref().map_or(0, |h| h.client_count());
        c.stage = StageCounters::Foxglove(FoxgloveCounters {
            poses: s.poses,
            fixes: s.fixes,
            diags: s.diags,
            clients: clients as u64,
        });
        c
    }
}

impl LazyChannel {
    /// The channel, made as `spec` says now if this is its first message;
    /// `None` when making it failed (said once, as a warning).
    fn get(
        &mut self,
        ctx: &Arc<Context>,
        c: &FoxgloveConfig,
        spec: &LazySpec,
    ) -> Option<&JsonChannel> {
        if matches!(self, Self::NotYet) {
            debug_assert!(
                TOPICS.contains(&spec.topic),
                "{} missing in TOPICS",
                spec.topic
            );
            *self = match json_channel(ctx, c.topic(spec.topic), spec.schema_name, spec.schema) {
                Ok(ch) => Self::Open(ch),
                Err(e) => {
                    tracing::warn!("{} not shown: {e}", spec.what);
                    Self::Failed
                }
            };
        }
        match self {
            Self::Open(ch) => Some(ch),
            Self::NotYet | Self::Failed => None,
        }
    }
}

/// Adds or moves anchor `a`; true when that changed the list.
fn note_anchor(anchors: &mut Vec<Anchor>, a: Anchor) -> bool {
    if a.pos_m.iter().any(|v| !v.is_finite()) {
        return false;
    }
    if let Some(x) = anchors.iter_mut().find(|x| x.id == a.id) {
        let moved = x.pos_m != a.pos_m;
        x.pos_m = a.pos_m;
        return moved;
    }
    if anchors.len() >= MAX_ANCHORS {
        return false;
    }
    anchors.push(a);
    anchors.sort_by_key(|x| x.id);
    true
}

impl Outputs {
    fn truth_sample(&mut self, t: &GroundTruth, frame: &str, clock: &ClockOffset) {
        match convert::truth_pose(t, frame, clock) {
            Ok(p) => {
                self.truth_track.push(t.header.meas_time_ns, t.pos_m);
                let Some((truth, _)) = &self.truth else {
                    return;
                };
                let ts = p.timestamp.map_or(0, |t| t.total_nanos());
                truth.log_with_time(&p, ts);
                self.stats.truth += 1;
            }
            Err(e) => invalid(&mut self.stats, "ground truth", t.header.seq, &e),
        }
    }

    fn fused_sample(&mut self, s: &FusedState, frame: &str, clock: &ClockOffset) {
        match convert::fused_pose(s, frame, clock) {
            Ok(p) => {
                let ts = p.timestamp.map_or(0, |t| t.total_nanos());
                let child = &self.setup.foxglove.child_frame_id;
                self.tf
                    .log_with_time(&convert::pose_transform(&p, child), ts);
                if let Some(pose) = p.pose {
                    self.path.push(pose);
                }
                if self.path_ch.has_sinks() {
                    if let Some(stamp) = p.timestamp {
                        self.path_ch
                            .log_with_time(&self.path.message(frame, stamp), ts);
                    }
                }
                self.pose.log_with_time(&p, ts);
                self.stats.poses += 1;
                if self.truth.is_some() {
                    if self.pending.len() == PENDING_KEPT {
                        self.pending.remove(0);
                    }
                    self.pending.push((s.header.meas_time_ns, s.pos_m));
                }
            }
            Err(e) => invalid(&mut self.stats, "fused state", s.header.seq, &e),
        }
    }

    /// Logs the position errors of the fused states whose truth has come;
    /// drops those older than every truth sample held.
    fn flush_pending(&mut self, clock: &ClockOffset) {
        let Some((_, error)) = &self.truth else {
            return;
        };
        let newest = self.truth_track.newest_ns().unwrap_or(0);
        let track = &self.truth_track;
        let stats = &mut self.stats;
        self.pending.retain(|(t, pos)| {
            if *t > newest {
                return true;
            }
            if let (Some(truth), Ok(ts)) = (track.at(*t), convert::stamp_ns(*t, clock)) {
                let e = convert::position_error(pos, &truth, convert::timestamp(ts));
                if error.log(&e, ts) {
                    stats.errors += 1;
                }
            }
            false
        });
    }

    fn publish_anchors(&mut self, clock: &ClockOffset, now_ns: u64) {
        self.anchors_changed = false;
        if self.anchors.is_empty() {
            return;
        }
        let Ok(ts) = convert::stamp_ns(now_ns, clock) else {
            return;
        };
        let scene = convert::anchors_scene(
            &self.anchors,
            &self.setup.foxglove.frame_id,
            convert::timestamp(ts),
        );
        self.anchors_ch.log_with_time(&scene, ts);
    }

    /// Stops the server (its clients get a close frame) and its runtime,
    /// each within a second.
    fn stop(&mut self) {
        let (Some(server), Some(rt)) = (self.server.take(), self.runtime.take()) else {
            return;
        };
        let shutdown = server.stop();
        rt.block_on(async {
            let _ = tokio::time::timeout(Duration::from_secs(1), shutdown.wait()).await;
        });
        rt.shutdown_timeout(Duration::from_secs(1));
    }
}

fn invalid(stats: &mut LiveStats, what: &str, seq: u64, e: &ConvertError) {
    stats.invalid += 1;
    tracing::debug!("{what} {seq} not shown: {e}");
}

#[cfg(test)]
mod websocket_tests;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn anchors_are_kept_by_id_sorted_and_moved() {
        let mut a = Vec::new();
        assert!(note_anchor(
            &mut a,
            Anchor {
                id: 5,
                pos_m: [1.0, 0.0, 0.0]
            }
        ));
        assert!(note_anchor(
            &mut a,
            Anchor {
                id: 2,
                pos_m: [0.0, 1.0, 0.0]
            }
        ));
        assert!(!note_anchor(
            &mut a,
            Anchor {
                id: 5,
                pos_m: [1.0, 0.0, 0.0]
            }
        ));
        assert!(!note_anchor(
            &mut a,
            Anchor {
                id: 3,
                pos_m: [f64::NAN, 0.0, 0.0]
            }
        ));
        assert!(note_anchor(
            &mut a,
            Anchor {
                id: 5,
                pos_m: [2.0, 0.0, 0.0]
            }
        ));
        assert_eq!(a.iter().map(|x| x.id).collect::<Vec<_>>(), [2, 5]);
        assert_eq!(a[1].pos_m, [2.0, 0.0, 0.0]);
    }
}
