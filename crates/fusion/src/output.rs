//! What is published besides the updates: the coasting and stale-input
//! policy of the fusion stage, as a pure type the stage and the lockstep
//! runner ([`crate::runner`]) both feed, so `insuwb eval`, replay and the
//! stage apply the same rules.
//!
//! - Every fused state an update produced is published; while the INS input
//!   is stale it is flagged [`FusedState::FLAG_STALE`] and loses
//!   [`FusedState::FLAG_VALID`].
//! - On each tick the newest INS state's age decides staleness: older than
//!   `stale_ins_timeout_s` (or no INS state yet) is stale.
//! - With no update for longer than `coast_timeout_s`, each tick at least one
//!   coasting period after the previous coasting output publishes the
//!   engine's INS-only state ([`crate::engine::FusionEngine::coasting_state`],
//!   flagged [`FusedState::FLAG_DEGRADED`]), at `coast_rate_hz`.
//! - While the INS input is stale, each UWB fix also gives a pose built on
//!   the fix alone ([`OutputPolicy::on_fix`], flagged
//!   [`FusedState::FLAG_UWB_ONLY`] and valid): a dead INS leaves the robot
//!   a pose at the fix rate, with the fix's covariance.
//!
//! Times are whatever clock the caller ticks with (the stage: monotonic
//! nanoseconds; the runner: the recording's measurement times).

use insuwb_msg::FusedState;
use serde::{Deserialize, Serialize};

/// Coasting and stale-input settings: `[fusion.output]` of the fusion
/// settings, read by the stage and the runner alike.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputPolicyConfig {
    /// With no update for this long, publish the INS-only coasting state, s.
    /// Default 0.15.
    pub coast_timeout_s: f64,
    /// Rate of coasting outputs, Hz. Default 10.
    pub coast_rate_hz: f64,
    /// An INS state older than this is stale: outputs are flagged stale and
    /// not valid, s. Default 0.25.
    pub stale_ins_timeout_s: f64,
}

impl Default for OutputPolicyConfig {
    fn default() -> Self {
        Self {
            coast_timeout_s: 0.15,
            coast_rate_hz: 10.0,
            stale_ins_timeout_s: 0.25,
        }
    }
}

/// Why an [`OutputPolicyConfig`] was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum OutputPolicyConfigError {
    /// A setting that must be a finite positive number is not.
    #[error("{key}: must be > 0, got {value}")]
    NotPositive {
        /// The key.
        key: &'static str,
        /// Its value.
        value: f64,
    },
}

impl OutputPolicyConfig {
    /// Checks that every setting is finite and positive.
    ///
    /// # Errors
    /// [`OutputPolicyConfigError::NotPositive`] naming the first key that is not.
    pub fn validate(&self) -> Result<(), OutputPolicyConfigError> {
        for (key, value) in [
            ("coast_timeout_s", self.coast_timeout_s),
            ("coast_rate_hz", self.coast_rate_hz),
            ("stale_ins_timeout_s", self.stale_ins_timeout_s),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(OutputPolicyConfigError::NotPositive { key, value });
            }
        }
        Ok(())
    }
}

/// The coasting and stale-input policy: fed with times, the updates' fused
/// states and the INS age, it says what to publish and how it is flagged.
#[derive(Debug, Clone)]
pub struct OutputPolicy {
    coast_ns: u64,
    coast_period_ns: u64,
    stale_ns: u64,
    slack_ns: u64,
    last_update_ns: u64,
    last_coast_ns: Option<u64>,
    stale: bool,
}

impl OutputPolicy {
    /// A policy started at `start_ns` (coasting begins `coast_timeout_s`
    /// after it without an update) for a caller that ticks every `tick_ns`
    /// (0: on every input): half a tick of slack keeps the coasting rate.
    ///
    /// # Errors
    /// A configuration that does not validate.
    pub fn new(
        cfg: &OutputPolicyConfig,
        tick_ns: u64,
        start_ns: u64,
    ) -> Result<Self, OutputPolicyConfigError> {
        cfg.validate()?;
        Ok(Self {
            coast_ns: (cfg.coast_timeout_s * 1e9) as u64,
            coast_period_ns: (1e9 / cfg.coast_rate_hz) as u64,
            stale_ns: (cfg.stale_ins_timeout_s * 1e9) as u64,
            slack_ns: tick_ns / 2,
            last_update_ns: start_ns,
            last_coast_ns: None,
            stale: false,
        })
    }

    /// A fused state an update produced, published at `now_ns`: returned
    /// flagged stale and not valid while the INS input is stale.
    pub fn on_update(&mut self, s: FusedState, now_ns: u64) -> FusedState {
        self.last_update_ns = now_ns;
        self.flagged(s)
    }

    /// A tick at `now_ns`, with the newest INS state `ins_age_ns` old (None:
    /// no INS state yet). Updates the stale flag; when coasting is due,
    /// returns the state `coasting_state` builds (called only then),
    /// flagged as [`OutputPolicy::on_update`] flags.
    pub fn on_tick(
        &mut self,
        now_ns: u64,
        ins_age_ns: Option<u64>,
        coasting_state: impl FnOnce() -> Option<FusedState>,
    ) -> Option<FusedState> {
        self.stale = ins_age_ns.is_none_or(|a| a > self.stale_ns);
        let due = self.coasting(now_ns)
            && self
                .last_coast_ns
                .is_none_or(|t| now_ns.saturating_sub(t) + self.slack_ns >= self.coast_period_ns);
        if !due {
            return None;
        }
        let s = coasting_state()?;
        self.last_coast_ns = Some(now_ns);
        Some(self.flagged(s))
    }

    /// A UWB fix arrived: while the INS input is stale (at the last tick),
    /// returns the pose `uwb_only_state` builds on the fix alone (called
    /// only then; [`crate::engine::FusionEngine::uwb_only_state`]), so that
    /// a dead or frozen INS leaves a valid, UWB-backed pose flagged
    /// [`FusedState::FLAG_UWB_ONLY`] instead of none. It neither starts nor
    /// stops coasting.
    pub fn on_fix(
        &mut self,
        uwb_only_state: impl FnOnce() -> Option<FusedState>,
    ) -> Option<FusedState> {
        if !self.stale {
            return None;
        }
        uwb_only_state()
    }

    /// Whether the INS input was stale at the last tick.
    #[must_use]
    pub fn stale(&self) -> bool {
        self.stale
    }

    /// Whether no update came for longer than `coast_timeout_s` before `now_ns`.
    #[must_use]
    pub fn coasting(&self, now_ns: u64) -> bool {
        now_ns.saturating_sub(self.last_update_ns) > self.coast_ns
    }

    fn flagged(&self, mut s: FusedState) -> FusedState {
        if self.stale {
            s.header.flags = (s.header.flags | FusedState::FLAG_STALE) & !FusedState::FLAG_VALID;
        }
        s
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;
    use insuwb_msg::Header;

    const MS: u64 = 1_000_000;

    fn state(t_ns: u64) -> FusedState {
        FusedState {
            header: Header {
                flags: FusedState::FLAG_VALID,
                ..Header::new(0, t_ns)
            },
            ..FusedState::default()
        }
    }

    fn coast(t_ns: u64) -> Option<FusedState> {
        let mut s = state(t_ns);
        s.header.flags |= FusedState::FLAG_DEGRADED;
        Some(s)
    }

    /// Ticks every `step` from `from` to `to` (exclusive) with fresh INS;
    /// the times of the coasting outputs.
    fn ticks(p: &mut OutputPolicy, from: u64, to: u64, step: u64) -> Vec<u64> {
        (from..to)
            .step_by(step as usize)
            .filter_map(|t| {
                p.on_tick(t, Some(MS), || coast(t))
                    .map(|s| s.header.meas_time_ns)
            })
            .collect()
    }

    #[test]
    fn coasts_after_the_timeout_at_the_rate() {
        let cfg = OutputPolicyConfig::default();
        let mut p = OutputPolicy::new(&cfg, 0, 0).unwrap();
        // 150 ms without an update: nothing before, then every 100 ms.
        let out = ticks(&mut p, 0, 600 * MS, 10 * MS);
        assert_eq!(out, [160 * MS, 260 * MS, 360 * MS, 460 * MS, 560 * MS]);
        assert!(p.coasting(600 * MS));
        let s = p.on_tick(700 * MS, Some(MS), || coast(700 * MS)).unwrap();
        assert_ne!(s.header.flags & FusedState::FLAG_DEGRADED, 0);
        assert_ne!(s.header.flags & FusedState::FLAG_VALID, 0);
    }

    #[test]
    fn half_a_tick_of_slack_keeps_the_rate() {
        // 40 ms ticks, not on the coasting period's grid: the tick 99 ms
        // after a coasting output publishes the next one.
        let cfg = OutputPolicyConfig::default();
        let mut p = OutputPolicy::new(&cfg, 40 * MS, 0).unwrap();
        let mut out = Vec::new();
        for t in [160, 199, 259, 299, 359] {
            if let Some(s) = p.on_tick(t * MS, Some(MS), || coast(t * MS)) {
                out.push(s.header.meas_time_ns / MS);
            }
        }
        assert_eq!(out, [160, 259, 359]);
        let mut strict = OutputPolicy::new(&cfg, 0, 0).unwrap();
        let mut out = Vec::new();
        for t in [160, 199, 259, 299, 359] {
            if let Some(s) = strict.on_tick(t * MS, Some(MS), || coast(t * MS)) {
                out.push(s.header.meas_time_ns / MS);
            }
        }
        assert_eq!(out, [160, 299]);
    }

    #[test]
    fn an_update_stops_coasting_and_it_resumes_after_the_timeout() {
        let cfg = OutputPolicyConfig::default();
        let mut p = OutputPolicy::new(&cfg, 0, 0).unwrap();
        assert_eq!(ticks(&mut p, 0, 300 * MS, 10 * MS), [160 * MS, 260 * MS]);
        let s = p.on_update(state(300 * MS), 300 * MS);
        assert_eq!(s.header.flags, FusedState::FLAG_VALID);
        assert!(!p.coasting(450 * MS));
        // Recovered: no coasting until 150 ms after the update.
        assert_eq!(
            ticks(&mut p, 300 * MS, 460 * MS, 10 * MS),
            Vec::<u64>::new()
        );
        assert_eq!(ticks(&mut p, 460 * MS, 470 * MS, 10 * MS), [460 * MS]);
    }

    #[test]
    fn no_coasting_state_no_output() {
        let cfg = OutputPolicyConfig::default();
        let mut p = OutputPolicy::new(&cfg, 0, 0).unwrap();
        assert!(p.on_tick(200 * MS, None, || None).is_none());
        // Not counted as a coasting output: the next tick with a state publishes.
        assert!(p.on_tick(210 * MS, Some(MS), || coast(210 * MS)).is_some());
    }

    #[test]
    fn stale_ins_flags_outputs_until_it_recovers() {
        let cfg = OutputPolicyConfig::default();
        let mut p = OutputPolicy::new(&cfg, 0, 0).unwrap();
        assert!(!p.stale());
        // No INS state yet: stale.
        assert!(p.on_tick(10 * MS, None, || None).is_none());
        assert!(p.stale());
        // Fresh, then older than 250 ms.
        p.on_tick(20 * MS, Some(250 * MS), || None);
        assert!(!p.stale());
        p.on_tick(30 * MS, Some(251 * MS), || None);
        assert!(p.stale());
        let s = p.on_update(state(40 * MS), 40 * MS);
        assert_eq!(s.header.flags, FusedState::FLAG_STALE);
        let c = p
            .on_tick(200 * MS, Some(400 * MS), || coast(200 * MS))
            .unwrap();
        assert_eq!(c.header.flags & FusedState::FLAG_VALID, 0);
        assert_ne!(c.header.flags & FusedState::FLAG_STALE, 0);
        assert_ne!(c.header.flags & FusedState::FLAG_DEGRADED, 0);
        // Recovery: fresh INS again, outputs valid again.
        p.on_tick(210 * MS, Some(MS), || None);
        assert!(!p.stale());
        let s = p.on_update(state(220 * MS), 220 * MS);
        assert_eq!(s.header.flags, FusedState::FLAG_VALID);
    }

    #[test]
    fn a_fix_gives_a_uwb_only_pose_only_while_the_ins_is_stale() {
        let cfg = OutputPolicyConfig::default();
        let mut p = OutputPolicy::new(&cfg, 0, 0).unwrap();
        let uwb_only = |t: u64| {
            let mut s = state(t);
            s.header.flags |= FusedState::FLAG_UWB_ONLY;
            Some(s)
        };
        p.on_tick(10 * MS, Some(MS), || None);
        assert!(p.on_fix(|| uwb_only(10 * MS)).is_none());
        p.on_tick(20 * MS, Some(300 * MS), || None);
        let s = p.on_fix(|| uwb_only(20 * MS)).unwrap();
        // Valid, not flagged stale: it rests on no INS state.
        assert_eq!(
            s.header.flags,
            FusedState::FLAG_VALID | FusedState::FLAG_UWB_ONLY
        );
        // It neither stops coasting nor counts as an update.
        assert!(p.coasting(200 * MS));
        p.on_tick(210 * MS, Some(MS), || None);
        assert!(p.on_fix(|| uwb_only(210 * MS)).is_none());
    }

    #[test]
    fn settings_must_be_positive() {
        let mut cfg = OutputPolicyConfig::default();
        assert!(cfg.validate().is_ok());
        cfg.coast_rate_hz = 0.0;
        let e = OutputPolicy::new(&cfg, 0, 0).unwrap_err();
        assert_eq!(e.to_string(), "coast_rate_hz: must be > 0, got 0");
        cfg.coast_rate_hz = 10.0;
        cfg.stale_ins_timeout_s = f64::NAN;
        assert!(cfg.validate().is_err());
    }
}
