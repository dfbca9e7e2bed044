//! The station's view of the fleet: for each robot its last pose, pose
//! rate, age, status and restarts, and the events of robots going silent
//! and coming back ([`Station`]).
//!
//! Every input carries the station's receive time (CLOCK_MONOTONIC ns, or
//! any clock the caller keeps increasing); the view at a time is a pure
//! function of the inputs received before it.
//!
//! Status, first match wins:
//! - [`Status::Lost`]: nothing from the robot for
//!   [`StationConfig::lost_after_s`] (2 s by default);
//! - [`Status::Stale`]: the robot is heard (health) but its last pose is
//!   older than [`StationConfig::stale_after_s`], or it never sent one;
//! - [`Status::Degraded`]: a stage of its last health report is not OK;
//! - [`Status::Ok`].
//!
//! The station tracks at most [`StationConfig::max_robots`] robots (1000 by
//! default): a sample of a robot not yet tracked once that many are is
//! dropped and counted ([`Station::excess`]), so a peer that puts under
//! thousands of made-up robot ids cannot grow the station's memory without
//! bound.

use std::collections::{BTreeMap, VecDeque};

use serde::{Deserialize, Serialize};

/// Thresholds of the station.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StationConfig {
    /// A robot silent this long is lost, s (default 2).
    pub lost_after_s: f64,
    /// A pose this old makes a robot stale, s (default 0.5: five missed
    /// poses at 10 Hz).
    pub stale_after_s: f64,
    /// The window the pose rate is measured over, s (default 1).
    pub rate_window_s: f64,
    /// The most robots tracked (default [`DEFAULT_MAX_ROBOTS`], at most
    /// [`MAX_ROBOTS_LIMIT`]): the samples of any further robot are
    /// dropped and counted ([`Station::excess`]).
    pub max_robots: usize,
}

/// The default of [`StationConfig::max_robots`].
pub const DEFAULT_MAX_ROBOTS: usize = 1000;

/// The largest [`StationConfig::max_robots`].
pub const MAX_ROBOTS_LIMIT: usize = 1_000_000;

impl Default for StationConfig {
    fn default() -> Self {
        Self {
            lost_after_s: 2.0,
            stale_after_s: 0.5,
            rate_window_s: 1.0,
            max_robots: DEFAULT_MAX_ROBOTS,
        }
    }
}

/// A [`StationConfig`] value out of range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StationConfigError {
    /// A threshold is not finite or not in (0, 3600] s.
    #[error(
        "StationConfigError::OutOfRange: {key} must be finite and in (0, 3600] s, got {value}"
    )]
    OutOfRange {
        /// The key.
        key: &'static str,
        /// Its value.
        value: f64,
    },
    /// `max_robots` is 0 or above [`MAX_ROBOTS_LIMIT`].
    #[error(
        "StationConfigError::MaxRobots: max_robots must be in 1..={MAX_ROBOTS_LIMIT}, got {0}"
    )]
    MaxRobots(usize),
}

impl StationConfigError {
    /// The key whose value is refused.
    #[must_use]
    pub const fn key(&self) -> &'static str {
        match self {
            Self::OutOfRange { key, .. } => key,
            Self::MaxRobots(_) => "max_robots",
        }
    }
}

impl StationConfig {
    /// Checks every threshold.
    ///
    /// # Errors
    /// [`StationConfigError`] naming the first bad key.
    pub fn validate(&self) -> Result<(), StationConfigError> {
        for (key, value) in [
            ("lost_after_s", self.lost_after_s),
            ("stale_after_s", self.stale_after_s),
            ("rate_window_s", self.rate_window_s),
        ] {
            if !(value.is_finite() && value > 0.0 && value <= 3600.0) {
                return Err(StationConfigError::OutOfRange { key, value });
            }
        }
        if !(1..=MAX_ROBOTS_LIMIT).contains(&self.max_robots) {
            return Err(StationConfigError::MaxRobots(self.max_robots));
        }
        Ok(())
    }
}

/// A robot's fused pose as the station keeps it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PoseSample {
    /// The pose's own stamp, ns (the robot's clock).
    pub stamp_ns: u64,
    /// Position, m (the fleet's map frame).
    pub pos_m: [f64; 3],
    /// Heading, rad.
    pub yaw_rad: f64,
}

/// A stage's state in a health report.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StageState {
    /// Running normally.
    Ok,
    /// Running with degraded inputs (coasting, a source missing).
    Degraded,
    /// Its input source is disconnected.
    Disconnected,
    /// Shutting down.
    Stopping,
    /// Not running (its heartbeat is stale or the launcher gave it up).
    Down,
}

/// One stage in a health report.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct StageHealth {
    /// Stage name (`imu`, `fusion`, ...).
    pub stage: String,
    /// Its state.
    pub state: StageState,
    /// How many times it was restarted.
    pub restarts: u64,
}

/// A robot's health report: its stages.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct HealthSample {
    /// The report's stamp, ns (the robot's clock).
    pub stamp_ns: u64,
    /// Every stage of its group.
    pub stages: Vec<StageHealth>,
}

/// A robot's status at the station.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    /// Poses arrive and every stage is OK.
    Ok,
    /// Poses arrive, but a stage is not OK.
    Degraded,
    /// Heard, but no recent pose.
    Stale,
    /// Nothing heard for `lost_after_s`.
    Lost,
}

/// What the station shows of one robot.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RobotView {
    /// Robot id.
    pub id: String,
    /// Its last pose, if any came.
    pub pose: Option<PoseSample>,
    /// Poses per second over the rate window (0 with fewer than two).
    pub rate_hz: f64,
    /// Seconds since its last pose was received (`None`: never).
    pub age_s: Option<f64>,
    /// Its status.
    pub status: Status,
    /// Restarts of its stages, summed, from its last health report.
    pub restarts: u64,
    /// How many times it was lost.
    pub lost_count: u64,
}

/// A change of a robot's presence.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum Event {
    /// First heard.
    New {
        /// Robot id.
        robot: String,
        /// Receive time, ns.
        at_ns: u64,
    },
    /// Silent for `lost_after_s`.
    Lost {
        /// Robot id.
        robot: String,
        /// The time it was found silent, ns.
        at_ns: u64,
    },
    /// Heard again after it was lost.
    Back {
        /// Robot id.
        robot: String,
        /// Receive time, ns.
        at_ns: u64,
    },
}

#[derive(Debug, Clone, Default)]
struct Track {
    last_rx_ns: u64,
    pose: Option<PoseSample>,
    last_pose_rx_ns: Option<u64>,
    pose_rx_ns: VecDeque<u64>,
    health: Option<HealthSample>,
    lost: bool,
    lost_count: u64,
}

/// The station's view of every robot heard.
#[derive(Debug, Clone)]
pub struct Station {
    cfg: StationConfig,
    robots: BTreeMap<String, Track>,
    /// Samples of robots beyond `max_robots`.
    excess: u64,
}

fn s_to_ns(s: f64) -> u64 {
    // Validated: finite, positive, at most an hour.
    (s * 1e9).round() as u64
}

impl Station {
    /// An empty station.
    ///
    /// # Errors
    /// [`StationConfigError`] for a bad threshold.
    pub fn new(cfg: StationConfig) -> Result<Self, StationConfigError> {
        cfg.validate()?;
        Ok(Self {
            cfg,
            robots: BTreeMap::new(),
            excess: 0,
        })
    }

    /// Whether `robot` is tracked (heard while there was room for it).
    #[must_use]
    pub fn tracks(&self, robot: &str) -> bool {
        self.robots.contains_key(robot)
    }

    /// The samples dropped because their robot was not tracked and
    /// [`StationConfig::max_robots`] robots were.
    #[must_use]
    pub fn excess(&self) -> u64 {
        self.excess
    }

    /// The most robots tracked.
    #[must_use]
    pub fn max_robots(&self) -> usize {
        self.cfg.max_robots
    }

    /// Whether a sample of `robot` is taken: the robot is tracked, or there
    /// is room for one more. Counts the sample in [`Station::excess`] when
    /// it is not.
    fn admit(&mut self, robot: &str) -> bool {
        if self.robots.len() < self.cfg.max_robots || self.robots.contains_key(robot) {
            true
        } else {
            self.excess += 1;
            false
        }
    }

    /// The robots heard so far.
    #[must_use]
    pub fn len(&self) -> usize {
        self.robots.len()
    }

    /// Whether no robot was heard yet.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.robots.is_empty()
    }

    fn heard(&mut self, robot: &str, rx_ns: u64) -> (&mut Track, Option<Event>) {
        let at_ns = rx_ns;
        let new = !self.robots.contains_key(robot);
        let t = self.robots.entry(robot.to_owned()).or_default();
        let ev = if new {
            Some(Event::New {
                robot: robot.to_owned(),
                at_ns,
            })
        } else if t.lost {
            Some(Event::Back {
                robot: robot.to_owned(),
                at_ns,
            })
        } else {
            None
        };
        t.lost = false;
        t.last_rx_ns = t.last_rx_ns.max(rx_ns);
        (t, ev)
    }

    /// A pose of `robot` received at `rx_ns`; the event if the robot is
    /// new or back. A robot beyond [`StationConfig::max_robots`] is not
    /// tracked: the pose is counted in [`Station::excess`] and dropped
    /// ([`Station::tracks`] tells which).
    pub fn on_pose(&mut self, robot: &str, pose: PoseSample, rx_ns: u64) -> Option<Event> {
        if !self.admit(robot) {
            return None;
        }
        let window = s_to_ns(self.cfg.rate_window_s);
        let (t, ev) = self.heard(robot, rx_ns);
        t.pose = Some(pose);
        t.last_pose_rx_ns = Some(t.last_pose_rx_ns.map_or(rx_ns, |p| p.max(rx_ns)));
        t.pose_rx_ns.push_back(rx_ns);
        while t
            .pose_rx_ns
            .front()
            .is_some_and(|&f| f.saturating_add(window) < rx_ns)
        {
            t.pose_rx_ns.pop_front();
        }
        ev
    }

    /// A health report of `robot` received at `rx_ns`; the event if the
    /// robot is new or back. A robot beyond [`StationConfig::max_robots`]
    /// is not tracked, as with [`Station::on_pose`].
    pub fn on_health(&mut self, robot: &str, health: HealthSample, rx_ns: u64) -> Option<Event> {
        if !self.admit(robot) {
            return None;
        }
        let (t, ev) = self.heard(robot, rx_ns);
        t.health = Some(health);
        ev
    }

    /// The robots found silent for `lost_after_s` at `now_ns` since the
    /// last call (each once, until it is heard again).
    pub fn tick(&mut self, now_ns: u64) -> Vec<Event> {
        let lost_after = s_to_ns(self.cfg.lost_after_s);
        let mut out = Vec::new();
        for (id, t) in &mut self.robots {
            if !t.lost && now_ns.saturating_sub(t.last_rx_ns) >= lost_after {
                t.lost = true;
                t.lost_count += 1;
                out.push(Event::Lost {
                    robot: id.clone(),
                    at_ns: now_ns,
                });
            }
        }
        out
    }

    /// Every robot as the station shows it at `now_ns` (after [`Station::tick`]),
    /// sorted by id.
    #[must_use]
    pub fn snapshot(&self, now_ns: u64) -> Vec<RobotView> {
        let window = s_to_ns(self.cfg.rate_window_s);
        let stale_after = s_to_ns(self.cfg.stale_after_s);
        self.robots
            .iter()
            .map(|(id, t)| {
                let recent: Vec<u64> = t
                    .pose_rx_ns
                    .iter()
                    .copied()
                    .filter(|&r| r <= now_ns && r.saturating_add(window) >= now_ns)
                    .collect();
                let rate_hz = match (recent.first(), recent.last()) {
                    (Some(&a), Some(&b)) if recent.len() >= 2 && b > a => {
                        (recent.len() - 1) as f64 / ((b - a) as f64 * 1e-9)
                    }
                    _ => 0.0,
                };
                let age_ns = t.last_pose_rx_ns.map(|p| now_ns.saturating_sub(p));
                let degraded = t
                    .health
                    .as_ref()
                    .is_some_and(|h| h.stages.iter().any(|s| s.state != StageState::Ok));
                let status = if t.lost {
                    Status::Lost
                } else if age_ns.is_none_or(|a| a > stale_after) {
                    Status::Stale
                } else if degraded {
                    Status::Degraded
                } else {
                    Status::Ok
                };
                RobotView {
                    id: id.clone(),
                    pose: t.pose,
                    rate_hz,
                    age_s: age_ns.map(|a| a as f64 * 1e-9),
                    status,
                    restarts: t
                        .health
                        .as_ref()
                        .map_or(0, |h| h.stages.iter().map(|s| s.restarts).sum()),
                    lost_count: t.lost_count,
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn pose(t: u64) -> PoseSample {
        PoseSample {
            stamp_ns: t,
            pos_m: [t as f64 * 1e-9, 0.0, 1.0],
            yaw_rad: 0.0,
        }
    }

    fn health(state: StageState, restarts: u64) -> HealthSample {
        HealthSample {
            stamp_ns: 0,
            stages: vec![
                StageHealth {
                    stage: "imu".into(),
                    state: StageState::Ok,
                    restarts: 1,
                },
                StageHealth {
                    stage: "fusion".into(),
                    state,
                    restarts,
                },
            ],
        }
    }

    #[test]
    fn a_robot_is_new_then_ok_at_its_rate() {
        let mut s = Station::new(StationConfig::default()).unwrap();
        let mut events = Vec::new();
        for k in 0..30u64 {
            events.extend(s.on_pose("r1", pose(k * 100 * MS), k * 100 * MS));
        }
        assert_eq!(
            events,
            vec![Event::New {
                robot: "r1".into(),
                at_ns: 0
            }]
        );
        let v = &s.snapshot(2950 * MS)[0];
        assert_eq!(v.status, Status::Ok);
        assert!((v.rate_hz - 10.0).abs() < 1e-9, "{}", v.rate_hz);
        assert!((v.age_s.unwrap() - 0.05).abs() < 1e-12);
        assert!((v.pose.unwrap().pos_m[0] - 2.9).abs() < 1e-12);
    }

    #[test]
    fn silent_robots_are_lost_once_and_back_when_heard() {
        let mut s = Station::new(StationConfig::default()).unwrap();
        s.on_pose("r1", pose(0), 0);
        s.on_pose("r2", pose(0), 0);
        for k in 1..=25u64 {
            s.on_pose("r2", pose(k * 100 * MS), k * 100 * MS);
        }
        assert!(s.tick(1999 * MS).is_empty());
        assert_eq!(
            s.tick(2000 * MS),
            vec![Event::Lost {
                robot: "r1".into(),
                at_ns: 2000 * MS
            }]
        );
        assert!(s.tick(2100 * MS).is_empty(), "lost is reported once");
        let view = s.snapshot(2500 * MS);
        assert_eq!(view[0].status, Status::Lost);
        assert_eq!(view[0].lost_count, 1);
        assert_eq!(
            view[1].status,
            Status::Ok,
            "the other robot keeps its status"
        );
        assert_eq!(
            s.on_pose("r1", pose(3000 * MS), 3000 * MS),
            Some(Event::Back {
                robot: "r1".into(),
                at_ns: 3000 * MS
            })
        );
        assert_eq!(s.snapshot(3000 * MS)[0].status, Status::Ok);
    }

    #[test]
    fn health_makes_degraded_and_old_poses_stale() {
        let mut s = Station::new(StationConfig::default()).unwrap();
        s.on_health("r1", health(StageState::Ok, 0), 0);
        assert_eq!(s.snapshot(0)[0].status, Status::Stale, "no pose yet");
        s.on_pose("r1", pose(0), 10 * MS);
        assert_eq!(s.snapshot(20 * MS)[0].status, Status::Ok);
        s.on_health("r1", health(StageState::Degraded, 2), 30 * MS);
        let v = &s.snapshot(40 * MS)[0];
        assert_eq!((v.status, v.restarts), (Status::Degraded, 3));
        assert_eq!(s.snapshot(511 * MS)[0].status, Status::Stale);
        assert_eq!(s.snapshot(511 * MS)[0].rate_hz, 0.0);
    }

    #[test]
    fn thresholds_are_checked() {
        for (key, cfg) in [
            (
                "lost_after_s",
                StationConfig {
                    lost_after_s: 0.0,
                    ..StationConfig::default()
                },
            ),
            (
                "stale_after_s",
                StationConfig {
                    stale_after_s: f64::NAN,
                    ..StationConfig::default()
                },
            ),
            (
                "rate_window_s",
                StationConfig {
                    rate_window_s: 1e9,
                    ..StationConfig::default()
                },
            ),
            (
                "max_robots",
                StationConfig {
                    max_robots: 0,
                    ..StationConfig::default()
                },
            ),
        ] {
            let e = Station::new(cfg).unwrap_err();
            assert_eq!(e.key(), key);
            assert!(e.to_string().contains(key), "{e}");
        }
    }

    #[test]
    fn robots_beyond_the_cap_are_counted_not_tracked() {
        let mut s = Station::new(StationConfig {
            max_robots: 3,
            ..StationConfig::default()
        })
        .unwrap();
        assert_eq!(StationConfig::default().max_robots, DEFAULT_MAX_ROBOTS);
        s.on_pose("r1", pose(0), 0);
        let mut new = 0;
        for i in 0..20_000u64 {
            let id = format!("fake{i}");
            let ev = if i % 2 == 0 {
                s.on_health(&id, health(StageState::Ok, 0), i)
            } else {
                s.on_pose(&id, pose(i), i)
            };
            new += usize::from(ev.is_some());
        }
        assert_eq!((s.len(), new), (3, 2), "two made-up robots fit");
        assert_eq!(s.excess(), 19_998);
        assert!(s.tracks("fake0") && s.tracks("fake1") && !s.tracks("fake2"));
        // The robots tracked keep being taken; lost ones stay tracked.
        for k in 1..=10u64 {
            assert_eq!(s.on_pose("r1", pose(k * 100 * MS), k * 100 * MS), None);
        }
        assert_eq!(s.excess(), 19_998);
        let v = s.snapshot(1000 * MS);
        assert_eq!(v.len(), 3);
        assert_eq!(v[2].id, "r1");
        assert!((v[2].rate_hz - 10.0).abs() < 1e-9, "{}", v[2].rate_hz);
    }

    #[test]
    fn a_snapshot_serialises_as_json() {
        let mut s = Station::new(StationConfig::default()).unwrap();
        s.on_pose("r1", pose(0), 0);
        let j = serde_json::to_value(s.snapshot(0)).unwrap();
        assert_eq!(j[0]["id"], "r1");
        assert_eq!(j[0]["status"], "ok");
        let e = serde_json::to_value(Event::Lost {
            robot: "r1".into(),
            at_ns: 5,
        })
        .unwrap();
        assert_eq!(e["event"], "lost");
    }
}
