//! Scenario files: the simulator's `[sim]` table and the `[fusion]` settings
//! of the run, built in by name (`config/scenarios/`) or read from a file.

use crate::config::FusionConfig;
use insuwb_sim::Scenario;
use serde::{Deserialize, Serialize};

/// A scenario file: what to simulate and how to fuse it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct ScenarioFile {
    /// The simulation.
    pub sim: Scenario,
    /// The fusion settings (INS, fix builder, model, filters).
    #[serde(default)]
    pub fusion: FusionConfig,
}

/// Why a scenario could not be loaded or simulated.
#[derive(Debug, thiserror::Error)]
pub enum ScenarioError {
    /// The file did not parse.
    #[error(transparent)]
    Config(#[from] insuwb_config::ConfigError),
    /// The scenario is invalid.
    #[error("{origin}: {message}")]
    Invalid {
        /// The file.
        origin: String,
        /// What is wrong (names the key).
        message: String,
    },
    /// The simulation failed.
    #[error("simulation: {0}")]
    Sim(insuwb_sim::SimError),
}

impl From<insuwb_sim::SimError> for ScenarioError {
    fn from(e: insuwb_sim::SimError) -> Self {
        Self::Sim(e)
    }
}

impl ScenarioFile {
    /// Parses and validates a scenario file's text.
    ///
    /// # Errors
    /// Parse errors name the origin and key; invalid values name the key.
    pub fn from_str(text: &str, origin: &str) -> Result<Self, ScenarioError> {
        let f: Self = insuwb_config::load_str(text, origin)?;
        f.sim.validate().map_err(|e| ScenarioError::Invalid {
            origin: origin.to_owned(),
            message: e.to_string(),
        })?;
        Ok(f)
    }

    /// Loads a built-in scenario by name, or a file by path.
    ///
    /// # Errors
    /// Unknown name, unreadable file, or an invalid scenario.
    pub fn load(name_or_path: &str) -> Result<Self, ScenarioError> {
        let path = std::path::Path::new(name_or_path);
        if path.extension().is_some_and(|e| e == "toml") || path.exists() {
            let text = insuwb_config::read_text(path)?;
            return Self::from_str(&text, name_or_path);
        }
        let b = insuwb_config::builtin("scenario", name_or_path)?;
        Self::from_str(b.text, b.origin)
    }

    /// The fusion config for one Monte-Carlo run: the INS starts from the
    /// truth plus the scenario's initial errors drawn with `seed`.
    ///
    /// # Errors
    /// An invalid scenario.
    pub fn fusion_for_seed(&self, seed: u64) -> Result<FusionConfig, ScenarioError> {
        let init = self.sim.initial_ins_state(seed)?;
        let mut cfg = self.fusion.clone();
        cfg.ins.init.pos_m = init.pos_m;
        cfg.ins.init.vel_mps = init.vel_mps;
        cfg.ins.init.yaw_rad = init.yaw_rad;
        Ok(cfg)
    }

    /// Simulates the scenario with `seed`.
    ///
    /// # Errors
    /// A simulation failure.
    pub fn simulate(&self, seed: u64) -> Result<insuwb_sim::SimOutput, ScenarioError> {
        Ok(insuwb_sim::simulate(&self.sim, seed)?)
    }
}

/// The `[fusion]` table of a config text (a robot's fusion file, a log's
/// `fusion_config` metadata), every other table ignored; defaults where it
/// has none.
///
/// # Errors
/// [`insuwb_config::ConfigError`] naming `origin`, the key and the line.
pub fn fusion_table(text: &str, origin: &str) -> Result<FusionConfig, insuwb_config::ConfigError> {
    #[derive(Deserialize)]
    struct FusionOnly {
        #[serde(default)]
        fusion: FusionConfig,
    }
    Ok(insuwb_config::load_str::<FusionOnly>(text, origin)?.fusion)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_fusion_table_alone_is_read_and_its_errors_name_file_and_key() {
        let text = "[sim]\nname = \"x\"\n[other]\nanything = 1\n[fusion.fix]\nperiod_s = 0.2\n";
        let f = fusion_table(text, "f.toml");
        assert!(
            matches!(&f, Ok(c) if (c.fix.period_s - 0.2).abs() < 1e-12),
            "{f:?}"
        );
        assert!(matches!(fusion_table("[sim]\n", "f.toml"), Ok(c) if c == FusionConfig::default()));
        let bad = fusion_table("[fusion.fix]\nperiod_z = 0.2\n", "f.toml");
        let msg = bad
            .map(|_| ())
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(msg.contains("f.toml") && msg.contains("period_z"), "{msg}");
    }
}
