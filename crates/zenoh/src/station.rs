//! The fleet's station over Zenoh (`insuwb fleet`): a session that listens
//! on (or connects to) explicit endpoints, subscribes to every robot's
//! poses and health (`insuwb/*/pose`, `insuwb/*/health`), stamps each
//! sample with its CLOCK_MONOTONIC receive time, and feeds the station's
//! model ([`insuwb_fleet::station::Station`]: status, rate, age, restarts,
//! new / lost / back), what reached it ([`insuwb_fleet::delivery`]: gaps in
//! the publishers' `seq`, delays) and, when recording, each robot's log
//! ([`insuwb_fleet::record`]). Every period it hands a
//! [`Snapshot`] to the caller, which prints it.
//!
//! - [`StationSettings`]: the `[station]` table (name, mode, endpoints,
//!   TLS, the robots' stamp clock, the lost / stale / rate thresholds, the
//!   most robots tracked),
//!   checked with the link's own rules ([`LinkConfig::validate`]), every
//!   error naming its key;
//! - [`FleetStation`]: the open station, [`FleetStation::run`] its loop.
//!
//! Samples arrive on Zenoh's threads; each is stamped and decoded there
//! and queued for the station's thread, which wakes for them and at least
//! every [`TICK`] (a robot silent for the lost time is found within a tick
//! of it) and stops on SIGINT/SIGTERM or at the end of its duration.
//!
//! What any peer puts is refused unless it is a fleet payload: a sample
//! whose key, encoding, attachment or bytes are not those of
//! [`crate::payload`] (random bytes, a wrong encoding, a payload over
//! [`crate::payload::MAX_PAYLOAD_BYTES`], JSON nested deeper than
//! `serde_json`'s limit) is counted invalid, and a robot beyond
//! `max_robots` is not tracked, its samples counted as excess. The first
//! invalid sample is logged and then one in a thousand; the first excess
//! one once.
//!
//! A station that listens is a router by default (robots and any other
//! subscriber connect to it, and it routes between them); one that only
//! connects (to a router of the site) is a peer.
//!
//! ```no_run
//! use insuwb_zenoh::station::{FleetStation, RunOptions, StationSettings};
//! let settings = StationSettings {
//!     listen: vec!["tcp/0.0.0.0:7447".into()],
//!     ..StationSettings::default()
//! };
//! let mut station = FleetStation::open(&settings, None)?;
//! station.run(&RunOptions::default(), &mut |snap| {
//!     println!("{}", insuwb_fleet::view::render_table(snap));
//!     Ok(())
//! })?;
//! station.finish()?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::path::Path;
use std::sync::mpsc::{self, Receiver, RecvTimeoutError};
use std::sync::Arc;
use std::time::Duration;

use insuwb_fleet::delivery::Delivery;
use insuwb_fleet::keys::Kind;
use insuwb_fleet::record::{FleetRecorder, RecordError, RobotRecording};
use insuwb_fleet::station::StageState;
use insuwb_fleet::station::{Event, Station, StationConfig, StationConfigError, MAX_ROBOTS_LIMIT};
use insuwb_fleet::view::Snapshot;
use insuwb_msg::{fixed_name, FusedState, Header, Health, HealthState};
use insuwb_report::clock::{ClockOffset, StampClock};
use insuwb_runtime::monotonic_ns;
use serde::{Deserialize, Serialize};
use zenoh::pubsub::Subscriber;
use zenoh::{Session, Wait};

use crate::config::{LinkConfig, Mode, TlsConfig};
use crate::identity::{IdentitySettings, Refusals};
use crate::payload::{DecodeError, HealthPayload, Meta, Payload, Pose, Received};
use crate::session::{self, SessionError};

/// The longest the station's thread sleeps: the lost time is checked this
/// often.
pub const TICK: Duration = Duration::from_millis(50);

/// The longest station name.
pub const MAX_NAME_LEN: usize = 64;

/// `[station]`: how the station reaches the fleet and what it calls lost.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StationSettings {
    /// The station's name, in its recordings' metadata (empty: the host
    /// name).
    pub name: String,
    /// The session's role: by default `router` when it listens, else
    /// `peer`.
    pub mode: Option<Mode>,
    /// Endpoints to connect to (a router of the site), `tcp/HOST:PORT` or
    /// `tls/HOST:PORT`.
    pub connect: Vec<String>,
    /// Endpoints to listen on (the robots connect there), e.g.
    /// `tcp/0.0.0.0:7447`.
    pub listen: Vec<String>,
    /// The certificates of the `tls/` endpoints (`[station.tls]`, the keys
    /// of `[zenoh.tls]`).
    pub tls: TlsConfig,
    /// Refuse to start with a plain `tcp/` endpoint off the loopback (by
    /// default such an endpoint is only warned about).
    pub require_tls: bool,
    /// The clock of the robots' stamps (their `[zenoh] stamp_clock`):
    /// `realtime` (default) or `monotonic` (robots on this machine); the
    /// delay of a pose is its receive time in this clock minus its stamp.
    pub stamp_clock: StampClock,
    /// A robot silent this long is lost, s (default 2).
    pub lost_after_s: f64,
    /// A robot whose last pose is this old is stale, s (default 0.5).
    pub stale_after_s: f64,
    /// The window of the pose rate, s (default 1).
    pub rate_window_s: f64,
    /// The most robots tracked (default 1000): the samples of any further
    /// robot id are dropped and counted as excess.
    pub max_robots: usize,
    /// Which robot may put under which keys (`[station.identity]`; none
    /// listed: any peer that connects may, as without it).
    pub identity: IdentitySettings,
}

impl Default for StationSettings {
    fn default() -> Self {
        let d = StationConfig::default();
        Self {
            name: String::new(),
            mode: None,
            connect: Vec::new(),
            listen: Vec::new(),
            tls: TlsConfig::default(),
            require_tls: false,
            stamp_clock: StampClock::Realtime,
            lost_after_s: d.lost_after_s,
            stale_after_s: d.stale_after_s,
            rate_window_s: d.rate_window_s,
            max_robots: d.max_robots,
            identity: IdentitySettings::default(),
        }
    }
}

/// A `[station]` key with a value the station cannot use.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("key 'station.{key}': {reason}")]
pub struct StationSettingsError {
    /// The key, without `station.` (`tls.certificate` for a key of
    /// `[station.tls]`).
    pub key: String,
    /// What is wrong, with the value.
    pub reason: String,
}

impl StationSettings {
    /// The session's role: `mode`, else `router` when it listens, else
    /// `peer`.
    #[must_use]
    pub fn mode(&self) -> Mode {
        self.mode.unwrap_or(if self.listen.is_empty() {
            Mode::Peer
        } else {
            Mode::Router
        })
    }

    /// How the session reaches the fleet.
    #[must_use]
    pub fn link(&self) -> LinkConfig {
        LinkConfig {
            mode: self.mode(),
            connect: self.connect.clone(),
            listen: self.listen.clone(),
            tls: self.tls.clone(),
            require_tls: self.require_tls,
        }
    }

    /// The thresholds of the station's model.
    #[must_use]
    pub fn station_config(&self) -> StationConfig {
        StationConfig {
            lost_after_s: self.lost_after_s,
            stale_after_s: self.stale_after_s,
            rate_window_s: self.rate_window_s,
            max_robots: self.max_robots,
        }
    }

    /// The station's name: `name`, else the host name, else `station`.
    #[must_use]
    pub fn station_name(&self) -> String {
        if !self.name.is_empty() {
            return self.name.clone();
        }
        std::fs::read_to_string("/proc/sys/kernel/hostname")
            .ok()
            .map(|h| h.trim().to_owned())
            .filter(|h| !h.is_empty())
            .unwrap_or_else(|| "station".to_owned())
    }

    /// Makes the certificate paths absolute under `base` (the folder of
    /// the config file).
    pub fn resolve_paths(&mut self, base: &Path) {
        self.tls.resolve_paths(base);
    }

    /// Checks every key (the link with [`LinkConfig::validate`]'s rules);
    /// the error names the first bad one.
    ///
    /// # Errors
    /// [`StationSettingsError`] naming the key.
    pub fn validate(&self) -> Result<(), StationSettingsError> {
        let bad = |key: &str, reason: String| {
            Err(StationSettingsError {
                key: key.to_owned(),
                reason,
            })
        };
        if self.name.chars().count() > MAX_NAME_LEN || self.name.chars().any(char::is_control) {
            return bad(
                "name",
                format!(
                    "{:?}: at most {MAX_NAME_LEN} characters, none a control character",
                    self.name
                ),
            );
        }
        if let Err(e) = self.link().validate() {
            return bad(e.key, e.reason);
        }
        if let Err(e) = self.identity.validate() {
            return bad(&format!("identity.{}", e.key), e.reason);
        }
        if self.identity.enabled() && self.mode() != Mode::Router {
            return bad(
                "identity",
                "binds identity at the station's router: the station must listen (mode router)"
                    .to_owned(),
            );
        }
        if self.connect.is_empty() && self.listen.is_empty() {
            return bad(
                "listen",
                "the station needs an endpoint to listen on (e.g. [\"tcp/0.0.0.0:7447\"]) or one to connect to".to_owned(),
            );
        }
        match self.station_config().validate() {
            Ok(()) => {}
            Err(StationConfigError::OutOfRange { key, value }) => {
                return bad(
                    key,
                    format!("must be finite and in (0, 3600] s, got {value}"),
                );
            }
            Err(StationConfigError::MaxRobots(n)) => {
                return bad(
                    "max_robots",
                    format!("must be in 1..={MAX_ROBOTS_LIMIT}, got {n}"),
                );
            }
        }
        Ok(())
    }
}

/// Opening the station failed.
#[derive(Debug, thiserror::Error)]
pub enum StationOpenError {
    /// A `[station]` key is invalid.
    #[error("StationOpenError::Settings: {0}")]
    Settings(#[from] StationSettingsError),
    /// The model's thresholds are invalid.
    #[error("StationOpenError::Model: {0}")]
    Model(#[from] StationConfigError),
    /// The Zenoh session.
    #[error("StationOpenError::Session: {0}")]
    Session(#[from] SessionError),
    /// A Zenoh subscriber.
    #[error("StationOpenError::Subscriber: {key}: {reason}")]
    Subscriber {
        /// Its key expression.
        key: String,
        /// Zenoh's error.
        reason: String,
    },
}

/// The station's loop ended with an error.
#[derive(Debug, thiserror::Error)]
pub enum StationRunError {
    /// Recording a robot failed.
    #[error("StationRunError::Record: {0}")]
    Record(#[from] RecordError),
    /// The caller's output of a snapshot failed.
    #[error("StationRunError::Output: {0}")]
    Output(#[from] std::io::Error),
}

/// How long the loop runs and how often it hands out a snapshot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RunOptions {
    /// A snapshot every period (default 1 s).
    pub period: Duration,
    /// Stop after this long (none: until SIGINT or SIGTERM).
    pub duration: Option<Duration>,
}

impl Default for RunOptions {
    fn default() -> Self {
        Self {
            period: Duration::from_secs(1),
            duration: None,
        }
    }
}

/// One sample as it arrived: receive time, its attachment's `seq`, the
/// decoded payload (or its key and why it is none).
struct Arrival {
    rx_ns: u64,
    seq: u64,
    sample: Result<Received, (String, DecodeError)>,
}

/// The heartbeat state of a stage's health record (none for a stage
/// that is down).
fn heartbeat_state(s: StageState) -> Option<HealthState> {
    match s {
        StageState::Ok => Some(HealthState::Ok),
        StageState::Degraded => Some(HealthState::Degraded),
        StageState::Disconnected => Some(HealthState::Disconnected),
        StageState::Stopping => Some(HealthState::Stopping),
        StageState::Down => None,
    }
}

/// The heartbeats a health report stands for, as a recording holds them:
/// one per stage that runs (a stage the robot reports down sent no
/// heartbeat, so it has none), with the stage's name, process id, state
/// and restarts (`header.generation`); the report's stamp as measurement
/// time, `rx_ns` (the station's receive time) as publish time, `seq` the
/// report's. The counters stay 0, of no stage kind: the report carries
/// rates, and the stage's own counters by name only.
#[must_use]
pub fn health_records(h: &HealthPayload, seq: u64, rx_ns: u64) -> Vec<Health> {
    h.stages
        .iter()
        .filter_map(|s| {
            let state = heartbeat_state(s.state)?;
            let mut header = Header::new(seq, h.stamp_ns);
            header.pub_time_ns = rx_ns;
            header.generation = u32::try_from(s.restarts).unwrap_or(u32::MAX);
            Some(Health {
                header,
                stage: fixed_name(&s.stage),
                pid: s.pid,
                state: state.into(),
                ..Health::default()
            })
        })
        .collect()
}

/// The fused state a pose stands for, as a recording holds it
/// ([`Pose::fused_state`] with the stamp kept as it is: the robot's stamp
/// clock), `rx_ns` (the station's receive time) as publish time.
///
/// # Errors
/// [`DecodeError::Convert`] for values no fused state holds.
pub fn recorded_fused(p: &Pose, rx_ns: u64) -> Result<FusedState, DecodeError> {
    let mut s = p.fused_state(&ClockOffset::ZERO)?;
    s.header.pub_time_ns = rx_ns;
    Ok(s)
}

/// The open station: its session and subscribers, its model, what reached
/// it, its recording.
pub struct FleetStation {
    station: Station,
    delivery: Delivery,
    recorder: Option<FleetRecorder>,
    arrivals: Receiver<Arrival>,
    stamp_clock: StampClock,
    clock: ClockOffset,
    lost_after_s: f64,
    started_ns: u64,
    /// The events since the last snapshot.
    events: Vec<Event>,
    /// The access control's refusals, where a [`crate::identity::RefusalLayer`]
    /// counts them.
    refusals: Option<Arc<Refusals>>,
    // Fields drop in order: the subscribers before the session.
    _subscribers: Vec<Subscriber<()>>,
    _session: Session,
}

impl std::fmt::Debug for FleetStation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FleetStation")
            .field("robots", &self.station.len())
            .field("delivery", &self.delivery.summary())
            .field("recording", &self.recorder.as_ref().map(FleetRecorder::dir))
            .finish_non_exhaustive()
    }
}

/// Decodes a sample on Zenoh's thread.
fn arrival(sample: &zenoh::sample::Sample) -> Arrival {
    let rx_ns = monotonic_ns();
    let attachment = sample.attachment().map(|a| a.to_bytes());
    let seq = Meta::from_attachment(attachment.as_deref()).map_or(0, |m| m.seq);
    Arrival {
        rx_ns,
        seq,
        sample: session::decode_sample(sample)
            .map_err(|e| (sample.key_expr().as_str().to_owned(), e)),
    }
}

impl FleetStation {
    /// Checks the settings, opens the session ([`session::open`]) and
    /// subscribes to every robot's poses and health; records into
    /// `recorder` when given.
    ///
    /// # Errors
    /// [`StationOpenError`] naming what could not be opened.
    pub fn open(
        settings: &StationSettings,
        recorder: Option<FleetRecorder>,
    ) -> Result<Self, StationOpenError> {
        settings.validate()?;
        let station = Station::new(settings.station_config())?;
        let link = settings.link();
        let acl = settings
            .identity
            .enabled()
            .then(|| settings.identity.access_control_json());
        let session = session::open_with_access_control(&link, acl.as_ref())?;
        let (tx, arrivals) = mpsc::channel();
        let subscribers = insuwb_runtime::signal::with_signals_blocked(|| {
            [Kind::Pose, Kind::Health]
                .into_iter()
                .map(|kind| {
                    let key = kind.subscription();
                    let tx = tx.clone();
                    session
                        .declare_subscriber(key.clone())
                        .callback(move |sample| {
                            // The station's end is gone only when it stops.
                            let _ = tx.send(arrival(&sample));
                        })
                        .wait()
                        .map_err(|e| StationOpenError::Subscriber {
                            key,
                            reason: e.to_string(),
                        })
                })
                .collect::<Result<Vec<_>, _>>()
        })?;
        if settings.identity.enabled() {
            tracing::info!(
                "station: identity bound to the certificate: {:?} each put only under insuwb/<its id>/**{}; any other peer is refused",
                settings.identity.robots,
                if settings.identity.loopback_robots.is_empty() {
                    String::new()
                } else {
                    format!(
                        ", {:?} without TLS over plain TCP on the loopback",
                        settings.identity.loopback_robots
                    )
                }
            );
        }
        tracing::info!(
            "station: Zenoh {} session, listen {:?}, connect {:?}; subscribed to {} and {}{}",
            link.mode.name(),
            link.listen,
            link.connect,
            Kind::Pose.subscription(),
            Kind::Health.subscription(),
            recorder
                .as_ref()
                .map(|r| format!("; recording into {}", r.dir().display()))
                .unwrap_or_default()
        );
        Ok(Self {
            station,
            delivery: Delivery::default(),
            recorder,
            arrivals,
            stamp_clock: settings.stamp_clock,
            clock: ClockOffset::measure(settings.stamp_clock),
            lost_after_s: settings.lost_after_s,
            started_ns: monotonic_ns(),
            events: Vec::new(),
            refusals: None,
            _subscribers: subscribers,
            _session: session,
        })
    }

    /// Counts the access control's refusals from `refusals` (fed by a
    /// [`crate::identity::RefusalLayer`] in the process's `tracing`
    /// subscriber): the snapshots' `delivery.refused`, and one log line
    /// per robot and key refused.
    #[must_use]
    pub fn with_refusals(mut self, refusals: Arc<Refusals>) -> Self {
        self.refusals = Some(refusals);
        self
    }

    /// The station's model.
    #[must_use]
    pub fn station(&self) -> &Station {
        &self.station
    }

    /// What reached the station.
    #[must_use]
    pub fn delivery(&self) -> &Delivery {
        &self.delivery
    }

    fn note(&mut self, ev: Option<Event>) {
        let Some(ev) = ev else { return };
        match &ev {
            Event::New { robot, .. } => tracing::info!("robot {robot}: new"),
            Event::Back { robot, .. } => tracing::info!("robot {robot}: back"),
            Event::Lost { robot, .. } => tracing::warn!(
                "robot {robot}: lost (nothing heard for {} s)",
                self.lost_after_s
            ),
        }
        self.events.push(ev);
    }

    /// Whether `robot` is beyond the cap of robots tracked (its sample
    /// was counted as excess by the model and goes nowhere else); the
    /// first such sample is logged.
    fn beyond_cap(&self, robot: &str) -> bool {
        if self.station.tracks(robot) {
            return false;
        }
        if self.station.excess() == 1 {
            tracing::warn!(
                "robot {robot}: not tracked, the station tracks {} robots already \
                 (max_robots); the samples of further robots are counted as excess \
                 (logged once)",
                self.station.max_robots()
            );
        }
        true
    }

    /// Takes one arrival into the model, the delivery counts and the
    /// recording.
    fn take(&mut self, a: Arrival) -> Result<(), RecordError> {
        let Arrival { rx_ns, seq, sample } = a;
        let received = match sample {
            Ok(r) => r,
            Err((key, e)) => {
                self.delivery.on_invalid();
                let n = self.delivery.summary().invalid;
                // The first and then one in a thousand.
                if n % 1000 == 1 {
                    tracing::warn!("{key}: not a fleet payload ({n} so far): {e}");
                }
                return Ok(());
            }
        };
        let robot = received.key.robot();
        match &received.payload {
            Payload::Pose(p) => {
                let sample = p.sample();
                let rx_stamp = i128::from(rx_ns) + i128::from(self.clock.offset_ns);
                let delay = rx_stamp - i128::from(sample.stamp_ns);
                let delay_ns =
                    i64::try_from(delay).unwrap_or(if delay < 0 { i64::MIN } else { i64::MAX });
                let ev = self.station.on_pose(robot, sample, rx_ns);
                if self.beyond_cap(robot) {
                    return Ok(());
                }
                self.note(ev);
                self.delivery.on_pose(robot, p.meta.seq, delay_ns);
                if let Some(rec) = &mut self.recorder {
                    match recorded_fused(p, rx_ns) {
                        Ok(s) => rec.fused(robot, &s, rx_ns)?,
                        Err(e) => tracing::debug!("{robot}: pose {} not recorded: {e}", p.meta.seq),
                    }
                }
            }
            Payload::Health(h) => {
                let ev = self.station.on_health(robot, h.sample(), rx_ns);
                if self.beyond_cap(robot) {
                    return Ok(());
                }
                self.note(ev);
                self.delivery.on_health(robot, seq);
                if let Some(rec) = &mut self.recorder {
                    for beat in health_records(h, seq, rx_ns) {
                        rec.health(robot, &beat, rx_ns)?;
                    }
                }
            }
            // Not subscribed to.
            Payload::Fix(_) | Payload::Diag(_) => {}
        }
        Ok(())
    }

    /// Takes what arrives until `until_ns` (CLOCK_MONOTONIC), returning
    /// early on SIGINT/SIGTERM (once `insuwb_runtime::signal::install`
    /// ran).
    ///
    /// # Errors
    /// [`RecordError`] when recording fails.
    pub fn pump(&mut self, until_ns: u64) -> Result<(), RecordError> {
        loop {
            let now = monotonic_ns();
            if now >= until_ns || insuwb_runtime::signal::termination_requested() {
                return Ok(());
            }
            let wait = Duration::from_nanos(until_ns - now).min(TICK);
            match self.arrivals.recv_timeout(wait) {
                Ok(a) => self.take(a)?,
                Err(RecvTimeoutError::Timeout) => {}
                // The subscribers hold the senders while the station is open.
                Err(RecvTimeoutError::Disconnected) => return Ok(()),
            }
        }
    }

    /// Finds the robots silent for the lost time at `now_ns` (their lost
    /// events) and applies the recording's flush policy.
    ///
    /// # Errors
    /// [`RecordError`] when a flush fails.
    pub fn tick(&mut self, now_ns: u64) -> Result<(), RecordError> {
        if let Some(r) = &self.refusals {
            for refusal in r.take_fresh() {
                tracing::warn!("station: {refusal}");
            }
        }
        for ev in self.station.tick(now_ns) {
            self.note(Some(ev));
        }
        if let Some(rec) = &mut self.recorder {
            rec.tick(now_ns)?;
        }
        Ok(())
    }

    /// The fleet at `now_ns`, with the events since the previous snapshot.
    pub fn snapshot(&mut self, now_ns: u64) -> Snapshot {
        let t_s = now_ns.saturating_sub(self.started_ns) as f64 * 1e-9;
        let events = std::mem::take(&mut self.events);
        let mut snap = Snapshot::new(t_s, now_ns, &self.station, &self.delivery, events);
        snap.delivery.refused = self.refusals.as_ref().map_or(0, |r| r.total());
        snap
    }

    /// Runs until SIGINT/SIGTERM (once `insuwb_runtime::signal::install`
    /// ran) or the end of `opts.duration`: takes every sample as it
    /// arrives, checks for lost robots every [`TICK`], hands a snapshot to
    /// `out` every `opts.period` and once more at the end.
    ///
    /// # Errors
    /// [`StationRunError`]: recording or `out` failed.
    pub fn run(
        &mut self,
        opts: &RunOptions,
        out: &mut dyn FnMut(&Snapshot) -> std::io::Result<()>,
    ) -> Result<(), StationRunError> {
        let ns = |d: Duration| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX);
        let start = monotonic_ns();
        let end = opts.duration.map(|d| start.saturating_add(ns(d)));
        let period = ns(opts.period).max(1);
        let tick = ns(TICK);
        let mut next_tick = start.saturating_add(tick);
        let mut next_snap = start.saturating_add(period);
        loop {
            let until = next_tick.min(next_snap).min(end.unwrap_or(u64::MAX));
            self.pump(until)?;
            let now = monotonic_ns();
            if insuwb_runtime::signal::termination_requested() || end.is_some_and(|e| now >= e) {
                break;
            }
            if now >= next_tick {
                self.tick(now)?;
                next_tick = now.saturating_add(tick);
            }
            if now >= next_snap {
                self.clock = ClockOffset::measure(self.stamp_clock);
                out(&self.snapshot(now))?;
                next_snap = next_snap.saturating_add(period);
                if next_snap <= now {
                    next_snap = now.saturating_add(period);
                }
            }
        }
        let now = monotonic_ns();
        self.tick(now)?;
        out(&self.snapshot(now))?;
        Ok(())
    }

    /// Closes the recording and the session: what was recorded of each
    /// robot (none without a recording).
    ///
    /// # Errors
    /// [`RecordError`] when a robot's log cannot be closed.
    pub fn finish(self) -> Result<Vec<RobotRecording>, RecordError> {
        let s = self.delivery.summary();
        tracing::info!(
            "station: {} robots, {} poses and {} health samples received, {} lost on the way, {} invalid, {} of robots beyond max_robots, {} refused by the access control",
            self.station.len(),
            s.poses,
            s.health,
            s.gaps,
            s.invalid,
            self.station.excess(),
            self.refusals.as_ref().map_or(0, |r| r.total())
        );
        match self.recorder {
            Some(r) => r.finish(),
            None => Ok(Vec::new()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::payload::{encode_pose, StagePayload, VERSION};
    use insuwb_msg::FusedState;

    #[test]
    fn settings_default_to_a_router_when_listening_and_name_their_keys() {
        let s = StationSettings {
            listen: vec!["tcp/127.0.0.1:7447".into()],
            ..StationSettings::default()
        };
        s.validate().unwrap();
        assert_eq!(s.mode(), Mode::Router);
        let c = StationSettings {
            connect: vec!["tcp/127.0.0.1:7447".into()],
            ..StationSettings::default()
        };
        assert_eq!(c.link().mode, Mode::Peer);
        assert_eq!(
            StationSettings {
                mode: Some(Mode::Client),
                ..c.clone()
            }
            .mode(),
            Mode::Client
        );
        for (key, bad) in [
            ("listen", StationSettings::default()),
            (
                "connect",
                StationSettings {
                    connect: vec!["udp/1.2.3.4:7447".into()],
                    ..StationSettings::default()
                },
            ),
            (
                "tls.root_ca_certificate",
                StationSettings {
                    listen: vec!["tls/127.0.0.1:7447".into()],
                    ..StationSettings::default()
                },
            ),
            (
                "lost_after_s",
                StationSettings {
                    lost_after_s: 0.0,
                    ..c.clone()
                },
            ),
            (
                "name",
                StationSettings {
                    name: "a\nb".into(),
                    ..c.clone()
                },
            ),
            (
                "max_robots",
                StationSettings {
                    max_robots: 0,
                    ..c.clone()
                },
            ),
        ] {
            let e = bad.validate().unwrap_err();
            assert_eq!(e.key, key, "{e}");
            assert!(
                e.to_string().starts_with(&format!("key 'station.{key}': ")),
                "{e}"
            );
        }
        assert!(!c.station_name().is_empty());
        assert_eq!(
            StationSettings {
                name: "hq".into(),
                ..c
            }
            .station_name(),
            "hq"
        );
    }

    #[test]
    fn the_table_reads_from_toml_and_refuses_unknown_keys() {
        let t: toml::Table = toml::from_str(
            "[station]\nlisten = [\"tcp/0.0.0.0:7447\"]\nstamp_clock = \"monotonic\"\nlost_after_s = 3.0\nmax_robots = 50\n[station.tls]\nmutual = true\n",
        )
        .unwrap();
        let s: StationSettings = t["station"].clone().try_into().unwrap();
        assert_eq!(
            (s.stamp_clock, s.lost_after_s, s.station_config().max_robots),
            (StampClock::Monotonic, 3.0, 50)
        );
        assert_eq!(StationSettings::default().max_robots, 1000);
        assert!(toml::from_str::<StationSettings>("scouting = true").is_err());
    }

    #[test]
    fn a_health_report_is_one_heartbeat_per_running_stage() {
        let stage = |name: &str, state, restarts| StagePayload {
            stage: name.into(),
            state,
            condition: String::new(),
            restarts,
            pid: 7,
            heartbeat_age_s: None,
            received_rate_hz: None,
            published_rate_hz: None,
            counters: std::collections::BTreeMap::new(),
        };
        let h = HealthPayload {
            version: VERSION,
            robot: "r1".into(),
            stamp_ns: 123,
            stages: vec![
                stage("imu", StageState::Ok, 2),
                stage("fusion", StageState::Degraded, 0),
                stage("logger", StageState::Down, 0),
            ],
        };
        let beats = health_records(&h, 4, 999);
        assert_eq!(beats.len(), 2, "the stage that is down sent no heartbeat");
        assert_eq!(insuwb_msg::name_str(&beats[0].stage), "imu");
        assert_eq!((beats[0].header.generation, beats[0].pid), (2, 7));
        assert_eq!(beats[1].state(), Ok(HealthState::Degraded));
        let hd = beats[1].header;
        assert_eq!((hd.seq, hd.meas_time_ns, hd.pub_time_ns), (4, 123, 999));
    }

    #[test]
    fn a_recorded_pose_keeps_its_stamp_and_takes_the_receive_time() {
        let mut s = FusedState {
            header: Header::new(3, 2_000_000_000),
            quat: [1.0, 0.0, 0.0, 0.0],
            pos_m: [1.0, 2.0, 0.5],
            ..FusedState::default()
        };
        s.header.flags = FusedState::FLAG_VALID;
        let (bytes, meta) = encode_pose(&s, 17, &ClockOffset { offset_ns: 1_000 }).unwrap();
        let p = Pose::decode(&bytes, Some(&meta.to_attachment())).unwrap();
        let r = recorded_fused(&p, 55).unwrap();
        assert_eq!(r.header.meas_time_ns, 2_000_001_000, "the stamp as sent");
        assert_eq!((r.header.pub_time_ns, r.header.seq), (55, 17));
        assert_eq!((r.pos_m, r.header.flags), (s.pos_m, FusedState::FLAG_VALID));
    }
}
