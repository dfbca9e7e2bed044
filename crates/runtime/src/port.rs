//! Typed ports: [`Pub`] stamps headers and sends zero-copy, then wakes the
//! topic's listeners; [`Sub`] copies samples out, drops other layout versions
//! and tracks sequence gaps and restarts per (source, generation).
//!
//! This module is the only place where [`insuwb_msg::qos`] settings become
//! iceoryx2 service builder calls.

use core::cell::Cell;
use core::fmt::Debug;

use iceoryx2::port::listener::{Listener, ListenerCreateError, ListenerWaitError};
use iceoryx2::port::notifier::{Notifier, NotifierCreateError, NotifierNotifyError};
use iceoryx2::port::publisher::{Publisher, PublisherCreateError};
use iceoryx2::port::subscriber::{Subscriber, SubscriberCreateError};
use iceoryx2::port::update_connections::{ConnectionFailure, UpdateConnections};
use iceoryx2::port::{LoanError, ReceiveError as IoxReceiveError, SendError};
use iceoryx2::prelude::*;
use iceoryx2::service::builder::event::{EventOpenError, EventOpenOrCreateError};
use iceoryx2::service::builder::publish_subscribe::{
    PublishSubscribeOpenError, PublishSubscribeOpenOrCreateError,
};
use iceoryx2::service::port_factory::{event as event_factory, publish_subscribe as ps_factory};
use insuwb_msg::qos::{event_name, for_topic, ServiceQos};
use insuwb_msg::{HasHeader, Header, LAYOUT_VERSION};

use crate::monotonic_ns;

/// Why a port could not be created.
#[derive(Debug, thiserror::Error)]
pub enum PortError {
    /// The topic is not a valid iceoryx2 service name.
    #[error("invalid topic name {0:?}")]
    InvalidTopic(String),
    /// The publish-subscribe service could not be opened or created (another
    /// process created it with other settings or another type, or it is full).
    #[error("cannot open service {topic:?}: {error}")]
    Service {
        /// The topic.
        topic: String,
        /// iceoryx2's reason.
        error: PublishSubscribeOpenOrCreateError,
    },
    /// The companion event service could not be opened or created.
    #[error("cannot open event service {name:?}: {error}")]
    Event {
        /// The event service name.
        name: String,
        /// iceoryx2's reason.
        error: EventOpenOrCreateError,
    },
    /// The publisher could not be created (too many publishers?).
    #[error("cannot create publisher on {topic:?}: {error}")]
    Publisher {
        /// The topic.
        topic: String,
        /// iceoryx2's reason.
        error: PublisherCreateError,
    },
    /// The subscriber could not be created (too many subscribers?).
    #[error("cannot create subscriber on {topic:?}: {error}")]
    Subscriber {
        /// The topic.
        topic: String,
        /// iceoryx2's reason.
        error: SubscriberCreateError,
    },
    /// The notifier of the event service could not be created.
    #[error("cannot create notifier on {topic:?}: {error}")]
    Notifier {
        /// The topic.
        topic: String,
        /// iceoryx2's reason.
        error: NotifierCreateError,
    },
    /// The listener of the event service could not be created.
    #[error("cannot create listener on {topic:?}: {error}")]
    Listener {
        /// The topic.
        topic: String,
        /// iceoryx2's reason.
        error: ListenerCreateError,
    },
}

/// Why a sample could not be published.
#[derive(Debug, thiserror::Error)]
pub enum PublishError {
    /// No shared-memory chunk could be loaned.
    #[error("cannot loan a sample on {topic:?}: {error}")]
    Loan {
        /// The topic.
        topic: String,
        /// iceoryx2's reason.
        error: LoanError,
    },
    /// The sample could not be delivered.
    #[error("cannot send on {topic:?}: {error}")]
    Send {
        /// The topic.
        topic: String,
        /// iceoryx2's reason.
        error: SendError,
    },
    /// Connections to new subscribers could not be established.
    #[error("cannot connect new subscribers of {topic:?}: {error}")]
    Connect {
        /// The topic.
        topic: String,
        /// iceoryx2's reason.
        error: ConnectionFailure,
    },
    /// The sample was sent but the listeners could not be woken.
    #[error("sample sent on {topic:?} but notify failed: {error}")]
    Notify {
        /// The topic.
        topic: String,
        /// iceoryx2's reason.
        error: NotifierNotifyError,
    },
}

/// Why a sample could not be received.
#[derive(Debug, thiserror::Error)]
pub enum ReceiveError {
    /// iceoryx2 failed to receive (a connection to a publisher failed).
    #[error("cannot receive on {topic:?}: {error}")]
    Receive {
        /// The topic.
        topic: String,
        /// iceoryx2's reason.
        error: IoxReceiveError,
    },
    /// The pending wake-ups of the topic's listener could not be consumed.
    #[error("cannot consume wake-ups of {topic:?}: {error}")]
    Listener {
        /// The topic.
        topic: String,
        /// iceoryx2's reason.
        error: ListenerWaitError,
    },
}

type PsFactory<T> = ps_factory::PortFactory<crate::service::Ipc, T, ()>;
type EvFactory = event_factory::PortFactory<crate::service::Ipc>;

fn service_name(topic: &str) -> Result<ServiceName, PortError> {
    ServiceName::new(topic).map_err(|_| PortError::InvalidTopic(topic.to_owned()))
}

/// Opens or creates the publish-subscribe service of `topic` with its QoS.
pub(crate) fn open_pubsub<T>(
    node: &Node<crate::service::Ipc>,
    topic: &str,
) -> Result<PsFactory<T>, PortError>
where
    T: ZeroCopySend + Debug + 'static,
{
    let q = for_topic(topic);
    pubsub_builder::<T>(node, topic, &q)?
        .open_or_create()
        .map_err(|source| PortError::Service {
            topic: topic.to_owned(),
            error: source,
        })
}

/// Opens (never creates) the publish-subscribe service of `topic` with its QoS.
pub(crate) fn open_existing_pubsub<T>(
    node: &Node<crate::service::Ipc>,
    topic: &str,
) -> Result<Result<PsFactory<T>, PublishSubscribeOpenError>, PortError>
where
    T: ZeroCopySend + Debug + 'static,
{
    let q = for_topic(topic);
    Ok(pubsub_builder::<T>(node, topic, &q)?.open())
}

fn pubsub_builder<T>(
    node: &Node<crate::service::Ipc>,
    topic: &str,
    q: &ServiceQos,
) -> Result<
    iceoryx2::service::builder::publish_subscribe::Builder<T, (), crate::service::Ipc>,
    PortError,
>
where
    T: ZeroCopySend + Debug + 'static,
{
    Ok(node
        .service_builder(&service_name(topic)?)
        .publish_subscribe::<T>()
        .history_size(q.history_size)
        .subscriber_max_buffer_size(q.subscriber_max_buffer_size)
        .subscriber_max_borrowed_samples(q.subscriber_max_borrowed_samples)
        .max_publishers(q.max_publishers)
        .max_subscribers(q.max_subscribers)
        .max_nodes(q.max_nodes)
        .enable_safe_overflow(q.safe_overflow))
}

fn event_builder(
    node: &Node<crate::service::Ipc>,
    topic: &str,
) -> Result<
    (
        String,
        iceoryx2::service::builder::event::Builder<crate::service::Ipc>,
    ),
    PortError,
> {
    let q = for_topic(topic);
    let name = event_name(topic);
    let sname = ServiceName::new(&name).map_err(|_| PortError::InvalidTopic(name.clone()))?;
    let b = node
        .service_builder(&sname)
        .event()
        .max_notifiers(q.max_publishers)
        .max_listeners(q.max_subscribers)
        .max_nodes(q.max_nodes);
    Ok((name, b))
}

/// Opens or creates the event service that wakes `topic`'s subscribers.
pub(crate) fn open_event(
    node: &Node<crate::service::Ipc>,
    topic: &str,
) -> Result<EvFactory, PortError> {
    let (name, b) = event_builder(node, topic)?;
    b.open_or_create().map_err(|source| PortError::Event {
        name,
        error: source,
    })
}

/// Opens (never creates) the event service of `topic`.
pub(crate) fn open_existing_event(
    node: &Node<crate::service::Ipc>,
    topic: &str,
) -> Result<Result<EvFactory, EventOpenError>, PortError> {
    let (_, b) = event_builder(node, topic)?;
    Ok(b.open())
}

/// A typed publisher: stamps the header, sends zero-copy and wakes the
/// topic's listeners.
pub struct Pub<T>
where
    T: ZeroCopySend + Copy + Debug + HasHeader + 'static,
{
    topic: String,
    publisher: Publisher<crate::service::Ipc, T, ()>,
    notifier: Notifier<crate::service::Ipc>,
    service: PsFactory<T>,
    _event: EvFactory,
    next_seq: u64,
    generation: u32,
    source_id: u16,
    published: u64,
}

impl<T> Debug for Pub<T>
where
    T: ZeroCopySend + Copy + Debug + HasHeader + 'static,
{
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Pub")
            .field("topic", &self.topic)
            .field("next_seq", &self.next_seq)
            .field("generation", &self.generation)
            .field("source_id", &self.source_id)
            .field("published", &self.published)
            .finish_non_exhaustive()
    }
}

impl<T> Pub<T>
where
    T: ZeroCopySend + Copy + Debug + HasHeader + 'static,
{
    pub(crate) fn create(
        node: &Node<crate::service::Ipc>,
        topic: &str,
        generation: u32,
        source_id: u16,
    ) -> Result<Self, PortError> {
        let service = open_pubsub::<T>(node, topic)?;
        let event = open_event(node, topic)?;
        let publisher =
            service
                .publisher_builder()
                .create()
                .map_err(|source| PortError::Publisher {
                    topic: topic.to_owned(),
                    error: source,
                })?;
        let notifier = event
            .notifier_builder()
            .create()
            .map_err(|source| PortError::Notifier {
                topic: topic.to_owned(),
                error: source,
            })?;
        Ok(Self {
            topic: topic.to_owned(),
            publisher,
            notifier,
            service,
            _event: event,
            next_seq: 0,
            generation,
            source_id,
            published: 0,
        })
    }

    /// Stamps the header (`layout_version`, `source_id`, `generation`, `seq`
    /// counting from 0, `pub_time_ns` = [`monotonic_ns`] right before sending;
    /// `flags` and `meas_time_ns` are the caller's), sends the sample
    /// zero-copy and notifies the topic's listeners. Returns the sequence
    /// number given. The counter advances only when the sample was sent; when
    /// only the notification fails ([`PublishError::Notify`]) the sample was
    /// delivered and the counter advanced.
    pub fn publish(&mut self, mut sample: T) -> Result<u64, PublishError> {
        let seq = self.next_seq;
        {
            let h = sample.header_mut();
            h.layout_version = LAYOUT_VERSION;
            h.source_id = self.source_id;
            h.generation = self.generation;
            h.seq = seq;
        }
        self.send(sample)?;
        Ok(seq)
    }

    /// Sends `sample` with the caller's header untouched except `pub_time_ns`
    /// (replay of recorded logs, fault injection): `seq`, `generation`,
    /// `source_id` and even `layout_version` are the caller's, and this
    /// publisher's own sequence counter does not move. Returns the sample's seq.
    pub fn publish_raw(&mut self, sample: T) -> Result<u64, PublishError> {
        let seq = sample.header().seq;
        self.send_raw(sample)?;
        Ok(seq)
    }

    fn send(&mut self, sample: T) -> Result<(), PublishError> {
        let r = self.send_raw(sample);
        match &r {
            Ok(()) | Err(PublishError::Notify { .. }) => self.next_seq += 1,
            Err(_) => {}
        }
        r
    }

    fn send_raw(&mut self, mut sample: T) -> Result<(), PublishError> {
        let uninit = self
            .publisher
            .loan_uninit()
            .map_err(|source| PublishError::Loan {
                topic: self.topic.clone(),
                error: source,
            })?;
        sample.header_mut().pub_time_ns = monotonic_ns();
        uninit
            .write_payload(sample)
            .send()
            .map_err(|source| PublishError::Send {
                topic: self.topic.clone(),
                error: source,
            })?;
        self.published += 1;
        self.notifier
            .notify()
            .map_err(|source| PublishError::Notify {
                topic: self.topic.clone(),
                error: source,
            })?;
        Ok(())
    }

    /// Connects subscribers that joined since the last send and delivers them
    /// the history. Sending does this too; a publisher that may stay idle
    /// while late subscribers join (a logger restarting) should call it
    /// periodically, e.g. on its heartbeat tick.
    pub fn update_connections(&self) -> Result<(), PublishError> {
        self.publisher
            .update_connections()
            .map_err(|source| PublishError::Connect {
                topic: self.topic.clone(),
                error: source,
            })
    }

    /// Advances the sequence counter by `n` without sending: samples the stage
    /// decided not to publish (e.g. invalid inputs dropped) then show up
    /// downstream as a gap of `n`.
    pub fn skip_seq(&mut self, n: u64) {
        self.next_seq = self.next_seq.saturating_add(n);
    }

    /// The sequence number the next [`Pub::publish`] gives.
    #[must_use]
    pub fn next_seq(&self) -> u64 {
        self.next_seq
    }

    /// The generation this publisher stamps.
    #[must_use]
    pub fn generation(&self) -> u32 {
        self.generation
    }

    /// The source id this publisher stamps.
    #[must_use]
    pub fn source_id(&self) -> u16 {
        self.source_id
    }

    /// Stamps `id` as source id from now on (a stage publishing for several
    /// sensors on one topic uses one publisher per sensor).
    pub fn set_source_id(&mut self, id: u16) {
        self.source_id = id;
    }

    /// Samples sent so far (by [`Pub::publish`] and [`Pub::publish_raw`]).
    #[must_use]
    pub fn published(&self) -> u64 {
        self.published
    }

    /// The topic.
    #[must_use]
    pub fn topic(&self) -> &str {
        &self.topic
    }

    /// Subscribers currently registered on the topic (dead ones count until
    /// their node is cleaned up).
    #[must_use]
    pub fn subscriber_count(&self) -> usize {
        self.service.dynamic_config().number_of_subscribers()
    }
}

/// Counters of a [`Sub`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SubStats {
    /// Samples delivered to the caller.
    pub received: u64,
    /// Samples dropped for a layout version other than [`LAYOUT_VERSION`].
    pub dropped_version: u64,
    /// Samples missing: sequence numbers skipped within a (source, generation),
    /// plus the first `seq` samples of a new generation that were not seen.
    pub seq_gaps: u64,
    /// Samples whose seq did not advance within a (source, generation)
    /// (repeat or restart without a new generation); the tracker resyncs.
    pub seq_backwards: u64,
    /// New generations seen from a known source (publisher restarts).
    pub restarts: u64,
    /// Samples of an older generation than the newest seen from their source
    /// (delivered, not tracked).
    pub old_generation: u64,
    /// Sources forgotten because more than [`MAX_TRACKED_SOURCES`] were seen.
    pub sources_evicted: u64,
}

/// Sources (by `source_id`) a [`Sub`] tracks at once.
pub const MAX_TRACKED_SOURCES: usize = 16;

#[derive(Debug, Clone, Copy, Default)]
struct SourceTrack {
    used: bool,
    source_id: u16,
    generation: u32,
    next_seq: u64,
    last_used: u64,
}

/// Per-source sequence tracking in a fixed table (no allocation).
#[derive(Debug, Clone)]
pub(crate) struct SeqTracker {
    table: [SourceTrack; MAX_TRACKED_SOURCES],
    tick: u64,
}

impl Default for SeqTracker {
    fn default() -> Self {
        Self {
            table: [SourceTrack::default(); MAX_TRACKED_SOURCES],
            tick: 0,
        }
    }
}

impl SeqTracker {
    /// Accounts for one accepted sample with header `h`.
    pub(crate) fn observe(&mut self, h: &Header, st: &mut SubStats) {
        self.tick += 1;
        let tick = self.tick;
        if let Some(e) = self
            .table
            .iter_mut()
            .find(|e| e.used && e.source_id == h.source_id)
        {
            e.last_used = tick;
            if h.generation == e.generation {
                if h.seq > e.next_seq {
                    st.seq_gaps += h.seq - e.next_seq;
                } else if h.seq < e.next_seq {
                    st.seq_backwards += 1;
                }
                e.next_seq = h.seq.saturating_add(1);
            } else if h.generation > e.generation {
                st.restarts += 1;
                st.seq_gaps += h.seq;
                e.generation = h.generation;
                e.next_seq = h.seq.saturating_add(1);
            } else {
                st.old_generation += 1;
            }
            return;
        }
        // First sample of this source: we may have joined late, no gap counted.
        let slot = match self.table.iter().position(|e| !e.used) {
            Some(i) => i,
            None => {
                st.sources_evicted += 1;
                self.table
                    .iter()
                    .enumerate()
                    .min_by_key(|(_, e)| e.last_used)
                    .map_or(0, |(i, _)| i)
            }
        };
        if let Some(e) = self.table.get_mut(slot) {
            *e = SourceTrack {
                used: true,
                source_id: h.source_id,
                generation: h.generation,
                next_seq: h.seq.saturating_add(1),
                last_used: tick,
            };
        }
    }
}

/// A typed subscriber: copies samples out of shared memory, drops other
/// layout versions (counted) and tracks sequence gaps and restarts.
///
/// It is read through `&self`, so it can be read while a [`crate::Waiter`]
/// attachment borrows it (a `Sub` is neither `Send` nor `Sync`).
///
/// Reading until [`Sub::receive`] returns `None` (or calling [`Sub::drain`])
/// also consumes the wake-ups of the topic's listener, which a [`crate::Waiter`]
/// waits on: a stage woken for a subscriber must read it until empty, or the
/// waiter reports it again at once.
pub struct Sub<T>
where
    T: ZeroCopySend + Copy + Debug + HasHeader + 'static,
{
    topic: String,
    subscriber: Subscriber<crate::service::Ipc, T, ()>,
    pub(crate) listener: Listener<crate::service::Ipc>,
    _service: PsFactory<T>,
    _event: EvFactory,
    // Interior mutability: a Sub is read through `&self` so that it can be
    // read while a Waiter attachment borrows it.
    stats: Cell<SubStats>,
    tracker: Cell<SeqTracker>,
    last_header: Cell<Option<Header>>,
    last_receive_ns: Cell<Option<u64>>,
}

impl<T> Debug for Sub<T>
where
    T: ZeroCopySend + Copy + Debug + HasHeader + 'static,
{
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Sub")
            .field("topic", &self.topic)
            .field("stats", &self.stats.get())
            .field("last_header", &self.last_header.get())
            .finish_non_exhaustive()
    }
}

impl<T> Sub<T>
where
    T: ZeroCopySend + Copy + Debug + HasHeader + 'static,
{
    pub(crate) fn create(node: &Node<crate::service::Ipc>, topic: &str) -> Result<Self, PortError> {
        let q = for_topic(topic);
        let service = open_pubsub::<T>(node, topic)?;
        let event = open_event(node, topic)?;
        // Listener first: a sample sent after the subscriber exists then
        // always finds a listener to wake.
        let listener = event
            .listener_builder()
            .create()
            .map_err(|source| PortError::Listener {
                topic: topic.to_owned(),
                error: source,
            })?;
        let subscriber = service
            .subscriber_builder()
            .history_request(q.history_size)
            .create()
            .map_err(|source| PortError::Subscriber {
                topic: topic.to_owned(),
                error: source,
            })?;
        Ok(Self {
            topic: topic.to_owned(),
            subscriber,
            listener,
            _service: service,
            _event: event,
            stats: Cell::new(SubStats::default()),
            tracker: Cell::new(SeqTracker::default()),
            last_header: Cell::new(None),
            last_receive_ns: Cell::new(None),
        })
    }

    /// The next sample of the current layout version, copied out, or `None`
    /// when none is waiting. When the buffer is empty it consumes the
    /// listener's pending wake-ups and looks once more, so a sample sent in
    /// between is either returned now or still has its wake-up pending.
    pub fn receive(&self) -> Result<Option<T>, ReceiveError> {
        loop {
            let Some(sample) = self.next_raw()? else {
                return Ok(None);
            };
            let h = *sample.header();
            let mut st = self.stats.get();
            if h.layout_version != LAYOUT_VERSION {
                st.dropped_version += 1;
                self.stats.set(st);
                continue;
            }
            let mut tracker = self.tracker.take();
            tracker.observe(&h, &mut st);
            self.tracker.set(tracker);
            st.received += 1;
            self.stats.set(st);
            self.last_header.set(Some(h));
            self.last_receive_ns.set(Some(monotonic_ns()));
            return Ok(Some(sample));
        }
    }

    /// Calls `f` with every waiting sample (as [`Sub::receive`]); returns how many.
    pub fn drain(&self, mut f: impl FnMut(T)) -> Result<usize, ReceiveError> {
        let mut n = 0;
        while let Some(s) = self.receive()? {
            f(s);
            n += 1;
        }
        Ok(n)
    }

    fn take(&self) -> Result<Option<T>, ReceiveError> {
        self.subscriber
            .receive()
            .map(|o| o.map(|s| *s.payload()))
            .map_err(|source| ReceiveError::Receive {
                topic: self.topic.clone(),
                error: source,
            })
    }

    fn next_raw(&self) -> Result<Option<T>, ReceiveError> {
        if let Some(s) = self.take()? {
            return Ok(Some(s));
        }
        self.listener
            .try_wait(|_| {})
            .map_err(|source| ReceiveError::Listener {
                topic: self.topic.clone(),
                error: source,
            })?;
        self.take()
    }

    /// The counters so far.
    #[must_use]
    pub fn stats(&self) -> SubStats {
        self.stats.get()
    }

    /// Header of the last sample delivered.
    #[must_use]
    pub fn last_header(&self) -> Option<Header> {
        self.last_header.get()
    }

    /// [`monotonic_ns`] when the last sample was delivered.
    #[must_use]
    pub fn last_receive_ns(&self) -> Option<u64> {
        self.last_receive_ns.get()
    }

    /// Age of the input at `now_ns`: `now_ns` minus the publish time of the last
    /// sample delivered (the liveness measure: iceoryx2 still counts a killed
    /// publisher). `None` before the first sample.
    #[must_use]
    pub fn age_ns(&self, now_ns: u64) -> Option<u64> {
        self.last_header
            .get()
            .map(|h| now_ns.saturating_sub(h.pub_time_ns))
    }

    /// The topic.
    #[must_use]
    pub fn topic(&self) -> &str {
        &self.topic
    }

    /// Publishers currently registered on the topic (a killed one counts until
    /// its node is cleaned up: use [`Sub::age_ns`] for liveness).
    #[must_use]
    pub fn publisher_count(&self) -> usize {
        self._service.dynamic_config().number_of_publishers()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn h(source_id: u16, generation: u32, seq: u64) -> Header {
        Header {
            source_id,
            generation,
            seq,
            ..Header::new(seq, 0)
        }
    }

    #[test]
    fn tracker_counts_gaps_restarts_and_backwards() {
        let mut t = SeqTracker::default();
        let mut s = SubStats::default();
        // Late join at seq 10: no gap.
        t.observe(&h(1, 0, 10), &mut s);
        t.observe(&h(1, 0, 11), &mut s);
        assert_eq!(s, SubStats::default());
        // 12, 13 missing.
        t.observe(&h(1, 0, 14), &mut s);
        assert_eq!(s.seq_gaps, 2);
        // Another source interleaved does not disturb source 1.
        t.observe(&h(2, 3, 0), &mut s);
        t.observe(&h(1, 0, 15), &mut s);
        assert_eq!(s.seq_gaps, 2);
        // Restart of source 1 (generation 1), first sample seen is seq 1: one missed.
        t.observe(&h(1, 1, 1), &mut s);
        assert_eq!((s.restarts, s.seq_gaps), (1, 3));
        // Leftover of generation 0: delivered, counted, not tracked.
        t.observe(&h(1, 0, 16), &mut s);
        assert_eq!(s.old_generation, 1);
        t.observe(&h(1, 1, 2), &mut s);
        assert_eq!(s.seq_gaps, 3);
        // Repeat.
        t.observe(&h(1, 1, 2), &mut s);
        assert_eq!(s.seq_backwards, 1);
        t.observe(&h(1, 1, 3), &mut s);
        assert_eq!((s.seq_gaps, s.restarts), (3, 1));
    }

    #[test]
    fn tracker_evicts_least_recent_source_when_full() {
        let mut t = SeqTracker::default();
        let mut s = SubStats::default();
        for src in 0..MAX_TRACKED_SOURCES as u16 {
            t.observe(&h(src, 0, 0), &mut s);
        }
        // Touch source 0 so source 1 is the least recent.
        t.observe(&h(0, 0, 1), &mut s);
        t.observe(&h(100, 0, 0), &mut s);
        assert_eq!(s.sources_evicted, 1);
        // Source 0 is still tracked: a jump counts.
        t.observe(&h(0, 0, 5), &mut s);
        assert_eq!(s.seq_gaps, 3);
        // Source 1 was forgotten: it re-enters without a gap (evicting another).
        t.observe(&h(1, 0, 50), &mut s);
        assert_eq!((s.seq_gaps, s.sources_evicted), (3, 2));
    }
}
