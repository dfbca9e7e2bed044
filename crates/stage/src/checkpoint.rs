//! A stage's checkpoint file: TOML in the run directory, written whole
//! (a temporary file renamed over the old one, so a reader never sees half a
//! checkpoint) and read back by the stage's next generation.

use std::path::Path;

use anyhow::{Context, Result};
use serde::{de::DeserializeOwned, Serialize};

/// Writes `value` to `path` through `path` with the extension `tmp`.
///
/// # Errors
/// Serialisation, or the file cannot be written or renamed (the message names it).
pub fn write<T: Serialize>(path: &Path, value: &T) -> Result<()> {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, toml::to_string(value)?).with_context(|| format!("{}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("{}", path.display()))?;
    Ok(())
}

/// The checkpoint at `path`; `None` when it is missing or does not parse.
#[must_use]
pub fn read<T: DeserializeOwned>(path: &Path) -> Option<T> {
    toml::from_str(&std::fs::read_to_string(path).ok()?).ok()
}
