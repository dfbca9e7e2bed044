//! What the station shows: a [`Snapshot`] of the fleet at one time (every
//! robot's [`RobotView`] with what reached the station of it, the events
//! since the previous snapshot, the delivery totals), printed as one JSON
//! object per line (`insuwb fleet --json`) or as a terminal table
//! ([`render_table`]).
//!
//! The JSON of a snapshot:
//!
//! ```json
//! {"t_s": 12.5, "now_ns": 81234567890123,
//!  "robots": [{"id": "r1", "status": "ok", "rate_hz": 10.0, "age_s": 0.031,
//!              "restarts": 0, "lost_count": 0,
//!              "pose": {"stamp_ns": 1767225600100000000, "pos_m": [1.2, -3.4, 0.5], "yaw_rad": 0.61},
//!              "poses": 125, "health": 13, "gaps": 0, "runs": 1, "delay_ms": 1.42}],
//!  "events": [{"event": "lost", "robot": "r2", "at_ns": 81233567890123}],
//!  "delivery": {"poses": 375, "health": 39, "gaps": 0, "invalid": 0, "excess": 0, "refused": 0,
//!               "delay_p50_ms": 1.3, "delay_p99_ms": 4.1, "delay_max_ms": 9.8}}
//! ```
//!
//! - `t_s`: seconds since the station started; `now_ns`: the station's
//!   CLOCK_MONOTONIC, the clock of every `at_ns`;
//! - `robots`, sorted by id: the [`RobotView`] fields (`id`, `status` `ok`
//!   / `degraded` / `stale` / `lost`, `rate_hz` over the rate window,
//!   `age_s` of the last pose, `restarts` of its stages, `lost_count`,
//!   `pose` with the robot's stamp, position and heading; `pose` and
//!   `age_s` are `null` before the first pose), then `poses` and `health`
//!   received, `gaps` (samples lost on the way), `runs` (the bridge's runs
//!   seen: 1 + its restarts seen by the poses' `seq`) and `delay_ms` (the
//!   last pose's receive time minus its stamp, in the robots' stamp clock);
//! - `events` since the previous snapshot: `new`, `lost` (silent for the
//!   lost time, 2 s) and `back`, each with its robot and time;
//! - `delivery`: the totals ([`DeliverySummary`]): `invalid` counts the
//!   samples that are not fleet payloads, `excess` those of robots beyond
//!   the station's `max_robots`, `refused` the puts its router refused
//!   (a robot under another's keys, `[station.identity]`).
//!
//! ```
//! use insuwb_fleet::delivery::Delivery;
//! use insuwb_fleet::station::{PoseSample, Station, StationConfig};
//! use insuwb_fleet::view::{render_table, Snapshot};
//!
//! let mut s = Station::new(StationConfig::default()).unwrap();
//! let mut d = Delivery::default();
//! let pose = PoseSample { stamp_ns: 0, pos_m: [1.0, 2.0, 0.5], yaw_rad: 0.0 };
//! let events: Vec<_> = s.on_pose("r1", pose, 0).into_iter().collect();
//! d.on_pose("r1", 0, 1_000_000);
//! let snap = Snapshot::new(0.5, 50_000_000, &s, &d, events);
//! assert_eq!(snap.robots[0].view.id, "r1");
//! assert!(render_table(&snap).contains("r1"));
//! let back: Snapshot = serde_json::from_str(&serde_json::to_string(&snap).unwrap()).unwrap();
//! assert_eq!(back, snap);
//! ```

use std::fmt::Write as _;

use serde::{Deserialize, Serialize};

use crate::delivery::{Delivery, DeliverySummary};
use crate::station::{Event, RobotView, Station, Status};

/// One robot in a snapshot: what the station shows of it and what reached
/// the station.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RobotRow {
    /// The station's view.
    #[serde(flatten)]
    pub view: RobotView,
    /// Poses received.
    pub poses: u64,
    /// Health samples received.
    pub health: u64,
    /// Samples lost on the way (gaps in the sequence numbers).
    pub gaps: u64,
    /// Runs of its bridge seen (1 + restarts seen by the poses' `seq`).
    pub runs: u64,
    /// Receive time minus stamp of its last pose, ms (`null`: no pose).
    pub delay_ms: Option<f64>,
}

/// The fleet at one time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Snapshot {
    /// Seconds since the station started.
    pub t_s: f64,
    /// The station's CLOCK_MONOTONIC now, ns (the clock of the events).
    pub now_ns: u64,
    /// Every robot heard, sorted by id.
    pub robots: Vec<RobotRow>,
    /// The events since the previous snapshot.
    pub events: Vec<Event>,
    /// The delivery totals.
    pub delivery: DeliverySummary,
}

impl Snapshot {
    /// The snapshot of `station` and `delivery` at `now_ns` (`t_s` after
    /// the start), with `events`.
    #[must_use]
    pub fn new(
        t_s: f64,
        now_ns: u64,
        station: &Station,
        delivery: &Delivery,
        events: Vec<Event>,
    ) -> Self {
        let robots = station
            .snapshot(now_ns)
            .into_iter()
            .map(|view| {
                let d = delivery.robot(&view.id).copied().unwrap_or_default();
                RobotRow {
                    poses: d.poses.received(),
                    health: d.health.received(),
                    gaps: d.poses.gaps() + d.health.gaps(),
                    runs: d.poses.runs(),
                    delay_ms: d.last_delay_ns.map(|n| n as f64 * 1e-6),
                    view,
                }
            })
            .collect();
        let mut delivery = delivery.summary();
        delivery.excess = station.excess();
        Self {
            t_s,
            now_ns,
            robots,
            events,
            delivery,
        }
    }

    /// How many robots have `status`.
    #[must_use]
    pub fn count(&self, status: Status) -> usize {
        self.robots
            .iter()
            .filter(|r| r.view.status == status)
            .count()
    }
}

/// The name of a status as the table and the JSON spell it.
#[must_use]
pub const fn status_name(s: Status) -> &'static str {
    match s {
        Status::Ok => "ok",
        Status::Degraded => "degraded",
        Status::Stale => "stale",
        Status::Lost => "lost",
    }
}

/// A number with `prec` decimals, or `-`.
fn opt(v: Option<f64>, prec: usize) -> String {
    v.map_or_else(|| "-".to_owned(), |x| format!("{x:.prec$}"))
}

/// The terminal table of a snapshot: a summary line (and one of the
/// refused samples, when there are any), then one row per
/// robot (id, status, position, heading, pose rate, age of the last pose,
/// restarts, times lost, samples lost on the way, delay of the last pose).
#[must_use]
pub fn render_table(s: &Snapshot) -> String {
    let mut out = String::new();
    let d = &s.delivery;
    let _ = writeln!(
        out,
        "insuwb fleet  t {:.1} s  robots {}: {} ok, {} degraded, {} stale, {} lost  |  poses {}, lost on the way {}, delay p50 {} ms, p99 {} ms",
        s.t_s,
        s.robots.len(),
        s.count(Status::Ok),
        s.count(Status::Degraded),
        s.count(Status::Stale),
        s.count(Status::Lost),
        d.poses,
        d.gaps,
        opt(d.delay_p50_ms, 1),
        opt(d.delay_p99_ms, 1),
    );
    if d.invalid > 0 || d.excess > 0 {
        let _ = writeln!(
            out,
            "refused: {} not fleet payloads, {} of robots beyond max_robots",
            d.invalid, d.excess
        );
    }
    let _ = writeln!(
        out,
        "{:<16} {:<8} {:>9} {:>9} {:>7} {:>7} {:>6} {:>7} {:>8} {:>4} {:>6} {:>8}",
        "ROBOT",
        "STATUS",
        "X (m)",
        "Y (m)",
        "Z (m)",
        "YAW deg",
        "HZ",
        "AGE (s)",
        "RESTARTS",
        "LOST",
        "GAPS",
        "DELAY ms"
    );
    for r in &s.robots {
        let v = &r.view;
        let p = |i: usize| opt(v.pose.map(|p| p.pos_m[i]), 2);
        let _ = writeln!(
            out,
            "{:<16} {:<8} {:>9} {:>9} {:>7} {:>7} {:>6.1} {:>7} {:>8} {:>4} {:>6} {:>8}",
            v.id,
            status_name(v.status),
            p(0),
            p(1),
            p(2),
            opt(v.pose.map(|p| p.yaw_rad.to_degrees()), 0),
            v.rate_hz,
            opt(v.age_s, 2),
            v.restarts,
            v.lost_count,
            r.gaps,
            opt(r.delay_ms, 1),
        );
    }
    if s.robots.is_empty() {
        let _ = writeln!(out, "(no robot heard yet)");
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::station::{PoseSample, StationConfig};

    const MS: u64 = 1_000_000;

    fn fleet() -> (Station, Delivery, Vec<Event>) {
        let mut s = Station::new(StationConfig::default()).unwrap();
        let mut d = Delivery::default();
        let mut ev = Vec::new();
        for k in 0..30u64 {
            let t = k * 100 * MS;
            let pose = PoseSample {
                stamp_ns: t,
                pos_m: [1.5, -2.25, 0.5],
                yaw_rad: std::f64::consts::FRAC_PI_2,
            };
            ev.extend(s.on_pose("r1", pose, t));
            d.on_pose("r1", k, 2 * MS as i64);
            if k < 5 {
                ev.extend(s.on_pose("r2", pose, t));
                d.on_pose("r2", k * 2, MS as i64);
            }
        }
        ev.extend(s.tick(2950 * MS));
        (s, d, ev)
    }

    #[test]
    fn a_snapshot_holds_views_delivery_and_events() {
        let (s, d, ev) = fleet();
        let snap = Snapshot::new(2.95, 2950 * MS, &s, &d, ev);
        assert_eq!(snap.robots.len(), 2);
        let (r1, r2) = (&snap.robots[0], &snap.robots[1]);
        assert_eq!(
            (r1.view.status, r1.poses, r1.gaps, r1.runs),
            (Status::Ok, 30, 0, 1)
        );
        assert_eq!((r2.view.status, r2.poses, r2.gaps), (Status::Lost, 5, 4));
        assert_eq!(r1.delay_ms, Some(2.0));
        assert_eq!((snap.count(Status::Ok), snap.count(Status::Lost)), (1, 1));
        let kinds: Vec<&str> = snap
            .events
            .iter()
            .map(|e| match e {
                Event::New { .. } => "new",
                Event::Lost { .. } => "lost",
                Event::Back { .. } => "back",
            })
            .collect();
        assert_eq!(kinds, ["new", "new", "lost"]);
        assert_eq!(snap.delivery.poses, 35);
    }

    #[test]
    fn the_json_has_the_documented_fields() {
        let (s, d, ev) = fleet();
        let j = serde_json::to_value(Snapshot::new(2.95, 2950 * MS, &s, &d, ev)).unwrap();
        for k in ["t_s", "now_ns", "robots", "events", "delivery"] {
            assert!(!j[k].is_null(), "{k}");
        }
        let r = &j["robots"][0];
        for k in [
            "id",
            "status",
            "rate_hz",
            "age_s",
            "restarts",
            "lost_count",
            "pose",
            "poses",
            "health",
            "gaps",
            "runs",
            "delay_ms",
        ] {
            assert!(r.get(k).is_some(), "{k} in {r}");
        }
        assert_eq!(r["status"], "ok");
        assert_eq!(r["pose"]["pos_m"][0], 1.5);
        assert_eq!(j["events"][2]["event"], "lost");
        assert_eq!(j["events"][2]["robot"], "r2");
        for k in [
            "poses",
            "health",
            "gaps",
            "invalid",
            "excess",
            "delay_p50_ms",
            "delay_p99_ms",
            "delay_max_ms",
        ] {
            assert!(j["delivery"].get(k).is_some(), "{k}");
        }
    }

    #[test]
    fn refused_samples_are_in_the_totals_and_the_table() {
        let mut s = Station::new(StationConfig {
            max_robots: 1,
            ..StationConfig::default()
        })
        .unwrap();
        let mut d = Delivery::default();
        let pose = PoseSample {
            stamp_ns: 0,
            pos_m: [0.0; 3],
            yaw_rad: 0.0,
        };
        let _ = s.on_pose("r1", pose, 0);
        let _ = s.on_pose("made-up", pose, 0);
        d.on_pose("r1", 0, 0);
        d.on_invalid();
        let snap = Snapshot::new(0.1, 0, &s, &d, vec![]);
        assert_eq!(
            (
                snap.robots.len(),
                snap.delivery.invalid,
                snap.delivery.excess
            ),
            (1, 1, 1)
        );
        let t = render_table(&snap);
        assert!(
            t.lines().nth(1).is_some_and(
                |l| l == "refused: 1 not fleet payloads, 1 of robots beyond max_robots"
            ),
            "{t}"
        );
        let j = serde_json::to_value(&snap).unwrap();
        assert_eq!(j["delivery"]["excess"], 1);
    }

    #[test]
    fn the_table_shows_every_robot_and_dashes_for_what_is_unknown() {
        let (s, d, ev) = fleet();
        let t = render_table(&Snapshot::new(2.95, 2950 * MS, &s, &d, ev));
        let lines: Vec<&str> = t.lines().collect();
        assert_eq!(lines.len(), 4, "{t}");
        assert!(
            lines[0].contains("robots 2: 1 ok, 0 degraded, 0 stale, 1 lost"),
            "{t}"
        );
        assert!(lines[1].starts_with("ROBOT"), "{t}");
        let r1: Vec<&str> = lines[2].split_whitespace().collect();
        assert_eq!(r1[..6], ["r1", "ok", "1.50", "-2.25", "0.50", "90"], "{t}");
        assert!(
            lines[3].starts_with("r2") && lines[3].contains("lost"),
            "{t}"
        );
        let empty = Station::new(StationConfig::default()).unwrap();
        let t = render_table(&Snapshot::new(0.0, 0, &empty, &Delivery::default(), vec![]));
        assert!(
            t.contains("no robot heard yet") && t.contains(" - ms"),
            "{t}"
        );
    }
}
