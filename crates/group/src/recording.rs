//! What an emulated IMU and UWB positioning system measured: a simulated
//! scenario or a recorded log turned into the [`Recording`] a real IMU and
//! a real UWB system would have produced, for `insuwb_devices::play` to
//! encode and `insuwb_devices::emulator::Player` to play.
//!
//! - **Positions, not TDOA.** A UWB positioning system reports positions.
//!   They are the fixes the UWB driver would compute from the scenario's or
//!   the log's TDOA: `insuwb_uwb::fix::FixBuilder` with the `[fusion.fix]`
//!   settings the group would use (the scenario's; the log's
//!   `fusion_config` metadata, else the defaults), fed measurement by
//!   measurement as the driver feeds it. A log without TDOA but with
//!   recorded fixes plays those.
//! - **Logs.** Times in a log are shifted back by whole seconds so that the
//!   earliest sample lies in the first second (a log the logger recorded
//!   holds CLOCK_MONOTONIC times); whole seconds keep the fix epochs on
//!   their grid.

use std::path::Path;

use insuwb_log::Record;
use insuwb_msg::{GroundTruth, ImuSample, UwbFix, UwbTdoa};
use insuwb_uwb::fix::{FixBuilder, FixConfig, FixConfigError};

/// What an emulated IMU and UWB system measured, times in ns since the
/// start of the recording.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Recording {
    /// What was played (`nlos-long (seed 1)`, a log's path).
    pub name: String,
    /// IMU samples, in time order.
    pub imu: Vec<ImuSample>,
    /// UWB position fixes, in time order.
    pub fixes: Vec<UwbFix>,
    /// Ground truth (simulation, or a log that has it), in time order.
    pub truth: Vec<GroundTruth>,
}

impl Recording {
    /// Time of the last sample (IMU or fix), ns.
    #[must_use]
    pub fn end_ns(&self) -> u64 {
        let imu = self.imu.last().map_or(0, |s| s.header.meas_time_ns);
        let fix = self.fixes.last().map_or(0, |s| s.header.meas_time_ns);
        imu.max(fix)
    }
}

/// Why a recording could not be made.
#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    /// The scenario did not load or simulate.
    #[error("scenario {name:?}: {error}")]
    Scenario {
        /// The name or file given.
        name: String,
        /// What went wrong.
        error: insuwb_fusion::scenario::ScenarioError,
    },
    /// The log could not be read.
    #[error("{path}: {message}")]
    Log {
        /// The file.
        path: String,
        /// What went wrong.
        message: String,
    },
    /// The fix builder settings do not validate.
    #[error("fix: {0}")]
    FixConfig(FixConfigError),
}

impl From<FixConfigError> for LoadError {
    fn from(e: FixConfigError) -> Self {
        Self::FixConfig(e)
    }
}

/// The fixes the UWB driver computes from `tdoa`: each measurement pushed
/// into a [`FixBuilder`] in order, every fix it returns kept.
///
/// # Errors
/// [`FixConfigError`] when `cfg` does not validate.
pub fn fixes_from_tdoa(tdoa: &[UwbTdoa], cfg: &FixConfig) -> Result<Vec<UwbFix>, FixConfigError> {
    let mut builder = FixBuilder::new(cfg.clone())?;
    let mut out = Vec::new();
    for m in tdoa {
        if let Ok(Some(f)) = builder.push(m) {
            out.push(f);
        }
    }
    Ok(out)
}

/// Simulates scenario `name` (built-in name or TOML file) with `seed`.
///
/// # Errors
/// [`LoadError::Scenario`], [`LoadError::FixConfig`].
pub fn from_scenario(name: &str, seed: u64) -> Result<Recording, LoadError> {
    let scenario_err = |source| LoadError::Scenario {
        name: name.to_owned(),
        error: source,
    };
    let sc = insuwb_fusion::scenario::ScenarioFile::load(name).map_err(scenario_err)?;
    let fusion = sc.fusion_for_seed(seed).map_err(scenario_err)?;
    let data = sc.simulate(seed).map_err(scenario_err)?;
    let fixes = fixes_from_tdoa(&data.tdoa, &fusion.fix)?;
    Ok(Recording {
        name: format!("{} (seed {seed})", sc.sim.name),
        imu: data.imu,
        fixes,
        truth: data.truth,
    })
}

/// Reads an insuwb log: its IMU samples, its ground truth, and the fixes
/// of its TDOA (or its recorded fixes when it has no TDOA).
///
/// # Errors
/// [`LoadError::Log`], [`LoadError::FixConfig`].
pub fn from_log(path: &Path) -> Result<Recording, LoadError> {
    let log_err = |message: String| LoadError::Log {
        path: path.display().to_string(),
        message,
    };
    let (records, tail, header) = insuwb_log::read_all(path).map_err(|e| log_err(e.to_string()))?;
    if let Some(t) = tail {
        tracing::warn!("{}: {t}", path.display());
    }
    let fix_cfg = match header.meta.entries.get("fusion_config") {
        Some(text) => {
            insuwb_fusion::scenario::fusion_table(text, &path.display().to_string())
                .map_err(|e| log_err(e.to_string()))?
                .fix
        }
        None => FixConfig::default(),
    };
    let mut rec = Recording {
        name: path.display().to_string(),
        ..Recording::default()
    };
    let mut tdoa = Vec::new();
    let mut recorded_fixes = Vec::new();
    for r in records {
        match r {
            Record::Imu(s) => rec.imu.push(s),
            Record::Tdoa(s) => tdoa.push(s),
            Record::Fix(s) => recorded_fixes.push(s),
            Record::Truth(s) => rec.truth.push(s),
            _ => {}
        }
    }
    let first = [
        rec.imu.iter().map(|s| s.header.meas_time_ns).min(),
        tdoa.iter().map(|s| s.header.meas_time_ns).min(),
        recorded_fixes.iter().map(|s| s.header.meas_time_ns).min(),
    ]
    .into_iter()
    .flatten()
    .min()
    .unwrap_or(0);
    let shift = first / 1_000_000_000 * 1_000_000_000;
    let rebase = |t: &mut u64| *t = t.saturating_sub(shift);
    rec.imu
        .iter_mut()
        .for_each(|s| rebase(&mut s.header.meas_time_ns));
    rec.truth
        .iter_mut()
        .for_each(|s| rebase(&mut s.header.meas_time_ns));
    tdoa.iter_mut()
        .for_each(|s| rebase(&mut s.header.meas_time_ns));
    recorded_fixes
        .iter_mut()
        .for_each(|s| rebase(&mut s.header.meas_time_ns));
    rec.imu.sort_by_key(|s| s.header.meas_time_ns);
    rec.truth.sort_by_key(|s| s.header.meas_time_ns);
    tdoa.sort_by_key(|s| s.header.meas_time_ns);
    recorded_fixes.sort_by_key(|s| s.header.meas_time_ns);
    rec.fixes = if tdoa.is_empty() {
        recorded_fixes
    } else {
        fixes_from_tdoa(&tdoa, &fix_cfg)?
    };
    Ok(rec)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

    use super::*;

    #[test]
    fn scenario_fixes_are_what_the_driver_computes() {
        let rec = from_scenario("nlos-long", 1).unwrap();
        let sc = insuwb_fusion::scenario::ScenarioFile::load("nlos-long").unwrap();
        let data = sc.simulate(1).unwrap();
        let cfg = sc.fusion_for_seed(1).unwrap();
        let expected = insuwb_fusion::runner::run_fixes(&data.tdoa, &cfg).unwrap();
        // run_fixes also flushes at the end; the epochs are flagged, so the
        // flush adds nothing.
        assert_eq!(rec.fixes, expected);
        assert_eq!(rec.imu.len(), 6000);
        // 10 Hz for 60 s, less the epochs the NLOS events and the 2 s
        // dropout leave without a fix.
        assert!(
            (500..=600).contains(&rec.fixes.len()),
            "{}",
            rec.fixes.len()
        );
        assert!(rec.end_ns() >= 59_900_000_000);
    }
}
