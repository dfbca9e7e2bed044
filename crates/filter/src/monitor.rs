//! The divergence monitor every filter shares (the paper's four and the
//! tightly coupled ESKF): a window over the normalised innovation squared
//! (NIS) of the last updates.
//!
//! An update is *inconsistent* when its NIS per measured component exceeds
//! [`MonitorConfig::gate_per_dim`]; the filter has *diverged* when at least
//! [`MonitorConfig::fraction`] of a full window of
//! [`MonitorConfig::window`] updates are inconsistent. A fraction of 0.5 is
//! "the window's median NIS per component above the gate". A window
//! counts updates, whatever they are: a UWB fix (2 or 4 components) for
//! the loose filters, one TDOA difference for the tight one.
//!
//! Measurements the filter rejected outright (its hard gate, or an update
//! that failed) are not in the window: the gate is there to drop outliers,
//! and NLOS brings runs of them. A filter so far off that it rejects
//! everything has no window to show it, so a run of nothing but rejections
//! longer than [`MonitorConfig::max_reject_run_s`] is a divergence too.
//!
//! The monitor only says so; the caller re-initialises the filter (the
//! fusion engine: from agreeing UWB fixes) and calls
//! [`DivergenceMonitor::clear`], so that updates of the diverged filter do
//! not count against the re-initialised one. The window's memory is taken
//! at construction: [`DivergenceMonitor::push`] does not allocate.
//!
//! ```
//! use insuwb_filter::{DivergenceMonitor, MonitorConfig};
//!
//! let cfg = MonitorConfig { window: 4, gate_per_dim: 9.0, fraction: 0.75, max_reject_run_s: 1.0 };
//! let mut m = DivergenceMonitor::new(cfg).unwrap();
//! assert!(!m.push(1.0, 2)); // NIS 0.5 per component: consistent
//! assert!(!m.push(40.0, 2));
//! assert!(!m.push(40.0, 2)); // window not full yet
//! assert!(m.push(40.0, 2)); // 3 of 4 above 9 per component: diverged
//! assert_eq!(m.len(), 0); // the window starts afresh
//! assert!(!m.push_rejected(0.5));
//! assert!(m.push_rejected(1.6)); // nothing but rejections for 1.1 s
//! ```

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Largest [`MonitorConfig::window`].
pub const MAX_MONITOR_WINDOW: usize = 4096;

/// Settings of the [`DivergenceMonitor`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MonitorConfig {
    /// Updates in the window, at most [`MAX_MONITOR_WINDOW`]; 0 disables the
    /// monitor. Default 30 (3 s of fixes at 10 Hz: longer than an NLOS burst).
    pub window: usize,
    /// NIS per measured component above which an update is inconsistent.
    /// Default 16 (4 sigma).
    pub gate_per_dim: f64,
    /// Fraction of a full window that must be inconsistent, in (0, 1].
    /// Default 0.9. 0.5 fires when the window's median NIS per component
    /// exceeds the gate.
    pub fraction: f64,
    /// A run of rejected updates (none applied in between) lasting longer
    /// than this, s, is a divergence; 0 disables. Default 1.
    pub max_reject_run_s: f64,
}

impl Default for MonitorConfig {
    fn default() -> Self {
        Self {
            window: 30,
            gate_per_dim: 16.0,
            fraction: 0.9,
            max_reject_run_s: 1.0,
        }
    }
}

/// Why a [`MonitorConfig`] was refused.
#[derive(Debug, Clone, PartialEq, Error)]
#[error("monitor.{key} must be {allowed}, got {value}")]
pub struct MonitorConfigError {
    /// The offending key (without the `monitor.` prefix).
    pub key: &'static str,
    /// What is allowed.
    pub allowed: &'static str,
    /// Its value.
    pub value: f64,
}

impl MonitorConfig {
    /// Checks every key; the error names the first offending one.
    ///
    /// # Errors
    /// [`MonitorConfigError`] naming the key, the allowed range and the value.
    pub fn validate(&self) -> Result<(), MonitorConfigError> {
        if self.window > MAX_MONITOR_WINDOW {
            return Err(MonitorConfigError {
                key: "window",
                allowed: "in 0..=4096",
                // usize -> f64 is exact up to 2^53; beyond, close enough for a message.
                #[allow(clippy::cast_precision_loss)]
                value: self.window as f64,
            });
        }
        let g = self.gate_per_dim;
        if !(g.is_finite() && g > 0.0) {
            return Err(MonitorConfigError {
                key: "gate_per_dim",
                allowed: "finite and > 0",
                value: g,
            });
        }
        let f = self.fraction;
        if !(f.is_finite() && f > 0.0 && f <= 1.0) {
            return Err(MonitorConfigError {
                key: "fraction",
                allowed: "in (0, 1]",
                value: f,
            });
        }
        let r = self.max_reject_run_s;
        if !(r.is_finite() && r >= 0.0) {
            return Err(MonitorConfigError {
                key: "max_reject_run_s",
                allowed: "finite and >= 0",
                value: r,
            });
        }
        Ok(())
    }
}

/// The windowed NIS consistency check (see the [module](self) docs).
#[derive(Debug, Clone)]
pub struct DivergenceMonitor {
    cfg: MonitorConfig,
    /// Whether each of the last updates (at most `window`) was inconsistent.
    hist: VecDeque<bool>,
    /// How many of them were.
    bad: usize,
    /// Time of the first of the rejections since the last applied update, s.
    reject_run_start_s: Option<f64>,
}

impl DivergenceMonitor {
    /// A monitor with an empty window.
    ///
    /// # Errors
    /// [`MonitorConfigError`] when `cfg` does not validate.
    pub fn new(cfg: MonitorConfig) -> Result<Self, MonitorConfigError> {
        cfg.validate()?;
        Ok(Self {
            hist: VecDeque::with_capacity(cfg.window),
            cfg,
            bad: 0,
            reject_run_start_s: None,
        })
    }

    /// A monitor that never fires (window 0, no rejection runs).
    #[must_use]
    pub fn disabled() -> Self {
        Self {
            cfg: MonitorConfig {
                window: 0,
                max_reject_run_s: 0.0,
                ..MonitorConfig::default()
            },
            hist: VecDeque::new(),
            bad: 0,
            reject_run_start_s: None,
        }
    }

    /// Records an applied update of `dim` components and NIS `nis`; it ends
    /// a run of rejections. True when the window says the
    /// filter diverged, after which the monitor starts afresh. An update
    /// without components (`dim` 0, e.g. a measurement the filter skipped)
    /// or with a NIS that is not finite is not counted.
    pub fn push(&mut self, nis: f64, dim: u32) -> bool {
        if dim == 0 || !nis.is_finite() {
            return false;
        }
        self.reject_run_start_s = None;
        let w = self.cfg.window;
        if w == 0 {
            return false;
        }
        let bad = nis / f64::from(dim) > self.cfg.gate_per_dim;
        if self.hist.len() >= w && self.hist.pop_front() == Some(true) {
            self.bad = self.bad.saturating_sub(1);
        }
        self.hist.push_back(bad);
        self.bad += usize::from(bad);
        // Counts up to MAX_MONITOR_WINDOW: exact in f64.
        #[allow(clippy::cast_precision_loss)]
        let diverged = self.hist.len() >= w && self.bad as f64 >= self.cfg.fraction * w as f64;
        if diverged {
            self.clear();
        }
        diverged
    }

    /// Records a measurement at `t_s` (s) that the filter rejected outright
    /// (not in the window); true when nothing but rejections came for
    /// longer than `max_reject_run_s`, after which the monitor starts afresh.
    pub fn push_rejected(&mut self, t_s: f64) -> bool {
        let max = self.cfg.max_reject_run_s;
        if max <= 0.0 || !t_s.is_finite() {
            return false;
        }
        let t0 = *self.reject_run_start_s.get_or_insert(t_s);
        let diverged = t_s - t0 > max;
        if diverged {
            self.clear();
        }
        diverged
    }

    /// Empties the window and ends a run of rejections (after the filter
    /// was re-initialised).
    pub fn clear(&mut self) {
        self.hist.clear();
        self.bad = 0;
        self.reject_run_start_s = None;
    }

    /// Updates in the window.
    #[must_use]
    pub fn len(&self) -> usize {
        self.hist.len()
    }

    /// Whether the window holds no update.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.hist.is_empty()
    }

    /// Inconsistent updates in the window.
    #[must_use]
    pub fn inconsistent(&self) -> usize {
        self.bad
    }

    /// Whether the window holds `window` updates (never, when disabled).
    #[must_use]
    pub fn is_full(&self) -> bool {
        self.cfg.window > 0 && self.hist.len() >= self.cfg.window
    }

    /// The settings.
    #[must_use]
    pub fn config(&self) -> &MonitorConfig {
        &self.cfg
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    fn monitor(window: usize, gate_per_dim: f64, fraction: f64) -> DivergenceMonitor {
        DivergenceMonitor::new(MonitorConfig {
            window,
            gate_per_dim,
            fraction,
            max_reject_run_s: 1.0,
        })
        .unwrap()
    }

    /// Nothing fires before the window is full, however bad the updates.
    #[test]
    fn a_window_must_be_full() {
        let mut m = monitor(10, 9.0, 0.7);
        for k in 0..9 {
            assert!(!m.push(1e6, 1), "update {k}");
            assert!(!m.is_full());
        }
        assert_eq!((m.len(), m.inconsistent()), (9, 9));
        assert!(m.push(1e6, 1));
    }

    /// The gate is per component: a 4-component update with NIS 40 is 10
    /// per component, one with NIS 30 is 7.5.
    #[test]
    fn the_gate_is_per_component() {
        let mut m = monitor(3, 9.0, 1.0);
        assert!(!m.push(40.0, 4));
        assert!(!m.push(30.0, 4));
        assert_eq!(m.inconsistent(), 1);
        assert!(!m.push(40.0, 4));
        // The window slides: [bad, good, bad] then [good, bad, bad].
        assert!(!m.push(40.0, 4));
        assert_eq!((m.len(), m.inconsistent()), (3, 2));
        assert!(m.push(40.0, 4));
    }

    /// The fraction is of the full window, reached exactly: 7 of 10 fires at
    /// 0.7, not at 0.71; the oldest update leaves as a new one comes.
    #[test]
    fn the_fraction_of_a_sliding_window() {
        for (fraction, fires) in [(0.7, true), (0.71, false)] {
            let mut m = monitor(10, 9.0, fraction);
            let mut fired = false;
            for k in 0..10 {
                fired |= m.push(if k < 3 { 1.0 } else { 10.0 }, 1);
            }
            assert_eq!(fired, fires, "fraction {fraction}");
        }
        // 6 of 10, then the good ones slide out one by one.
        let mut m = monitor(10, 9.0, 0.7);
        for k in 0..10 {
            assert!(!m.push(if k < 4 { 1.0 } else { 10.0 }, 1));
        }
        assert!(m.push(10.0, 1), "7 of the last 10");
    }

    /// A fraction of 0.5 is the median of the window above the gate: with
    /// an odd window of 5, 3 inconsistent updates are needed.
    #[test]
    fn half_the_window_is_the_median() {
        let mut m = monitor(5, 9.0, 0.5);
        for nis in [1.0, 10.0, 10.0, 1.0] {
            assert!(!m.push(nis, 1));
        }
        assert!(!m.push(1.0, 1), "2 of 5: the median is below the gate");
        assert!(m.push(10.0, 1), "3 of 5: the median is above");
    }

    /// After a trigger, and after `clear` (the filter re-initialised), the
    /// window starts afresh: updates before it do not count.
    #[test]
    fn the_window_restarts_after_a_trigger_and_a_clear() {
        let mut m = monitor(4, 9.0, 0.75);
        for _ in 0..3 {
            assert!(!m.push(100.0, 1));
        }
        assert!(m.push(100.0, 1));
        assert!(m.is_empty());
        for _ in 0..3 {
            assert!(!m.push(100.0, 1));
        }
        m.clear();
        assert_eq!((m.len(), m.inconsistent()), (0, 0));
        for _ in 0..3 {
            assert!(!m.push(100.0, 1));
        }
        assert!(m.push(100.0, 1), "a full window after the clear");
    }

    /// Updates without components or with a non-finite NIS are not counted;
    /// a disabled monitor never fires.
    #[test]
    fn what_is_not_counted() {
        let mut m = monitor(2, 9.0, 1.0);
        assert!(!m.push(100.0, 0));
        assert!(!m.push(f64::NAN, 1));
        assert!(!m.push(f64::INFINITY, 1));
        assert!(m.is_empty());
        let mut off = monitor(0, 9.0, 1.0);
        let mut d = DivergenceMonitor::disabled();
        for k in 0..100 {
            assert!(!off.push(1e9, 1));
            assert!(!d.push(1e9, 1));
            assert!(!d.push_rejected(f64::from(k)));
        }
        assert!(!off.is_full() && off.is_empty());
    }

    /// Rejections are not in the window; nothing but rejections for longer
    /// than `max_reject_run_s` fires; an applied update, a trigger or a
    /// clear ends the run; a measurement the filter skipped (`dim` 0) does
    /// not.
    #[test]
    fn a_run_of_rejections() {
        let mut m = monitor(3, 9.0, 1.0);
        assert!(!m.push(100.0, 1));
        for k in 0..=10 {
            assert!(!m.push_rejected(5.0 + 0.1 * f64::from(k)), "{k}");
        }
        assert_eq!((m.len(), m.inconsistent()), (1, 1));
        assert!(!m.push(100.0, 0), "a skipped measurement");
        assert!(m.push_rejected(6.05), "1.05 s of rejections");
        assert!(m.is_empty());
        // The run starts afresh after the trigger ...
        assert!(!m.push_rejected(6.1));
        assert!(!m.push_rejected(7.0));
        // ... and after an applied update, and after a clear.
        assert!(!m.push(1.0, 1));
        assert!(!m.push_rejected(7.2));
        assert!(!m.push_rejected(8.1));
        m.clear();
        assert!(!m.push_rejected(8.5));
        assert!(!m.push_rejected(9.4));
        assert!(m.push_rejected(9.6));
        // 0 disables it.
        let mut off = DivergenceMonitor::new(MonitorConfig {
            max_reject_run_s: 0.0,
            ..MonitorConfig::default()
        })
        .unwrap();
        assert!((0..100).all(|k| !off.push_rejected(f64::from(k))));
    }

    #[test]
    fn validate_names_the_key() {
        MonitorConfig::default().validate().unwrap();
        let e = |c: MonitorConfig| c.validate().unwrap_err().to_string();
        assert_eq!(
            e(MonitorConfig {
                window: 5000,
                ..MonitorConfig::default()
            }),
            "monitor.window must be in 0..=4096, got 5000"
        );
        assert_eq!(
            e(MonitorConfig {
                fraction: 0.0,
                ..MonitorConfig::default()
            }),
            "monitor.fraction must be in (0, 1], got 0"
        );
        assert!(e(MonitorConfig {
            fraction: f64::NAN,
            ..MonitorConfig::default()
        })
        .starts_with("monitor.fraction"));
        assert!(e(MonitorConfig {
            gate_per_dim: -1.0,
            ..MonitorConfig::default()
        })
        .starts_with("monitor.gate_per_dim"));
        assert!(e(MonitorConfig {
            max_reject_run_s: f64::INFINITY,
            ..MonitorConfig::default()
        })
        .starts_with("monitor.max_reject_run_s"));
        assert!(DivergenceMonitor::new(MonitorConfig {
            window: 5000,
            ..MonitorConfig::default()
        })
        .is_err());
        let c: MonitorConfig = serde_json::from_str(r#"{"window":10}"#).unwrap();
        assert_eq!((c.window, c.fraction), (10, 0.9));
        assert!(serde_json::from_str::<MonitorConfig>(r#"{"nis_window":10}"#).is_err());
    }
}
