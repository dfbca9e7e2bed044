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
//! longer than [`MonitorConfig::max_reject_run_s`] is a divergence too,
//! and so is a share of at least [`MonitorConfig::outlier_fraction`]
//! outliers (rejected, or applied but inconsistent) among the measurements
//! of the last [`MonitorConfig::outlier_window_s`]: a filter thrown off by
//! metres still lets through the odd measurement whose innovation happens
//! to be small, which ends a run, where the radio's outliers (one anchor
//! in NLOS) take only the measurements that anchor is in. The window is
//! in time, not in updates: 10 TDOA differences are 25 ms at TDOA2's 400
//! Hz, 10 fixes 1 s.
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
//! let cfg = MonitorConfig {
//!     window: 4,
//!     gate_per_dim: 9.0,
//!     fraction: 0.75,
//!     max_reject_run_s: 1.0,
//!     outlier_window_s: 0.5,
//!     outlier_fraction: 0.8,
//! };
//! let mut m = DivergenceMonitor::new(cfg).unwrap();
//! assert!(!m.push(0.0, 1.0, 2)); // NIS 0.5 per component: consistent
//! assert!(!m.push(0.1, 40.0, 2));
//! assert!(!m.push(0.2, 40.0, 2)); // window not full yet
//! assert!(m.push(0.3, 40.0, 2)); // 3 of 4 above 9 per component: diverged
//! assert_eq!(m.len(), 0); // the window starts afresh
//! assert!(!m.push_rejected(0.5));
//! assert!(m.push_rejected(1.6)); // nothing but rejections for 1.1 s
//! // 10 of 11 measurements over 0.5 s rejected: diverged, though one passed.
//! let fired: Vec<bool> = (0..=10)
//!     .map(|k| {
//!         let t = 2.0 + 0.05 * f64::from(k);
//!         if k == 3 { m.push(t, 1.0, 1) } else { m.push_rejected(t) }
//!     })
//!     .collect();
//! assert_eq!(fired.iter().position(|&f| f), Some(10));
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
    /// Length of the time window over which the share of outliers (rejected
    /// measurements, and applied ones above `gate_per_dim`) is counted, s;
    /// 0 disables. Default 0.
    pub outlier_window_s: f64,
    /// Share of outliers among the measurements of the last
    /// `outlier_window_s` at or above which the filter has diverged, in
    /// (0, 1]. Counted once the measurements since the last clear span the
    /// window and it holds at least [`MIN_OUTLIER_WINDOW_LEN`] of them.
    /// Default 0.9.
    pub outlier_fraction: f64,
}

impl Default for MonitorConfig {
    fn default() -> Self {
        Self {
            window: 30,
            gate_per_dim: 16.0,
            fraction: 0.9,
            max_reject_run_s: 1.0,
            outlier_window_s: 0.0,
            outlier_fraction: 0.9,
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
        let check = |key: &'static str, value: f64, allowed: &'static str, ok: bool| {
            if value.is_finite() && ok {
                Ok(())
            } else {
                Err(MonitorConfigError {
                    key,
                    allowed,
                    value,
                })
            }
        };
        let in_unit = |f: f64| f > 0.0 && f <= 1.0;
        let g = self.gate_per_dim;
        check("gate_per_dim", g, "finite and > 0", g > 0.0)?;
        check(
            "fraction",
            self.fraction,
            "in (0, 1]",
            in_unit(self.fraction),
        )?;
        let r = self.max_reject_run_s;
        check("max_reject_run_s", r, "finite and >= 0", r >= 0.0)?;
        let w = self.outlier_window_s;
        check("outlier_window_s", w, "finite and >= 0", w >= 0.0)?;
        let f = self.outlier_fraction;
        check("outlier_fraction", f, "in (0, 1]", in_unit(f))?;
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
    /// Time and whether an outlier of the measurements within the last
    /// `outlier_window_s` (at most [`MAX_OUTLIER_WINDOW_LEN`]).
    recent: VecDeque<(f64, bool)>,
    /// How many of them were outliers.
    recent_outliers: usize,
    /// Time of the first measurement since the last clear, s.
    recent_since_s: Option<f64>,
}

/// Most measurements the outliers' time window holds (10 s of TDOA2's 400
/// differences per second); older ones leave early.
pub const MAX_OUTLIER_WINDOW_LEN: usize = 4096;

/// Fewest measurements the outliers' time window must hold for its share
/// to count: two of three fixes are no evidence of a divergence.
pub const MIN_OUTLIER_WINDOW_LEN: usize = 10;

impl DivergenceMonitor {
    /// A monitor with an empty window.
    ///
    /// # Errors
    /// [`MonitorConfigError`] when `cfg` does not validate.
    pub fn new(cfg: MonitorConfig) -> Result<Self, MonitorConfigError> {
        cfg.validate()?;
        Ok(Self::with_config(cfg))
    }

    /// A monitor that never fires (window 0, no rejection runs, no
    /// outliers' share).
    #[must_use]
    pub fn disabled() -> Self {
        Self::with_config(MonitorConfig {
            window: 0,
            max_reject_run_s: 0.0,
            outlier_window_s: 0.0,
            ..MonitorConfig::default()
        })
    }

    /// A monitor with empty windows for `cfg`, taken as valid.
    fn with_config(cfg: MonitorConfig) -> Self {
        let recent_len = if cfg.outlier_window_s > 0.0 {
            MAX_OUTLIER_WINDOW_LEN
        } else {
            0
        };
        Self {
            hist: VecDeque::with_capacity(cfg.window),
            cfg,
            bad: 0,
            reject_run_start_s: None,
            recent: VecDeque::with_capacity(recent_len),
            recent_outliers: 0,
            recent_since_s: None,
        }
    }

    /// Records an update at `t_s` (s) of `dim` components and NIS `nis`,
    /// applied; it ends a run of rejections. True when the window (or the
    /// outliers' share) says the filter diverged, after which the monitor
    /// starts afresh. An update without components (`dim` 0, e.g. a
    /// measurement the filter skipped) or with a NIS that is not finite is
    /// not counted.
    pub fn push(&mut self, t_s: f64, nis: f64, dim: u32) -> bool {
        if dim == 0 || !nis.is_finite() {
            return false;
        }
        self.reject_run_start_s = None;
        let bad = nis / f64::from(dim) > self.cfg.gate_per_dim;
        if self.note(t_s, bad) {
            self.clear();
            return true;
        }
        let w = self.cfg.window;
        if w == 0 {
            return false;
        }
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
    /// (not in the window, an outlier of the share); true when nothing but
    /// rejections came for longer than `max_reject_run_s`, or the outliers'
    /// share says the filter diverged, after which the monitor starts
    /// afresh.
    pub fn push_rejected(&mut self, t_s: f64) -> bool {
        if !t_s.is_finite() {
            return false;
        }
        let max = self.cfg.max_reject_run_s;
        let mut diverged = self.note(t_s, true);
        if max > 0.0 {
            let t0 = *self.reject_run_start_s.get_or_insert(t_s);
            diverged |= t_s - t0 > max;
        }
        if diverged {
            self.clear();
        }
        diverged
    }

    /// Adds a measurement at `t_s` to the outliers' time window, an outlier
    /// when `outlier`; true when their share there reaches
    /// `outlier_fraction` over a full window.
    fn note(&mut self, t_s: f64, outlier: bool) -> bool {
        let span = self.cfg.outlier_window_s;
        if span <= 0.0 || !t_s.is_finite() {
            return false;
        }
        while let Some(&(t, r)) = self.recent.front() {
            if t >= t_s - span && self.recent.len() < MAX_OUTLIER_WINDOW_LEN {
                break;
            }
            self.recent.pop_front();
            self.recent_outliers = self.recent_outliers.saturating_sub(usize::from(r));
        }
        self.recent.push_back((t_s, outlier));
        self.recent_outliers += usize::from(outlier);
        let since = *self.recent_since_s.get_or_insert(t_s);
        // Counts up to MAX_OUTLIER_WINDOW_LEN: exact in f64.
        #[allow(clippy::cast_precision_loss)]
        let share = self.recent_outliers as f64 / self.recent.len() as f64;
        t_s - since >= span
            && self.recent.len() >= MIN_OUTLIER_WINDOW_LEN
            && share >= self.cfg.outlier_fraction
    }

    /// Empties the window and ends a run of rejections (after the filter
    /// was re-initialised).
    pub fn clear(&mut self) {
        self.hist.clear();
        self.bad = 0;
        self.reject_run_start_s = None;
        self.recent.clear();
        self.recent_outliers = 0;
        self.recent_since_s = None;
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
            outlier_window_s: 0.0,
            outlier_fraction: 0.9,
        })
        .unwrap()
    }

    /// Nothing fires before the window is full, however bad the updates.
    #[test]
    fn a_window_must_be_full() {
        let mut m = monitor(10, 9.0, 0.7);
        for k in 0..9 {
            assert!(!m.push(0.0, 1e6, 1), "update {k}");
            assert!(!m.is_full());
        }
        assert_eq!((m.len(), m.inconsistent()), (9, 9));
        assert!(m.push(0.0, 1e6, 1));
    }

    /// The gate is per component: a 4-component update with NIS 40 is 10
    /// per component, one with NIS 30 is 7.5.
    #[test]
    fn the_gate_is_per_component() {
        let mut m = monitor(3, 9.0, 1.0);
        assert!(!m.push(0.0, 40.0, 4));
        assert!(!m.push(0.0, 30.0, 4));
        assert_eq!(m.inconsistent(), 1);
        assert!(!m.push(0.0, 40.0, 4));
        // The window slides: [bad, good, bad] then [good, bad, bad].
        assert!(!m.push(0.0, 40.0, 4));
        assert_eq!((m.len(), m.inconsistent()), (3, 2));
        assert!(m.push(0.0, 40.0, 4));
    }

    /// The fraction is of the full window, reached exactly: 7 of 10 fires at
    /// 0.7, not at 0.71; the oldest update leaves as a new one comes.
    #[test]
    fn the_fraction_of_a_sliding_window() {
        for (fraction, fires) in [(0.7, true), (0.71, false)] {
            let mut m = monitor(10, 9.0, fraction);
            let mut fired = false;
            for k in 0..10 {
                fired |= m.push(0.0, if k < 3 { 1.0 } else { 10.0 }, 1);
            }
            assert_eq!(fired, fires, "fraction {fraction}");
        }
        // 6 of 10, then the good ones slide out one by one.
        let mut m = monitor(10, 9.0, 0.7);
        for k in 0..10 {
            assert!(!m.push(0.0, if k < 4 { 1.0 } else { 10.0 }, 1));
        }
        assert!(m.push(0.0, 10.0, 1), "7 of the last 10");
    }

    /// A fraction of 0.5 is the median of the window above the gate: with
    /// an odd window of 5, 3 inconsistent updates are needed.
    #[test]
    fn half_the_window_is_the_median() {
        let mut m = monitor(5, 9.0, 0.5);
        for nis in [1.0, 10.0, 10.0, 1.0] {
            assert!(!m.push(0.0, nis, 1));
        }
        assert!(!m.push(0.0, 1.0, 1), "2 of 5: the median is below the gate");
        assert!(m.push(0.0, 10.0, 1), "3 of 5: the median is above");
    }

    /// After a trigger, and after `clear` (the filter re-initialised), the
    /// window starts afresh: updates before it do not count.
    #[test]
    fn the_window_restarts_after_a_trigger_and_a_clear() {
        let mut m = monitor(4, 9.0, 0.75);
        for _ in 0..3 {
            assert!(!m.push(0.0, 100.0, 1));
        }
        assert!(m.push(0.0, 100.0, 1));
        assert!(m.is_empty());
        for _ in 0..3 {
            assert!(!m.push(0.0, 100.0, 1));
        }
        m.clear();
        assert_eq!((m.len(), m.inconsistent()), (0, 0));
        for _ in 0..3 {
            assert!(!m.push(0.0, 100.0, 1));
        }
        assert!(m.push(0.0, 100.0, 1), "a full window after the clear");
    }

    /// Updates without components or with a non-finite NIS are not counted;
    /// a disabled monitor never fires.
    #[test]
    fn what_is_not_counted() {
        let mut m = monitor(2, 9.0, 1.0);
        assert!(!m.push(0.0, 100.0, 0));
        assert!(!m.push(0.0, f64::NAN, 1));
        assert!(!m.push(0.0, f64::INFINITY, 1));
        assert!(m.is_empty());
        let mut off = monitor(0, 9.0, 1.0);
        let mut d = DivergenceMonitor::disabled();
        for k in 0..100 {
            assert!(!off.push(0.0, 1e9, 1));
            assert!(!d.push(0.0, 1e9, 1));
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
        assert!(!m.push(0.0, 100.0, 1));
        for k in 0..=10 {
            assert!(!m.push_rejected(5.0 + 0.1 * f64::from(k)), "{k}");
        }
        assert_eq!((m.len(), m.inconsistent()), (1, 1));
        assert!(!m.push(0.0, 100.0, 0), "a skipped measurement");
        assert!(m.push_rejected(6.05), "1.05 s of rejections");
        assert!(m.is_empty());
        // The run starts afresh after the trigger ...
        assert!(!m.push_rejected(6.1));
        assert!(!m.push_rejected(7.0));
        // ... and after an applied update, and after a clear.
        assert!(!m.push(0.0, 1.0, 1));
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

    /// The outliers' share is over a time window: rejections and
    /// inconsistent updates count, a consistent update does not end it as
    /// it ends a run; nothing fires before the measurements span the window,
    /// old ones leave it, and a clear starts it afresh.
    #[test]
    fn a_share_of_outliers_over_time() {
        let mut m = DivergenceMonitor::new(MonitorConfig {
            window: 0,
            gate_per_dim: 9.0,
            fraction: 1.0,
            max_reject_run_s: 0.0,
            outlier_window_s: 1.0,
            outlier_fraction: 0.75,
        })
        .unwrap();
        // Every fourth update consistent: 3 of 4 are outliers, half of them
        // rejected, half applied beyond the gate.
        let mut fired_at = None;
        for k in 0..40 {
            let t = 0.1 * f64::from(k);
            let fired = match k % 4 {
                0 => m.push(t, 1.0, 1),
                1 => m.push(t, 10.0, 1),
                _ => m.push_rejected(t),
            };
            if fired {
                fired_at = Some(k);
                break;
            }
        }
        // At 1.0 s (k = 10) the window is spanned and 8 of its 11 updates are
        // outliers (0.73); at 1.1 s the first consistent update has left it.
        assert_eq!(fired_at, Some(11));
        assert_eq!(m.len(), 0);
        // A share below the fraction never fires.
        let mut m2 = DivergenceMonitor::new(MonitorConfig {
            outlier_window_s: 1.0,
            outlier_fraction: 0.75,
            max_reject_run_s: 0.0,
            ..MonitorConfig::default()
        })
        .unwrap();
        for k in 0..400 {
            let t = 0.01 * f64::from(k);
            let fired = if k % 3 == 0 {
                m2.push(t, 1.0, 1)
            } else if k % 3 == 1 {
                m2.push_rejected(t)
            } else {
                m2.push(t, 20.0, 1)
            };
            assert!(!fired, "2 of 3 outliers fired at {k}");
        }
        // After a clear the window must be spanned again ...
        m2.clear();
        for k in 0..10 {
            assert!(!m2.push_rejected(10.0 + 0.1 * f64::from(k)), "{k}");
        }
        assert!(m2.push_rejected(11.0));
        // ... and hold MIN_OUTLIER_WINDOW_LEN measurements: 3 fixes do not.
        for t in [20.0, 20.5, 21.5] {
            assert!(!m2.push_rejected(t));
        }
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
        assert!(e(MonitorConfig {
            outlier_window_s: -1.0,
            ..MonitorConfig::default()
        })
        .starts_with("monitor.outlier_window_s"));
        assert_eq!(
            e(MonitorConfig {
                outlier_fraction: 1.5,
                ..MonitorConfig::default()
            }),
            "monitor.outlier_fraction must be in (0, 1], got 1.5"
        );
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
