//! A ROS 2 subscriber over DDS (`ros2-client` on RustDDS): one node with one
//! reader of one message type ([`Subscriber`]), with bounded waits
//! ([`Subscriber::recv_timeout`]) so a stage's loop keeps its heartbeat and
//! sees a shutdown.
//!
//! - [`ImuSubscriber`]: `sensor_msgs/Imu`, for robots whose IMU is already
//!   in ROS: the IMU driver's source `ros2:/TOPIC` reads it, converts each
//!   message with [`crate::convert::ros_to_imu_sample`] and publishes it on
//!   iceoryx2. The node is `<[ros2] node_name>_imu_in` in the `[ros2]`
//!   namespace and domain; a relative topic is taken under that namespace.
//!   QoS: best effort, volatile, keep-last [`QUEUE_DEPTH`]: a best-effort
//!   reader matches both the sensor-data QoS ROS IMU drivers publish with
//!   (best effort) and reliable writers.
//! - `insuwb bench latency --with ros2` reads the bridge's
//!   `nav_msgs/Odometry` with one, to time the delivery over DDS.

use std::time::Duration;

use ros2_client::dds::rustdds::mio1::{Events, Interest, Poll, Token};
use ros2_client::qos::{Durability, History};
use ros2_client::{
    Context, ContextOptions, MessageTypeName, Name, NodeName, NodeOptions, QosProfile, ReadError,
    Subscription,
};

use crate::config::{check_topic_name, Ros2Config, Ros2ConfigError, TopicNameError};
use crate::msgs::{Imu, RosMessage};
use insuwb_runtime::signal::with_signals_blocked;
use serde::de::DeserializeOwned;

/// Messages the reader keeps while the driver is busy: 100 ms at 1 kHz.
pub const QUEUE_DEPTH: usize = 100;

/// Opening the subscriber failed.
#[derive(Debug, thiserror::Error)]
pub enum SubscribeError {
    /// `[ros2]` is invalid.
    #[error("SubscribeError::Config: {0}")]
    Config(#[from] Ros2ConfigError),
    /// The topic is not a ROS topic name.
    #[error("SubscribeError::Topic: {0}")]
    Topic(#[from] TopicNameError),
    /// A DDS entity (participant, node, topic, reader).
    #[error("SubscribeError::Dds: {what}: {reason}")]
    Dds {
        /// What was being created.
        what: String,
        /// The middleware's error.
        reason: String,
    },
    /// The poller of the bounded waits.
    #[error("SubscribeError::Poll: {0}")]
    Poll(std::io::Error),
}

/// Receiving failed.
#[derive(Debug, thiserror::Error)]
pub enum ReceiveError {
    /// A message that does not decode as the reader's type: it was taken
    /// and is skipped; the subscriber goes on.
    #[error("ReceiveError::Undecodable: {0}")]
    Undecodable(String),
    /// The reader failed (closed, internal error).
    #[error("ReceiveError::Reader: {0}")]
    Reader(String),
    /// Waiting failed.
    #[error("ReceiveError::Poll: {0}")]
    Poll(std::io::Error),
}

impl ReceiveError {
    /// Whether the subscriber can go on after it (an undecodable message).
    #[must_use]
    pub fn is_recoverable(&self) -> bool {
        matches!(self, Self::Undecodable(_))
    }
}

/// A ROS 2 node with one reader of `M`.
pub struct Subscriber<M: 'static> {
    topic: String,
    node_name: String,
    poll: Poll,
    events: Events,
    // Fields drop in order: the reader before the node and the node before
    // the participant (context) that removes them.
    sub: Subscription<M>,
    _node: ros2_client::Node,
    _context: Context,
}

/// The IMU source's subscriber.
pub type ImuSubscriber = Subscriber<Imu>;

impl<M: 'static> std::fmt::Debug for Subscriber<M> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Subscriber")
            .field("topic", &self.topic)
            .field("node", &self.node_name)
            .finish_non_exhaustive()
    }
}

fn dds<T, E: std::fmt::Display>(what: &str, r: Result<T, E>) -> Result<T, SubscribeError> {
    r.map_err(|e| SubscribeError::Dds {
        what: what.to_owned(),
        reason: e.to_string(),
    })
}

/// The subscriber's QoS: best effort, volatile, keep-last [`QUEUE_DEPTH`].
#[must_use]
pub fn imu_qos() -> QosProfile {
    QosProfile::subscription_default()
        .reliability_best_effort()
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: QUEUE_DEPTH })
}

/// The QoS of a reader of the bridge's odometry: reliable, volatile,
/// keep-last 10, as the bridge writes it.
#[must_use]
pub fn odometry_qos() -> QosProfile {
    QosProfile::subscription_default()
        .reliability_reliable(ros2_client::qos::WhenFull::Fail)
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 10 })
}

/// The node name of the IMU source: `<node_name>_imu_in`.
#[must_use]
pub fn node_name(ros2: &Ros2Config) -> String {
    format!("{}_imu_in", ros2.node_name.trim_end_matches('_'))
}

impl Subscriber<Imu> {
    /// The IMU source's subscriber: node [`node_name`], QoS [`imu_qos`]
    /// (see [`Subscriber::open_with`]).
    ///
    /// # Errors
    /// [`SubscribeError`] naming what could not be opened.
    pub fn open(ros2: &Ros2Config, topic: &str) -> Result<Self, SubscribeError> {
        Self::open_with(ros2, &node_name(ros2), topic, &imu_qos())
    }
}

impl<M: RosMessage + DeserializeOwned + 'static> Subscriber<M> {
    /// Opens the DDS participant in the `[ros2]` domain, the node
    /// `node_name` in the `[ros2]` namespace and the reader of `topic`
    /// (absolute, or relative to the `[ros2]` namespace) with `qos`.
    /// RustDDS's threads start with signals blocked, so SIGTERM and SIGINT
    /// stay the caller's.
    ///
    /// # Errors
    /// [`SubscribeError`] naming what could not be opened.
    pub fn open_with(
        ros2: &Ros2Config,
        node_name: &str,
        topic: &str,
        qos: &QosProfile,
    ) -> Result<Self, SubscribeError> {
        ros2.validate()?;
        check_topic_name(topic)?;
        let topic = ros2.full_topic(topic);
        with_signals_blocked(|| Self::open_dds(ros2, node_name.to_owned(), topic, qos))
    }

    fn open_dds(
        c: &Ros2Config,
        node_name: String,
        topic: String,
        qos: &QosProfile,
    ) -> Result<Self, SubscribeError> {
        let context = dds(
            &format!("DDS participant in domain {}", c.domain_id),
            Context::with_options(ContextOptions::new().domain_id(c.domain_id)),
        )?;
        let mut node = dds(
            &format!("node {}/{node_name}", c.namespace),
            NodeName::new(&c.namespace, &node_name)
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
        let name = dds(&format!("topic name {topic}"), Name::parse(&topic))?;
        let ty = MessageTypeName::new(M::DEF.package, M::DEF.name);
        let t = dds(
            &format!("topic {topic} ({})", M::type_name()),
            node.create_topic(&name, ty, qos),
        )?;
        let mut sub = dds(
            &format!("reader on {topic}"),
            node.create_subscription::<M>(&t, None),
        )?;
        let poll = Poll::new().map_err(SubscribeError::Poll)?;
        poll.registry()
            .register(&mut sub, Token(0), Interest::READABLE)
            .map_err(SubscribeError::Poll)?;
        Ok(Self {
            topic,
            node_name,
            poll,
            events: Events::with_capacity(4),
            sub,
            _node: node,
            _context: context,
        })
    }

    /// The topic's full name.
    #[must_use]
    pub fn topic(&self) -> &str {
        &self.topic
    }

    /// The next message if one is there, without waiting.
    ///
    /// # Errors
    /// [`ReceiveError`]: an undecodable message (taken; go on) or a
    /// failed reader.
    pub fn try_recv(&mut self) -> Result<Option<M>, ReceiveError> {
        match self.sub.take() {
            Ok(m) => Ok(m.map(|(m, _)| m)),
            Err(e @ (ReadError::Deserialization { .. } | ReadError::Malformed)) => {
                Err(ReceiveError::Undecodable(e.to_string()))
            }
            Err(e) => Err(ReceiveError::Reader(e.to_string())),
        }
    }

    /// The next message, waiting at most `timeout` for one; `None` when
    /// none came (or a signal interrupted the wait).
    ///
    /// # Errors
    /// As [`Subscriber::try_recv`], and a failed wait.
    pub fn recv_timeout(&mut self, timeout: Duration) -> Result<Option<M>, ReceiveError> {
        // `take` drains the reader's notifications first, so one that comes
        // after it wakes the poll below.
        if let Some(m) = self.try_recv()? {
            return Ok(Some(m));
        }
        match self.poll.poll(&mut self.events, Some(timeout)) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => return Ok(None),
            Err(e) => return Err(ReceiveError::Poll(e)),
        }
        self.try_recv()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn qos_is_best_effort_keep_last() {
        let q = imu_qos();
        assert_eq!(q.reliability, ros2_client::qos::Reliability::BestEffort);
        assert_eq!(q.durability, Durability::Volatile);
        assert_eq!(q.history, History::KeepLast { depth: QUEUE_DEPTH });
        assert_eq!(node_name(&Ros2Config::default()), "insuwb_imu_in");
    }

    #[test]
    fn a_bad_topic_or_config_is_refused_before_dds() {
        let c = Ros2Config::default();
        assert!(matches!(
            ImuSubscriber::open(&c, "/imu//data"),
            Err(SubscribeError::Topic(_))
        ));
        let bad = Ros2Config {
            domain_id: 300,
            ..Ros2Config::default()
        };
        assert!(matches!(
            ImuSubscriber::open(&bad, "/imu"),
            Err(SubscribeError::Config(_))
        ));
    }
}
