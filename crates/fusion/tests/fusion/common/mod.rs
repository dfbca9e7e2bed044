//! What the real-flight tests share: the `config/util.toml` preset as
//! `insuwb eval` reads it, the UTIL data directory (`INSUWB_UTIL_DIR`, else
//! `<workspace>/../shared/data/util`; absent: the tests say so and pass,
//! unless `CI` is set, where they fail) and a flight loaded with the preset.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};

use insuwb_data::util::{load_util_flight, ImportOptions, UtilFlight};
use insuwb_fusion::config::FusionConfig;

/// The preset, as `insuwb eval` reads it (`[fusion]`, `[import]`, `[eval]`).
#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Preset {
    #[serde(default)]
    pub fusion: FusionConfig,
    #[serde(default)]
    pub import: ImportOptions,
    #[serde(default)]
    pub eval: Option<toml::Value>,
}

const PRESET: &str = include_str!("../../../../../config/util.toml");

/// `config/util.toml`.
pub fn preset() -> Preset {
    toml::from_str(PRESET).expect("config/util.toml parses as [fusion], [import], [eval]")
}

/// The data directory (checked by the presence of `probe` in it), or `None`
/// (after saying so) when it is absent outside CI.
pub fn data_dir(probe: &str) -> Option<PathBuf> {
    let dir = std::env::var_os("INSUWB_UTIL_DIR").map_or_else(
        || PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/util"),
        PathBuf::from,
    );
    if dir.join(probe).is_file() {
        return Some(dir);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "UTIL data not found at {} (set INSUWB_UTIL_DIR); CI is set, so this fails instead of skipping",
        dir.display()
    );
    eprintln!(
        "SKIPPED: UTIL data not found at {} (set INSUWB_UTIL_DIR to run the real-flight tests)",
        dir.display()
    );
    None
}

/// The flight `log` with its anchor survey, imported with the preset.
pub fn load(dir: &Path, log: &str, anchors: &str, p: &Preset) -> UtilFlight {
    load_util_flight(
        &dir.join(log),
        &dir.join(anchors),
        &insuwb_data::cflog::ParseOptions::default(),
        &p.import,
    )
    .unwrap()
}
