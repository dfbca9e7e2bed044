//! The bridge loop: subscribes to `fused`, `imu` and `health` over
//! iceoryx2 and publishes them as a ROS 2 node over DDS (`ros2-client` on
//! RustDDS; no ROS installation):
//!
//! | ROS topic | type | QoS | from |
//! |---|---|---|---|
//! | `<ns>/odom` | `nav_msgs/Odometry` | reliable, volatile, keep-last 10 | each fused state |
//! | `/tf` | `tf2_msgs/TFMessage` | reliable, volatile, keep-last 100 | each fused state (`publish_tf`) |
//! | `/tf_static` | `tf2_msgs/TFMessage` | reliable, transient-local, keep-last 1 | once: every static transform in one message |
//! | `<ns>/imu` | `sensor_msgs/Imu` | reliable, volatile, keep-last 10 | each IMU sample (`publish_imu`) |
//! | `/diagnostics` | `diagnostic_msgs/DiagnosticArray` | reliable, volatile, keep-last 10 | every `diagnostics_period_s`: one status per stage |
//!
//! and, when `[ros2] odometry_in` or `height_in` names a topic, it reads
//! the robot base's odometry or a downward range finder from ROS and
//! publishes them on iceoryx2:
//!
//! | ROS topic (in) | type | QoS | to |
//! |---|---|---|---|
//! | `odometry_in` | `nav_msgs/Odometry` or `geometry_msgs/TwistStamped` (`odometry_in_type`) | best effort, volatile, keep-last 100 (matches reliable and best-effort writers) | `body_vel`: a `BodyVelocity` of source odometry per message the velocity gate accepts |
//! | `height_in` | `sensor_msgs/Range` | as `odometry_in` | `height`: a `Height` of source range finder per reading within the sensor's limits that the height gate accepts ([`crate::height_in`]) |
//!
//! Each message's linear twist is taken as the body's velocity (its frame
//! should be `child_frame_id`; another is used all the same, counted and
//! warned of once), each axis's sigma from the twist covariance's diagonal
//! (0: `odometry_in_sigma_mps`; 1e6 or more: not measured; negative or NaN:
//! refused), timed by its stamp mapped to CLOCK_MONOTONIC
//! ([`crate::convert::TwistMessage`], [`crate::odometry_in`]). Every
//! velocity passes `insuwb_msg::check::VelocityGate` (values, then a time
//! strictly after the previous one's); refused ones are counted and never
//! published. The reader is drained with non-blocking takes at each drain.
//!
//! The loop ([`crate::report_loop`]) sleeps in the stage's `Waiter`: it
//! wakes for each fused state, drains the IMU samples and heartbeats then
//! (or [`DRAIN_PERIOD_NS`] after the last drain while no fused state
//! comes), publishes the diagnostics on their own interval and its own
//! heartbeat on `health` like every stage.
//! A DDS write never blocks the loop (a full reliable send window drops
//! the message and counts it). Stamps: see [`crate::convert`].
//!
//! Samples published (on iceoryx2) before the bridge opened are not
//! republished: a restarted bridge's subscribers first get the topics'
//! history, which its previous run published already.
//!
//! Heartbeat counters: `received` what the subscribers got and the odometry
//! and range messages taken, `published` the DDS messages written and the
//! body velocities and heights published, `dropped_invalid` samples no
//! conversion accepts and odometry and ranges refused for their values (or
//! the sensor's limits) or undecodable, `dropped_time` samples too old to
//! republish and odometry and ranges refused for their time, and
//! [`Ros2BridgeCounters`] (odometry, IMU and transforms written, write
//! failures, body velocities published, odometry in another frame).

use insuwb_msg::{
    topics, BodyVelocity, FusedState, Health, Height, ImuSample, Ros2BridgeCounters, StageCounters,
};
use insuwb_runtime::{
    monotonic_ns, HealthCounters, HealthReporter, PortError, Pub, RuntimeConfig, Stage, StageError,
    Sub,
};
use ros2_client::qos::{Durability, History, WhenFull};
use ros2_client::{
    Context, ContextOptions, MessageTypeName, Name, NodeName, NodeOptions, QosProfile, ReadError,
    Subscription,
};
use serde::de::DeserializeOwned;

use crate::config::{OdometryInType, Ros2Config, Ros2ConfigError};
use crate::convert::{self, ConvertError, Frames, RosStamp, TwistMessage};
use crate::height_in::HeightIntake;
use crate::msgs::{
    DiagnosticArray, Header, Imu, Odometry, Range, RosMessage, TfMessage, TransformStamped,
    TwistStamped,
};
use crate::odometry_in::OdometryIntake;
use insuwb_report::clock::ClockOffset;
use insuwb_report::health::GroupSeen;
use insuwb_report::report_loop::{ReportLoop, ReportOutputs};

pub use insuwb_report::report_loop::DRAIN_PERIOD_NS;

/// What the bridge needs besides `[ros2]`.
#[derive(Debug, Clone)]
pub struct BridgeSetup {
    /// The iceoryx2 node of the stage (prefix, root, name `ros2`).
    pub runtime: RuntimeConfig,
    /// `[ros2]`.
    pub ros2: Ros2Config,
    /// The stages of the group, each reported on `/diagnostics`.
    pub stages: Vec<String>,
    /// `hardware_id` of the diagnostics (the group's name).
    pub hardware_id: String,
    /// Antenna position in the body frame, m (`/tf_static`).
    pub antenna_lever_arm_m: [f64; 3],
}

/// Opening the bridge failed.
#[derive(Debug, thiserror::Error)]
pub enum BridgeOpenError {
    /// `[ros2]` is invalid.
    #[error("BridgeOpenError::Config: {0}")]
    Config(#[from] Ros2ConfigError),
    /// The iceoryx2 node.
    #[error("BridgeOpenError::Stage: {0}")]
    Stage(#[from] StageError),
    /// A subscriber or the heartbeat publisher.
    #[error("BridgeOpenError::Port: {0}")]
    Port(#[from] PortError),
    /// A DDS entity (participant, node, topic, writer).
    #[error("BridgeOpenError::Dds: {what}: {reason}")]
    Dds {
        /// What was being created.
        what: String,
        /// The middleware's error.
        reason: String,
    },
    /// The static transforms.
    #[error("BridgeOpenError::StaticTransform: {0}")]
    StaticTransform(ConvertError),
}

/// The loop ended with an error (the report loop's, shared by the
/// stages it runs).
pub use insuwb_report::report_loop::ReportLoopError as BridgeRunError;

/// What the bridge published, for the log line at its end.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct BridgeStats {
    /// `nav_msgs/Odometry` messages.
    pub odometry: u64,
    /// `sensor_msgs/Imu` messages.
    pub imu: u64,
    /// `/tf` messages.
    pub tf: u64,
    /// `/diagnostics` messages.
    pub diagnostics: u64,
    /// Samples no conversion accepted.
    pub invalid: u64,
    /// Samples published before the bridge opened (the history a restarted
    /// bridge's subscribers get first): not republished.
    pub old: u64,
    /// DDS writes that failed (full send window, middleware error).
    pub write_failures: u64,
    /// Body velocities published on `body_vel` from `[ros2] odometry_in`.
    pub velocities: u64,
    /// Odometry messages refused (invalid values, an undecodable message,
    /// a time not after the previous one's).
    pub velocities_refused: u64,
    /// Odometry messages whose twist is in a frame other than the body
    /// frame.
    pub velocities_other_frame: u64,
    /// Takes from the odometry reader that failed (not a message).
    pub odometry_in_read_failures: u64,
    /// Heights published on `height` from `[ros2] height_in`.
    pub heights: u64,
    /// Range messages refused (beyond the sensor's limits, invalid values,
    /// an undecodable message, a time not after the previous one's).
    pub heights_refused: u64,
    /// Takes from the range reader that failed (not a message).
    pub height_in_read_failures: u64,
}

type Publisher<M> = ros2_client::Publisher<M>;

/// The open bridge: iceoryx2 subscribers and DDS writers.
pub struct Bridge {
    stage: Stage,
    inputs: Inputs,
    health: HealthReporter,
    out: Outputs,
}

/// The iceoryx2 subscribers.
struct Inputs {
    fused: Sub<FusedState>,
    imu: Sub<ImuSample>,
    health: Sub<Health>,
}

/// The DDS side: node, writers, what was written.
struct Outputs {
    setup: BridgeSetup,
    frames: Frames,
    /// When the bridge opened (CLOCK_MONOTONIC ns): samples published
    /// earlier are history.
    opened_ns: u64,
    stats: BridgeStats,
    // Fields drop in order: the writers before the node and the node
    // before the participant (context) that removes them.
    odom_pub: Publisher<Odometry>,
    tf_pub: Option<Publisher<TfMessage>>,
    _tf_static_pub: Publisher<TfMessage>,
    imu_pub: Option<Publisher<Imu>>,
    diag_pub: Publisher<DiagnosticArray>,
    odometry_in: Option<OdometryIn>,
    height_in: Option<HeightIn>,
    _node: ros2_client::Node,
    _context: Context,
}

/// The iceoryx2 publishers of what the bridge reads from ROS (`None`:
/// that input is not configured).
struct InPorts {
    body_vel: Option<Pub<BodyVelocity>>,
    height: Option<Pub<Height>>,
}

/// Most messages taken from an input reader in one drain: a bound on
/// the loop's time even when a publisher floods it (the reader keeps
/// [`crate::subscribe::QUEUE_DEPTH`]).
const MAX_TAKES_PER_DRAIN: usize = 4 * crate::subscribe::QUEUE_DEPTH;

/// The reader of `[ros2] odometry_in`, of its configured type.
enum TwistReader {
    /// `nav_msgs/Odometry`.
    Odometry(Subscription<Odometry>),
    /// `geometry_msgs/TwistStamped`.
    TwistStamped(Subscription<TwistStamped>),
}

/// The base's odometry in: DDS reader, intake, iceoryx2 publisher.
struct OdometryIn {
    reader: TwistReader,
    intake: OdometryIntake,
    body_vel: Pub<BodyVelocity>,
}

impl OdometryIn {
    /// Takes every message the reader holds (at most
    /// [`MAX_TAKES_PER_DRAIN`]), without waiting, and publishes the
    /// velocities the intake accepts.
    fn drain(
        &mut self,
        clock: &ClockOffset,
        stats: &mut BridgeStats,
    ) -> Result<(), BridgeRunError> {
        let Self {
            reader,
            intake,
            body_vel,
        } = self;
        match reader {
            TwistReader::Odometry(r) => take_all(r, intake, body_vel, clock, stats),
            TwistReader::TwistStamped(r) => take_all(r, intake, body_vel, clock, stats),
        }
    }
}

fn take_all<M: TwistMessage + DeserializeOwned + 'static>(
    reader: &Subscription<M>,
    intake: &mut OdometryIntake,
    body_vel: &mut Pub<BodyVelocity>,
    clock: &ClockOffset,
    stats: &mut BridgeStats,
) -> Result<(), BridgeRunError> {
    let BridgeStats {
        velocities,
        odometry_in_read_failures,
        ..
    } = stats;
    let failures = odometry_in_read_failures;
    take_each(reader, intake, clock, failures, "odometry_in", |v| {
        body_vel.publish(v).map_err(BridgeRunError::Publish)?;
        *velocities += 1;
        Ok(())
    })
}

/// An intake of ROS messages `M`: the checked sample of each, or none
/// (counted by the intake).
trait Intake<M> {
    /// What a message becomes.
    type Sample;
    /// The sample of `m` received at `rx_ns`, `None` when refused.
    fn take_message(&mut self, m: &M, clock: &ClockOffset, rx_ns: u64) -> Option<Self::Sample>;
    /// Counts a message that did not decode.
    fn count_undecodable(&mut self);
}

impl<M: TwistMessage> Intake<M> for OdometryIntake {
    type Sample = BodyVelocity;
    fn take_message(&mut self, m: &M, clock: &ClockOffset, rx_ns: u64) -> Option<BodyVelocity> {
        self.take(m, clock, rx_ns)
    }
    fn count_undecodable(&mut self) {
        self.undecodable();
    }
}

impl Intake<Range> for HeightIntake {
    type Sample = Height;
    fn take_message(&mut self, m: &Range, clock: &ClockOffset, rx_ns: u64) -> Option<Height> {
        self.take(m, clock, rx_ns)
    }
    fn count_undecodable(&mut self) {
        self.undecodable();
    }
}

/// Takes every message `reader` holds (at most [`MAX_TAKES_PER_DRAIN`]),
/// without waiting, through `intake`, and hands each accepted sample to
/// `publish`; a failed take ends the drain, counted in `failures` and
/// warned of (the first, then one in a thousand) under the key `what`.
fn take_each<M: DeserializeOwned + 'static, I: Intake<M>>(
    reader: &Subscription<M>,
    intake: &mut I,
    clock: &ClockOffset,
    failures: &mut u64,
    what: &str,
    mut publish: impl FnMut(I::Sample) -> Result<(), BridgeRunError>,
) -> Result<(), BridgeRunError> {
    for _ in 0..MAX_TAKES_PER_DRAIN {
        match reader.take() {
            Ok(Some((m, _))) => {
                if let Some(s) = intake.take_message(&m, clock, monotonic_ns()) {
                    publish(s)?;
                }
            }
            Ok(None) => break,
            Err(ReadError::Deserialization { .. } | ReadError::Malformed) => {
                intake.count_undecodable();
            }
            Err(e) => {
                *failures += 1;
                if *failures % 1000 == 1 {
                    tracing::warn!("ros2: reading {what} failed ({failures} so far): {e}");
                }
                break;
            }
        }
    }
    Ok(())
}

/// The range finder in: DDS reader, intake, iceoryx2 publisher.
struct HeightIn {
    reader: Subscription<Range>,
    intake: HeightIntake,
    height: Pub<Height>,
}

impl HeightIn {
    /// Takes every message the reader holds (at most
    /// [`MAX_TAKES_PER_DRAIN`]), without waiting, and publishes the
    /// heights the intake accepts.
    fn drain(
        &mut self,
        clock: &ClockOffset,
        stats: &mut BridgeStats,
    ) -> Result<(), BridgeRunError> {
        let Self {
            reader,
            intake,
            height,
        } = self;
        let BridgeStats {
            heights,
            height_in_read_failures,
            ..
        } = stats;
        take_each(
            reader,
            intake,
            clock,
            height_in_read_failures,
            "height_in",
            |h| {
                height.publish(h).map_err(BridgeRunError::Publish)?;
                *heights += 1;
                Ok(())
            },
        )
    }
}

impl std::fmt::Debug for Bridge {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Bridge")
            .field("setup", &self.out.setup)
            .field("stats", &self.out.stats)
            .finish_non_exhaustive()
    }
}

fn dds<T, E: std::fmt::Display>(what: &str, r: Result<T, E>) -> Result<T, BridgeOpenError> {
    r.map_err(|e| BridgeOpenError::Dds {
        what: what.to_owned(),
        reason: e.to_string(),
    })
}

/// Reliable, never blocking the writer, volatile, keep-last `depth`.
fn reliable(depth: usize, durability: Durability) -> QosProfile {
    QosProfile::publisher_default()
        .reliability_reliable(WhenFull::Fail)
        .durability(durability)
        .history(History::KeepLast { depth })
}

/// The reader of an input topic (`[ros2] odometry_in`, `height_in`; full
/// name `topic`) of type `M`, with the QoS that matches reliable and
/// best-effort writers.
fn in_reader<M: RosMessage + DeserializeOwned + 'static>(
    node: &mut ros2_client::Node,
    topic: &str,
) -> Result<Subscription<M>, BridgeOpenError> {
    let name = dds(&format!("topic name {topic}"), Name::parse(topic))?;
    let ty = MessageTypeName::new(M::DEF.package, M::DEF.name);
    let t = dds(
        &format!("topic {topic} ({})", M::type_name()),
        node.create_topic(&name, ty, &crate::subscribe::imu_qos()),
    )?;
    dds(
        &format!("reader on {topic}"),
        node.create_subscription::<M>(&t, None),
    )
}

fn publisher<M: RosMessage>(
    node: &mut ros2_client::Node,
    topic: &str,
    qos: &QosProfile,
) -> Result<Publisher<M>, BridgeOpenError> {
    let name = dds(&format!("topic name {topic}"), Name::parse(topic))?;
    let ty = MessageTypeName::new(M::DEF.package, M::DEF.name);
    let t = dds(
        &format!("topic {topic} ({})", M::type_name()),
        node.create_topic(&name, ty, qos),
    )?;
    dds(
        &format!("writer on {topic}"),
        node.create_publisher::<M>(&t, None),
    )
}

impl Bridge {
    /// Opens the iceoryx2 node and its ports, the DDS participant, the node
    /// and its writers, and publishes the static transforms.
    ///
    /// # Errors
    /// [`BridgeOpenError`] naming what could not be opened.
    pub fn open(setup: BridgeSetup) -> Result<Self, BridgeOpenError> {
        let c = &setup.ros2;
        c.validate()?;
        let stage = Stage::new(setup.runtime.clone())?;
        let fused = stage.subscriber::<FusedState>(topics::FUSED)?;
        let imu = stage.subscriber::<ImuSample>(topics::IMU)?;
        let health_sub = stage.subscriber::<Health>(topics::HEALTH)?;
        let body_vel = match c.odometry_in_topic_name() {
            Some(_) => Some(stage.publisher::<BodyVelocity>(topics::BODY_VEL)?),
            None => None,
        };
        let height = match c.height_in_topic_name() {
            Some(_) => Some(stage.publisher::<Height>(topics::HEIGHT)?),
            None => None,
        };
        let health = stage.health_reporter()?;
        insuwb_runtime::signal::with_signals_blocked(|| {
            Self::open_dds(
                setup,
                stage,
                Inputs {
                    fused,
                    imu,
                    health: health_sub,
                },
                health,
                InPorts { body_vel, height },
            )
        })
    }

    /// The DDS half of [`Bridge::open`] (run with signals blocked).
    fn open_dds(
        setup: BridgeSetup,
        stage: Stage,
        inputs: Inputs,
        health: HealthReporter,
        ports: InPorts,
    ) -> Result<Self, BridgeOpenError> {
        let InPorts { body_vel, height } = ports;
        let c = &setup.ros2;
        let context = dds(
            &format!("DDS participant in domain {}", c.domain_id),
            Context::with_options(ContextOptions::new().domain_id(c.domain_id)),
        )?;
        let mut node = dds(
            &format!("node {}/{}", c.namespace, c.node_name),
            NodeName::new(&c.namespace, &c.node_name)
                .map_err(|e| e.to_string())
                .and_then(|n| {
                    context
                        .new_node(
                            n,
                            NodeOptions::new()
                                .enable_rosout(false)
                                .start_parameter_services(false),
                        )
                        .map_err(|e| e.to_string())
                }),
        )?;
        let volatile10 = reliable(10, Durability::Volatile);
        let odom_pub = publisher::<Odometry>(&mut node, &c.odom_topic_name(), &volatile10)?;
        let tf_pub = if c.publish_tf {
            Some(publisher::<TfMessage>(
                &mut node,
                "/tf",
                &reliable(100, Durability::Volatile),
            )?)
        } else {
            None
        };
        let tf_static_pub = publisher::<TfMessage>(
            &mut node,
            "/tf_static",
            &reliable(1, Durability::TransientLocal),
        )?;
        let imu_pub = if c.publish_imu {
            Some(publisher::<Imu>(
                &mut node,
                &c.imu_topic_name(),
                &volatile10,
            )?)
        } else {
            None
        };
        let diag_pub =
            publisher::<DiagnosticArray>(&mut node, &c.diagnostics_topic_name(), &volatile10)?;
        let odometry_in = match (c.odometry_in_topic_name(), body_vel) {
            (Some(topic), Some(body_vel)) => {
                let reader = match c.odometry_in_type {
                    OdometryInType::Odometry => {
                        TwistReader::Odometry(in_reader::<Odometry>(&mut node, &topic)?)
                    }
                    OdometryInType::TwistStamped => {
                        TwistReader::TwistStamped(in_reader::<TwistStamped>(&mut node, &topic)?)
                    }
                };
                tracing::info!(
                    "ROS 2 odometry in: {topic} ({}), body velocities on {}",
                    c.odometry_in_type.name(),
                    topics::BODY_VEL
                );
                Some(OdometryIn {
                    reader,
                    intake: OdometryIntake::new(c),
                    body_vel,
                })
            }
            _ => None,
        };
        let height_in = match (c.height_in_topic_name(), height) {
            (Some(topic), Some(height)) => {
                let reader = in_reader::<Range>(&mut node, &topic)?;
                tracing::info!(
                    "ROS 2 range finder in: {topic} (sensor_msgs/Range), heights on {}",
                    topics::HEIGHT
                );
                Some(HeightIn {
                    reader,
                    intake: HeightIntake::new(),
                    height,
                })
            }
            _ => None,
        };
        let frames = Frames {
            frame_id: c.frame_id.clone(),
            child_frame_id: c.child_frame_id.clone(),
            imu_frame_id: c.imu_frame_id.clone(),
        };
        let statics = static_transforms(&setup, ClockOffset::measure(c.stamp_clock))
            .map_err(BridgeOpenError::StaticTransform)?;
        let n = statics.transforms.len();
        dds("the /tf_static message", tf_static_pub.publish(statics))?;
        tracing::info!(
            "ROS 2 node {}/{} in domain {}: {} (frames {} -> {}), {n} static transform(s)",
            c.namespace,
            c.node_name,
            c.domain_id,
            c.odom_topic_name(),
            c.frame_id,
            c.child_frame_id
        );
        Ok(Self {
            stage,
            inputs,
            health,
            out: Outputs {
                frames,
                _node: node,
                _context: context,
                odom_pub,
                tf_pub,
                _tf_static_pub: tf_static_pub,
                imu_pub,
                diag_pub,
                odometry_in,
                height_in,
                stats: BridgeStats::default(),
                opened_ns: monotonic_ns(),
                setup,
            },
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
        let r = &out.setup.ros2;
        let stages = out.setup.stages.clone();
        let looped = ReportLoop {
            stages: &stages,
            report_period_s: r.diagnostics_period_s,
            stale_after_s: r.stale_after_s,
            stamp_clock: r.stamp_clock,
        };
        looped.run(&stage, &inputs.fused, &inputs, &mut health, &mut out)?;
        if let Some(o) = &out.odometry_in {
            out.stats.velocities_refused = o.intake.dropped_invalid() + o.intake.dropped_time();
            out.stats.velocities_other_frame = o.intake.counts().other_frame;
        }
        if let Some(h) = &out.height_in {
            out.stats.heights_refused = h.intake.dropped_invalid() + h.intake.dropped_time();
        }
        Ok(out.stats)
    }
}

impl ReportOutputs for Outputs {
    type Inputs = Inputs;
    type Error = BridgeRunError;

    /// Drains the three subscribers and the input readers and publishes
    /// what they held.
    fn drain(
        &mut self,
        inputs: &Inputs,
        clock: &ClockOffset,
        group: &mut GroupSeen,
    ) -> Result<(), BridgeRunError> {
        let Inputs {
            fused,
            imu,
            health: health_sub,
        } = inputs;
        let Self {
            setup,
            frames,
            opened_ns,
            odom_pub,
            tf_pub,
            imu_pub,
            stats,
            odometry_in,
            height_in,
            ..
        } = self;
        let only_valid = setup.ros2.only_valid;
        let opened_ns = *opened_ns;
        fused.drain(|s| {
            if s.header.pub_time_ns < opened_ns {
                stats.old += 1;
                return;
            }
            group.note_fused(&s);
            if only_valid && s.header.flags & FusedState::FLAG_VALID == 0 {
                return;
            }
            match convert::fused_to_odometry(&s, frames, clock) {
                Ok(o) => {
                    let tf = tf_pub.as_ref().map(|p| {
                        (
                            p,
                            TransformStamped {
                                header: o.header.clone(),
                                child_frame_id: o.child_frame_id.clone(),
                                transform: crate::msgs::Transform {
                                    translation: crate::msgs::Vector3 {
                                        x: o.pose.pose.position.x,
                                        y: o.pose.pose.position.y,
                                        z: o.pose.pose.position.z,
                                    },
                                    rotation: o.pose.pose.orientation,
                                },
                            },
                        )
                    });
                    write(odom_pub, o, &mut stats.odometry, &mut stats.write_failures);
                    if let Some((p, t)) = tf {
                        let m = TfMessage {
                            transforms: vec![t],
                        };
                        write(p, m, &mut stats.tf, &mut stats.write_failures);
                    }
                }
                Err(e) => {
                    stats.invalid += 1;
                    tracing::debug!("fused state {} not published: {e}", s.header.seq);
                }
            }
        })?;
        imu.drain(|s| {
            let Some(p) = imu_pub.as_ref() else { return };
            if s.header.pub_time_ns < opened_ns {
                stats.old += 1;
                return;
            }
            match convert::imu_to_ros(&s, frames, clock) {
                Ok(m) => write(p, m, &mut stats.imu, &mut stats.write_failures),
                Err(e) => {
                    stats.invalid += 1;
                    tracing::debug!("IMU sample {} not published: {e}", s.header.seq);
                }
            }
        })?;
        if let Some(o) = odometry_in {
            o.drain(clock, stats)?;
        }
        if let Some(h) = height_in {
            h.drain(clock, stats)?;
        }
        let now = monotonic_ns();
        health_sub.drain(|h| group.note_heartbeat(h, now))?;
        Ok(())
    }

    /// Publishes one status per stage on `/diagnostics`.
    fn report(&mut self, clock: &ClockOffset, group: &GroupSeen, now_ns: u64, stale_after_ns: u64) {
        let stamp = match clock.stamp(now_ns) {
            Ok(t) => t,
            Err(e) => {
                self.stats.invalid += 1;
                tracing::debug!("diagnostics not published: {e}");
                return;
            }
        };
        let status = group
            .stages()
            .map(|(name, seen, coasting)| {
                convert::stage_status(
                    name,
                    &self.setup.hardware_id,
                    seen,
                    coasting,
                    now_ns,
                    stale_after_ns,
                )
            })
            .collect();
        let m = DiagnosticArray {
            header: Header {
                stamp,
                frame_id: String::new(),
            },
            status,
        };
        write(
            &self.diag_pub,
            m,
            &mut self.stats.diagnostics,
            &mut self.stats.write_failures,
        );
    }

    fn counters(&self, inputs: &Inputs) -> HealthCounters {
        let mut c = HealthCounters::default();
        for st in [
            inputs.fused.stats(),
            inputs.imu.stats(),
            inputs.health.stats(),
        ] {
            c.add_sub(&st);
        }
        let s = &self.stats;
        c.published = s.odometry + s.imu + s.tf + s.diagnostics + s.velocities + s.heights;
        c.dropped_invalid = s.invalid;
        c.dropped_time = s.old;
        let mut other_frame = 0;
        if let Some(o) = &self.odometry_in {
            c.received += o.intake.counts().received;
            c.dropped_invalid += o.intake.dropped_invalid();
            c.dropped_time += o.intake.dropped_time();
            other_frame = o.intake.counts().other_frame;
        }
        if let Some(h) = &self.height_in {
            c.received += h.intake.counts().received;
            c.dropped_invalid += h.intake.dropped_invalid();
            c.dropped_time += h.intake.dropped_time();
        }
        c.stage = StageCounters::Ros2Bridge(Ros2BridgeCounters {
            odometry: s.odometry,
            imu: s.imu,
            tf: s.tf,
            write_failures: s.write_failures,
            velocities: s.velocities,
            velocities_other_frame: other_frame,
        });
        c
    }
}

/// Writes `m`, counting it in `ok` or, when the writer refuses it, in
/// `failed` (a full reliable send window: the loop never waits for a slow
/// reader).
fn write<M: RosMessage>(p: &Publisher<M>, m: M, ok: &mut u64, failed: &mut u64) {
    match p.publish(m) {
        Ok(()) => *ok += 1,
        Err(e) => {
            *failed += 1;
            // The first failure and then one in a thousand.
            if *failed % 1000 == 1 {
                tracing::warn!(
                    "DDS write on {} failed ({failed} so far): {e}",
                    M::type_name()
                );
            }
        }
    }
}

/// Every static transform in one message: the UWB antenna under the body
/// frame, and the IMU frame (identity) when it is not the body frame.
///
/// # Errors
/// [`ConvertError`] for a non-finite lever arm or a stamp out of range.
pub fn static_transforms(
    setup: &BridgeSetup,
    clock: ClockOffset,
) -> Result<TfMessage, ConvertError> {
    let c = &setup.ros2;
    let stamp = clock.stamp(monotonic_ns())?;
    let mut transforms = vec![convert::static_transform(
        &c.child_frame_id,
        &c.antenna_frame_id,
        setup.antenna_lever_arm_m,
        stamp,
    )?];
    if c.imu_frame_id != c.child_frame_id {
        transforms.push(convert::static_transform(
            &c.child_frame_id,
            &c.imu_frame_id,
            [0.0; 3],
            stamp,
        )?);
    }
    Ok(TfMessage { transforms })
}
