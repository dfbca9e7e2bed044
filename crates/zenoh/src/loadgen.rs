//! A load generator for the fleet's station (`insuwb bench fleet`): N
//! simulated robots, each with a Zenoh session of its own connected to the
//! station's endpoint (as N robots' bridges would be), publishing a pose
//! at `rate_hz` and a health report every `health_period_s` with the
//! bridge's keys, payloads, attachments and congestion control
//! ([`crate::payload`]).
//!
//! The robots' poses are spread evenly over each period (robot `i` of `N`
//! publishes `i / N` of a period after robot 0), as robots that started at
//! different times would. Each pose is stamped with CLOCK_MONOTONIC just
//! before it is encoded and put (`stamp_clock = "monotonic"`), so a station
//! on the same machine measures its delivery delay from the stamp; the
//! attachment's `seq` counts each robot's poses from 0, so it counts what
//! was lost.
//!
//! [`LoadFleet::open`] opens every session and waits until every robot's
//! pose publisher sees the station's subscriber (Zenoh drops what is put
//! before), [`LoadFleet::run`] publishes.
//!
//! ```no_run
//! use std::time::Duration;
//! use insuwb_zenoh::loadgen::{LoadFleet, LoadSpec};
//! let spec = LoadSpec { endpoint: "tcp/127.0.0.1:7447".into(), robots: 100, ..LoadSpec::default() };
//! let mut fleet = LoadFleet::open(&spec)?;
//! let report = fleet.run(Duration::from_secs(10), &|| false);
//! println!("{} poses put, {} failed", report.poses, report.put_failures);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::collections::BTreeMap;
use std::time::Duration;

use insuwb_fleet::delivery::DelayHistogram;
use insuwb_fleet::keys::{Key, Kind};
use insuwb_fleet::station::StageState;
use insuwb_msg::{FusedState, Header, StageRole};
use insuwb_report::clock::ClockOffset;
use insuwb_runtime::monotonic_ns;
use serde::Serialize;
use zenoh::pubsub::Publisher;
use zenoh::qos::CongestionControl;
use zenoh::{Session, Wait};

use crate::config::{check_endpoint, LinkConfig, Mode, ZenohConfigError};
use crate::payload::{self, HealthPayload, Meta, StagePayload, VERSION};
use crate::session::{self, SessionError};

/// The most robots one generator plays.
pub const MAX_ROBOTS: usize = 10_000;

/// What to play.
#[derive(Debug, Clone, PartialEq)]
pub struct LoadSpec {
    /// The station's endpoint, `tcp/HOST:PORT`.
    pub endpoint: String,
    /// Robots, 1 to [`MAX_ROBOTS`].
    pub robots: usize,
    /// Poses per second of each robot (default 10).
    pub rate_hz: f64,
    /// Period of each robot's health report, s (default 1).
    pub health_period_s: f64,
    /// The robots' ids: this prefix and a number from 0 (`sim0000`, ...).
    pub prefix: String,
    /// How long [`LoadFleet::open`] waits for every robot to see the
    /// station.
    pub match_timeout: Duration,
}

impl Default for LoadSpec {
    fn default() -> Self {
        Self {
            endpoint: String::new(),
            robots: 10,
            rate_hz: 10.0,
            health_period_s: 1.0,
            prefix: "sim".to_owned(),
            match_timeout: Duration::from_secs(60),
        }
    }
}

/// Opening the simulated robots failed.
#[derive(Debug, thiserror::Error)]
pub enum LoadOpenError {
    /// A value of the [`LoadSpec`] is out of range.
    #[error("LoadOpenError::Spec: {0}")]
    Spec(String),
    /// The endpoint is not one.
    #[error("LoadOpenError::Endpoint: {0}")]
    Endpoint(#[from] ZenohConfigError),
    /// A robot's session.
    #[error("LoadOpenError::Session: robot {robot}: {error}")]
    Session {
        /// The robot.
        robot: String,
        /// Why.
        error: SessionError,
    },
    /// A Zenoh publisher.
    #[error("LoadOpenError::Publisher: {key}: {reason}")]
    Publisher {
        /// Its key.
        key: String,
        /// Zenoh's error.
        reason: String,
    },
    /// Robots whose pose publisher never saw the station's subscriber.
    #[error("LoadOpenError::NotMatched: {unmatched} of {robots} robots saw no subscriber of their poses within {waited_s:.1} s")]
    NotMatched {
        /// Robots that saw none.
        unmatched: usize,
        /// Robots.
        robots: usize,
        /// How long it waited, s.
        waited_s: f64,
    },
}

/// What a run published.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LoadReport {
    /// Robots played.
    pub robots: usize,
    /// Seconds it published.
    pub seconds: f64,
    /// Poses put.
    pub poses: u64,
    /// Health reports put.
    pub health: u64,
    /// Puts Zenoh refused.
    pub put_failures: u64,
    /// How late the puts were against their schedule: median, us.
    pub late_p50_us: f64,
    /// Same, 99th percentile, us.
    pub late_p99_us: f64,
    /// Poses put per robot.
    #[serde(skip)]
    pub per_robot: BTreeMap<String, u64>,
}

/// One simulated robot: its session and publishers.
struct SimRobot {
    id: String,
    pose_seq: u64,
    health_seq: u64,
    // Fields drop in order: the publishers before the session.
    pose: Publisher<'static>,
    health: Publisher<'static>,
    _session: Session,
}

/// The open simulated robots.
pub struct LoadFleet {
    spec: LoadSpec,
    robots: Vec<SimRobot>,
}

impl std::fmt::Debug for LoadFleet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LoadFleet")
            .field("spec", &self.spec)
            .field("robots", &self.robots.len())
            .finish()
    }
}

fn publisher(session: &Session, key: &Key) -> Result<Publisher<'static>, LoadOpenError> {
    let k = key.to_string();
    session
        .declare_publisher(k.clone())
        .encoding(payload::encoding(key.kind()))
        .congestion_control(CongestionControl::Drop)
        .wait()
        .map_err(|e| LoadOpenError::Publisher {
            key: k,
            reason: e.to_string(),
        })
}

/// Robot `i`'s fused state at `t_ns` (CLOCK_MONOTONIC): a circle of 2 m
/// about its own place on a 5 m grid, half a radian per second.
fn pose_at(i: usize, seq: u64, t_ns: u64) -> FusedState {
    let w = 0.5;
    let a = t_ns as f64 * 1e-9 * w + i as f64;
    let c = [(i % 25) as f64 * 5.0, (i / 25) as f64 * 5.0];
    let yaw = a + std::f64::consts::FRAC_PI_2;
    let mut s = FusedState {
        header: Header::new(seq, t_ns),
        pos_m: [c[0] + 2.0 * a.cos(), c[1] + 2.0 * a.sin(), 0.5],
        vel_mps: [-2.0 * w * a.sin(), 2.0 * w * a.cos(), 0.0],
        quat: [(yaw / 2.0).cos(), 0.0, 0.0, (yaw / 2.0).sin()],
        yaw_rad: yaw,
        ..FusedState::default()
    };
    s.header.flags = FusedState::FLAG_VALID;
    for k in 0..6 {
        s.cov[k][k] = if k < 3 { 0.01 } else { 0.0025 };
    }
    s
}

/// A health report of every stage OK.
fn health_at(robot: &str, t_ns: u64) -> HealthPayload {
    let stage = |name: &str| StagePayload {
        stage: name.to_owned(),
        state: StageState::Ok,
        condition: "ok".to_owned(),
        restarts: 0,
        pid: 0,
        heartbeat_age_s: Some(0.1),
        received_rate_hz: Some(100.0),
        published_rate_hz: Some(100.0),
        counters: std::collections::BTreeMap::new(),
    };
    HealthPayload {
        version: VERSION,
        robot: robot.to_owned(),
        stamp_ns: t_ns,
        stages: StageRole::DEFAULT
            .into_iter()
            .chain([StageRole::Zenoh])
            .map(|role| stage(role.name()))
            .collect(),
    }
}

impl LoadFleet {
    /// Opens a session per robot (a peer connecting to the endpoint), its
    /// pose and health publishers, and waits until every pose publisher
    /// sees a subscriber.
    ///
    /// # Errors
    /// [`LoadOpenError`].
    pub fn open(spec: &LoadSpec) -> Result<Self, LoadOpenError> {
        check_endpoint("connect", &spec.endpoint)?;
        if !(1..=MAX_ROBOTS).contains(&spec.robots) {
            return Err(LoadOpenError::Spec(format!(
                "robots must be 1 to {MAX_ROBOTS}, got {}",
                spec.robots
            )));
        }
        for (what, v) in [
            ("rate_hz", spec.rate_hz),
            ("health_period_s", spec.health_period_s),
        ] {
            if !(v.is_finite() && v > 0.0 && v <= 1000.0) {
                return Err(LoadOpenError::Spec(format!(
                    "{what} must be in (0, 1000], got {v}"
                )));
            }
        }
        let link = LinkConfig {
            mode: Mode::Peer,
            connect: vec![spec.endpoint.clone()],
            ..LinkConfig::default()
        };
        let robot0 = || format!("{}0000", spec.prefix);
        let mut config = session::zenoh_config(&link).map_err(|error| LoadOpenError::Session {
            robot: robot0(),
            error,
        })?;
        // A peer's open waits up to the scouting delay (0.5 s) for start
        // conditions a router never signals: 500 robots would take 250 s
        // to open. Readiness is the publishers' matching, below.
        config
            .insert_json5("open/return_conditions/connect_scouted", "false")
            .map_err(|e| LoadOpenError::Session {
                robot: robot0(),
                error: SessionError::ZenohConfig {
                    key: "open/return_conditions/connect_scouted",
                    reason: e.to_string(),
                },
            })?;
        let mut robots = Vec::with_capacity(spec.robots);
        for i in 0..spec.robots {
            let id = format!("{}{i:04}", spec.prefix);
            let key =
                |kind| Key::new(&id, kind).map_err(|e| LoadOpenError::Spec(format!("prefix: {e}")));
            let (pose_key, health_key) = (key(Kind::Pose)?, key(Kind::Health)?);
            let session =
                insuwb_runtime::signal::with_signals_blocked(|| zenoh::open(config.clone()).wait())
                    .map_err(|e| LoadOpenError::Session {
                        robot: id.clone(),
                        error: SessionError::Open(e.to_string()),
                    })?;
            let (pose, health) = insuwb_runtime::signal::with_signals_blocked(|| {
                Ok::<_, LoadOpenError>((
                    publisher(&session, &pose_key)?,
                    publisher(&session, &health_key)?,
                ))
            })?;
            robots.push(SimRobot {
                id,
                pose_seq: 0,
                health_seq: 0,
                pose,
                health,
                _session: session,
            });
        }
        let fleet = Self {
            spec: spec.clone(),
            robots,
        };
        fleet.wait_matched()?;
        Ok(fleet)
    }

    /// Waits until every pose publisher sees a subscriber.
    fn wait_matched(&self) -> Result<(), LoadOpenError> {
        let t0 = std::time::Instant::now();
        let mut pending: Vec<&SimRobot> = self.robots.iter().collect();
        loop {
            pending.retain(|r| !r.pose.matching_status().wait().is_ok_and(|m| m.matching()));
            if pending.is_empty() {
                return Ok(());
            }
            if t0.elapsed() >= self.spec.match_timeout {
                return Err(LoadOpenError::NotMatched {
                    unmatched: pending.len(),
                    robots: self.robots.len(),
                    waited_s: t0.elapsed().as_secs_f64(),
                });
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Robots played.
    #[must_use]
    pub fn len(&self) -> usize {
        self.robots.len()
    }

    /// Whether it plays no robot (never: [`LoadFleet::open`] refuses 0).
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.robots.is_empty()
    }

    /// Publishes for `duration` (or until `stop` says so, asked before each
    /// put): each robot's poses at `rate_hz`, spread over the period, and a
    /// health report with every `health_period_s`-th of them.
    pub fn run(&mut self, duration: Duration, stop: &dyn Fn() -> bool) -> LoadReport {
        let n = self.robots.len().max(1) as u64;
        let slot_ns = ((1e9 / self.spec.rate_hz) / n as f64).max(1.0);
        let health_every = (self.spec.health_period_s * self.spec.rate_hz)
            .round()
            .max(1.0) as u64;
        let t0 = monotonic_ns();
        let end = t0.saturating_add(u64::try_from(duration.as_nanos()).unwrap_or(u64::MAX));
        let mut late = DelayHistogram::default();
        let (mut poses, mut health, mut failures) = (0u64, 0u64, 0u64);
        let mut slot: u64 = 0;
        loop {
            let due = t0.saturating_add((slot as f64 * slot_ns) as u64);
            if due >= end || stop() {
                break;
            }
            let mut now = monotonic_ns();
            while now < due {
                std::thread::sleep(Duration::from_nanos(due - now));
                now = monotonic_ns();
            }
            late.record(now - due);
            let i = (slot % n) as usize;
            let round = slot / n;
            slot += 1;
            let Some(r) = self.robots.get_mut(i) else {
                continue;
            };
            let s = pose_at(i, r.pose_seq, monotonic_ns());
            if let Ok((bytes, meta)) = payload::encode_pose(&s, r.pose_seq, &ClockOffset::ZERO) {
                r.pose_seq += 1;
                match r.pose.put(bytes).attachment(meta.to_attachment()).wait() {
                    Ok(()) => poses += 1,
                    Err(_) => failures += 1,
                }
            }
            if round.is_multiple_of(health_every) {
                if let Ok(bytes) = health_at(&r.id, monotonic_ns()).encode() {
                    let meta = Meta::new(r.health_seq, 0);
                    r.health_seq += 1;
                    match r.health.put(bytes).attachment(meta.to_attachment()).wait() {
                        Ok(()) => health += 1,
                        Err(_) => failures += 1,
                    }
                }
            }
        }
        let us = |v: Option<u64>| v.map_or(0.0, |ns| ns as f64 * 1e-3);
        LoadReport {
            robots: self.robots.len(),
            seconds: monotonic_ns().saturating_sub(t0) as f64 * 1e-9,
            poses,
            health,
            put_failures: failures,
            late_p50_us: us(late.quantile(0.5)),
            late_p99_us: us(late.quantile(0.99)),
            per_robot: self
                .robots
                .iter()
                .map(|r| (r.id.clone(), r.pose_seq))
                .collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn poses_are_valid_rotations_on_each_robots_circle() {
        for i in [0usize, 7, 499] {
            let s = pose_at(i, 3, 1_234_567_890);
            let (bytes, meta) = payload::encode_pose(&s, 3, &ClockOffset::ZERO).unwrap();
            let p = payload::Pose::decode(&bytes, Some(&meta.to_attachment())).unwrap();
            let c = [(i % 25) as f64 * 5.0, (i / 25) as f64 * 5.0];
            let got = p.sample();
            let r = (got.pos_m[0] - c[0]).hypot(got.pos_m[1] - c[1]);
            assert!((r - 2.0).abs() < 1e-9, "{r}");
            assert_eq!(got.stamp_ns, 1_234_567_890);
            assert_eq!(p.meta.seq, 3);
        }
        let h = health_at("sim0001", 5);
        let back =
            HealthPayload::decode(&h.encode().unwrap(), Some(&Meta::new(0, 0).to_attachment()))
                .unwrap();
        assert_eq!(back.stages.len(), 6);
    }

    #[test]
    fn bad_specs_are_refused_before_anything_opens() {
        let spec = LoadSpec {
            endpoint: "tcp/127.0.0.1:1".into(),
            ..LoadSpec::default()
        };
        for (bad, what) in [
            (
                LoadSpec {
                    robots: 0,
                    ..spec.clone()
                },
                "robots",
            ),
            (
                LoadSpec {
                    rate_hz: 0.0,
                    ..spec.clone()
                },
                "rate_hz",
            ),
            (
                LoadSpec {
                    health_period_s: f64::NAN,
                    ..spec.clone()
                },
                "health_period_s",
            ),
            (
                LoadSpec {
                    endpoint: "udp/1.2.3.4:5".into(),
                    ..spec.clone()
                },
                "udp",
            ),
            (
                LoadSpec {
                    prefix: "a/b".into(),
                    ..spec.clone()
                },
                "prefix",
            ),
        ] {
            let e = LoadFleet::open(&bad).unwrap_err().to_string();
            assert!(e.starts_with("LoadOpenError::"), "{e}");
            assert!(e.contains(what), "{what}: {e}");
        }
    }
}
