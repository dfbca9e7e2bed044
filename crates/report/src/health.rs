//! The group's health from the stages' heartbeats, for a stage that reports
//! on every stage (the ROS 2 bridge's `/diagnostics`, the Foxglove live
//! view's `health`): what each stage's last heartbeat told ([`StageSeen`],
//! [`GroupSeen`]) and what that makes of it ([`StageCondition`]). No I/O,
//! no DDS: the Foxglove live view builds it without the `dds` feature.
//!
//! ```
//! use insuwb_msg::{fixed_name, Header, Health};
//! use insuwb_report::health::{GroupSeen, StageCondition};
//! let mut group = GroupSeen::new(&["imu".to_owned(), "fusion".to_owned()]);
//! let h = Health { header: Header::new(0, 1_000), stage: fixed_name("imu"), ..Health::default() };
//! group.note_heartbeat(h, 2_000);
//! let c: Vec<StageCondition> = group
//!     .stages()
//!     .map(|(_, seen, coasting)| StageCondition::of(seen, coasting, 3_000, 1_000_000_000))
//!     .collect();
//! assert_eq!(c, [StageCondition::Ok, StageCondition::Down]);
//! ```

use insuwb_msg::{name_str, FusedState, Health, HealthState, StageRole, StateCode, UnknownState};

/// What is known of one stage from its heartbeats.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StageSeen {
    /// The last heartbeat.
    pub last: Health,
    /// When it was published or, without a publish time, arrived
    /// (CLOCK_MONOTONIC ns).
    pub last_rx_ns: u64,
    /// Received and published samples per second between the last two
    /// heartbeats of the same process.
    pub rates_hz: Option<(f64, f64)>,
}

impl StageSeen {
    /// The first heartbeat of a stage.
    #[must_use]
    pub fn new(h: Health, rx_ns: u64) -> Self {
        Self {
            last: h,
            last_rx_ns: rx_ns,
            rates_hz: None,
        }
    }

    /// Takes a newer heartbeat, updating the rates (a new process starts
    /// them again).
    pub fn note(&mut self, h: Health, rx_ns: u64) {
        let dt = h
            .header
            .meas_time_ns
            .saturating_sub(self.last.header.meas_time_ns) as f64
            * 1e-9;
        self.rates_hz = (h.pid == self.last.pid && dt > 0.0).then(|| {
            (
                h.received.saturating_sub(self.last.received) as f64 / dt,
                h.published.saturating_sub(self.last.published) as f64 / dt,
            )
        });
        self.last = h;
        self.last_rx_ns = rx_ns;
    }

    /// Age of the last heartbeat at `now_ns` (CLOCK_MONOTONIC), ns (0 when
    /// `now_ns` is before it).
    #[must_use]
    pub fn age_ns(&self, now_ns: u64) -> u64 {
        now_ns.saturating_sub(self.last_rx_ns)
    }
}

/// What a stage's heartbeats make of it, each variant taking precedence
/// over the ones after it ([`StageCondition::of`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StageCondition {
    /// No heartbeat came yet.
    Down,
    /// The last heartbeat is older than the stale limit.
    Stale,
    /// The last heartbeat says the stage is stopping.
    Stopping,
    /// The last heartbeat says the stage's input is disconnected.
    Disconnected,
    /// The last heartbeat says the stage is degraded.
    Degraded,
    /// The fusion stage's last output was flagged degraded or stale (no
    /// UWB update, INS only).
    Coasting,
    /// The last heartbeat says the stage is fine.
    Ok,
    /// The last heartbeat holds a state code this version does not know.
    Unknown(u32),
}

impl StageCondition {
    /// The condition of a stage at `now_ns` from what its heartbeats told
    /// (`None`: none came), whether it coasts (the fusion stage whose last
    /// output was flagged degraded or stale), and how old its last
    /// heartbeat may be before it is stale, ns.
    #[must_use]
    pub fn of(seen: Option<&StageSeen>, coasting: bool, now_ns: u64, stale_after_ns: u64) -> Self {
        let Some(s) = seen else {
            return Self::Down;
        };
        if s.age_ns(now_ns) > stale_after_ns {
            return Self::Stale;
        }
        match Self::of_state(s.last.state) {
            Self::Ok if coasting => Self::Coasting,
            Self::Unknown(_) if coasting => Self::Coasting,
            c => c,
        }
    }

    /// The condition a heartbeat's state code says by itself (no age, no
    /// coasting): `Ok`, `Degraded`, `Disconnected`, `Stopping` or, for a
    /// code this version does not know, `Unknown`.
    #[must_use]
    pub fn of_state(state: StateCode) -> Self {
        match state.get() {
            Ok(HealthState::Ok) => Self::Ok,
            Ok(HealthState::Degraded) => Self::Degraded,
            Ok(HealthState::Disconnected) => Self::Disconnected,
            Ok(HealthState::Stopping) => Self::Stopping,
            Err(UnknownState(code)) => Self::Unknown(code),
        }
    }

    /// The condition's word, the same in every report (the launcher's,
    /// ROS 2 `/diagnostics`, the Foxglove live view, the Zenoh bridge's
    /// health): `down`, `stale`, `stopping`, `disconnected`, `degraded`,
    /// `coasting`, `ok`, `unknown`.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Down => "down",
            Self::Stale => "stale",
            Self::Stopping => "stopping",
            Self::Disconnected => "disconnected",
            Self::Degraded => "degraded",
            Self::Coasting => "coasting",
            Self::Ok => "ok",
            Self::Unknown(_) => "unknown",
        }
    }

    /// How bad the condition is, the same in every report: the stage is
    /// not doing its work (`Error`), does it with less (`Warn`, an unknown
    /// state code included), or is fine (`Ok`).
    #[must_use]
    pub fn severity(self) -> Severity {
        match self {
            Self::Down | Self::Stale | Self::Stopping | Self::Disconnected => Severity::Error,
            Self::Degraded | Self::Coasting | Self::Unknown(_) => Severity::Warn,
            Self::Ok => Severity::Ok,
        }
    }
}

/// How bad a stage's condition is ([`StageCondition::severity`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Severity {
    /// Working normally.
    Ok,
    /// Working with less (degraded input, coasting, an unknown state).
    Warn,
    /// Not working (no heartbeat, a stale one, stopping, input lost).
    Error,
}

impl Severity {
    /// 0, 1 or 2: the level of ROS 2's `diagnostic_msgs/DiagnosticStatus`
    /// (OK, WARN, ERROR) and of the Foxglove live view's health.
    #[must_use]
    pub fn level(self) -> u8 {
        match self {
            Self::Ok => 0,
            Self::Warn => 1,
            Self::Error => 2,
        }
    }
}

/// Every stage of a group, in the group's order, with what its heartbeats
/// told, and whether the fusion stage coasts: what a stage reporting on
/// the whole group keeps between its reports.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct GroupSeen {
    stages: Vec<(String, Option<StageSeen>)>,
    coasting: bool,
}

impl GroupSeen {
    /// The stages named, none heard from yet.
    #[must_use]
    pub fn new(stages: &[String]) -> Self {
        Self {
            stages: stages.iter().map(|s| (s.clone(), None)).collect(),
            coasting: false,
        }
    }

    /// Takes a heartbeat received at `now_ns` (CLOCK_MONOTONIC), aged from
    /// its publication (same host, same clock): a heartbeat of the topic's
    /// history is as old as it is. A stage outside the group is ignored.
    pub fn note_heartbeat(&mut self, h: Health, now_ns: u64) {
        let at = if h.header.pub_time_ns > 0 {
            h.header.pub_time_ns.min(now_ns)
        } else {
            now_ns
        };
        let name = name_str(&h.stage);
        if let Some((_, slot)) = self.stages.iter_mut().find(|(n, _)| *n == name) {
            match slot {
                Some(s) => s.note(h, at),
                None => *slot = Some(StageSeen::new(h, at)),
            }
        }
    }

    /// Takes a fused state: the fusion stage coasts while its last output
    /// is flagged degraded or stale.
    pub fn note_fused(&mut self, s: &FusedState) {
        self.coasting = s.header.flags & (FusedState::FLAG_DEGRADED | FusedState::FLAG_STALE) != 0;
    }

    /// Whether the fusion stage's last output was flagged degraded or stale.
    #[must_use]
    pub fn coasting(&self) -> bool {
        self.coasting
    }

    /// Each stage in the group's order: its name, what its heartbeats told
    /// (`None`: none yet), and whether it coasts (the fusion stage, see
    /// [`GroupSeen::coasting`]).
    pub fn stages(&self) -> impl Iterator<Item = (&str, Option<&StageSeen>, bool)> + '_ {
        let fusion = StageRole::Fusion.name();
        self.stages
            .iter()
            .map(move |(name, s)| (name.as_str(), s.as_ref(), self.coasting && name == fusion))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use insuwb_msg::{fixed_name, Header};

    fn beat(stage: &str, meas_ns: u64, pub_ns: u64) -> Health {
        let mut h = Health {
            header: Header::new(0, meas_ns),
            stage: fixed_name(stage),
            pid: 7,
            ..Health::default()
        };
        h.header.pub_time_ns = pub_ns;
        h
    }

    #[test]
    fn one_word_and_severity_per_condition_an_unknown_state_a_warning() {
        use StageCondition as C;
        let table = [
            (C::Down, "down", Severity::Error),
            (C::Stale, "stale", Severity::Error),
            (C::Stopping, "stopping", Severity::Error),
            (C::Disconnected, "disconnected", Severity::Error),
            (C::Degraded, "degraded", Severity::Warn),
            (C::Coasting, "coasting", Severity::Warn),
            (C::Ok, "ok", Severity::Ok),
            (C::Unknown(9), "unknown", Severity::Warn),
        ];
        for (c, name, severity) in table {
            assert_eq!((c.name(), c.severity()), (name, severity), "{c:?}");
        }
        assert_eq!(
            [Severity::Ok, Severity::Warn, Severity::Error].map(Severity::level),
            [0, 1, 2]
        );
        assert_eq!(C::of_state(HealthState::Stopping.into()), C::Stopping);
        assert_eq!(C::of_state(StateCode::from_raw(77)), C::Unknown(77));
    }

    #[test]
    fn conditions_follow_state_age_and_coasting_in_order() {
        let seen = StageSeen::new(beat("fusion", 1_000, 1_000), 1_000);
        let of = |s: &StageSeen, coasting, now| StageCondition::of(Some(s), coasting, now, 500);
        assert_eq!(StageCondition::of(None, true, 0, 500), StageCondition::Down);
        assert_eq!(of(&seen, false, 1_500), StageCondition::Ok);
        assert_eq!(of(&seen, true, 1_500), StageCondition::Coasting);
        assert_eq!(of(&seen, true, 1_501), StageCondition::Stale);
        assert_eq!(seen.age_ns(900), 0);
        for (state, want) in [
            (HealthState::Stopping.into(), StageCondition::Stopping),
            (
                HealthState::Disconnected.into(),
                StageCondition::Disconnected,
            ),
            (HealthState::Degraded.into(), StageCondition::Degraded),
            (StateCode::from_raw(9), StageCondition::Unknown(9)),
        ] {
            let mut s = seen;
            s.last.state = state;
            // A state the stage tells beats coasting, but for an unknown one.
            let coasting_wins = matches!(want, StageCondition::Unknown(_));
            assert_eq!(
                of(&s, true, 1_000),
                if coasting_wins {
                    StageCondition::Coasting
                } else {
                    want
                }
            );
            assert_eq!(of(&s, false, 1_000), want);
        }
    }

    #[test]
    fn the_group_keeps_its_stages_ages_beats_and_coasts() {
        let mut g = GroupSeen::new(&["imu".to_owned(), "fusion".to_owned()]);
        // Aged from its publication, never after now; no publish time: now.
        g.note_heartbeat(beat("imu", 100, 400), 1_000);
        g.note_heartbeat(beat("fusion", 100, 4_000), 1_000);
        g.note_heartbeat(beat("ros2", 100, 0), 1_000);
        let rx: Vec<_> = g
            .stages()
            .map(|(n, s, _)| (n.to_owned(), s.map(|s| s.last_rx_ns)))
            .collect();
        assert_eq!(
            rx,
            [
                ("imu".to_owned(), Some(400)),
                ("fusion".to_owned(), Some(1_000))
            ]
        );
        g.note_heartbeat(beat("imu", 200, 0), 2_000);
        let imu = g.stages().next().and_then(|(_, s, _)| s.copied());
        assert_eq!(imu.map(|s| s.last_rx_ns), Some(2_000));
        let mut f = FusedState::default();
        f.header.flags = FusedState::FLAG_STALE;
        g.note_fused(&f);
        assert!(g.coasting());
        let coasts: Vec<bool> = g.stages().map(|(_, _, c)| c).collect();
        assert_eq!(coasts, [false, true]);
        f.header.flags = FusedState::FLAG_VALID;
        g.note_fused(&f);
        assert!(!g.coasting());
    }
}
