//! Configuration loading and the built-in presets.
//!
//! Every configuration file is TOML. [`load_str`] parses one into the
//! caller's serde type and, on failure, names the file, the line and the key
//! path (`config/robot.toml:29: key 'fusion.filter': unknown variant ...`),
//! so a user can fix a file without reading code. A value the caller refuses
//! after parsing ([`invalid`]) gets the line of its key with
//! [`ConfigError::with_line_in`] ([`key_line`]). The built-in presets and
//! scenarios are compiled into the binary ([`builtin`]), so commands work from
//! any working directory; a `--config FILE` overrides them.
//!
//! ```
//! #[derive(Debug, serde::Deserialize)]
//! struct Cfg { rate_hz: f64 }
//! let c: Cfg = insuwb_config::load_str("rate_hz = 10.0", "inline").unwrap();
//! assert_eq!(c.rate_hz, 10.0);
//! let err = insuwb_config::load_str::<Cfg>("rate_hz = 'x'", "my.toml").unwrap_err();
//! assert!(err.to_string().starts_with("my.toml:1: key 'rate_hz'"));
//! ```
#![warn(missing_docs)]

use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;

/// Why a configuration could not be loaded.
///
/// Each message is whole (file, key, cause) and no variant exposes its
/// cause as [`std::error::Error::source`]: a report that prints the chain
/// (`anyhow`'s `{:#}`) shows each cause once.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("{path}: cannot read: {error}")]
    Read {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        error: std::io::Error,
    },
    /// The TOML is malformed or a key has the wrong type, an unknown name or is missing.
    #[error("{origin}{}: key '{key}': {message}", at_line(*.line))]
    Parse {
        /// The file (or a description of the built-in text).
        origin: String,
        /// Dotted key path, `.` for the document root.
        key: String,
        /// 1-based line of the problem; `None` for malformed TOML, whose
        /// message names the line and the column itself.
        line: Option<usize>,
        /// What the parser said.
        message: String,
    },
    /// A value is syntactically fine but not acceptable.
    #[error("{origin}{}: key '{key}': {message}", at_line(*.line))]
    Invalid {
        /// The file.
        origin: String,
        /// Dotted key path.
        key: String,
        /// 1-based line of the key (or of its nearest table written in the
        /// file), when known.
        line: Option<usize>,
        /// What is wrong with the value.
        message: String,
    },
    /// No built-in configuration of that name.
    #[error("no built-in {kind} named '{name}' (built-in: {known})")]
    UnknownBuiltin {
        /// What was looked for (scenario, preset).
        kind: &'static str,
        /// The name asked for.
        name: String,
        /// The names that exist, comma-separated.
        known: String,
    },
}

/// `:LINE` when the line is known, for the messages.
fn at_line(line: Option<usize>) -> String {
    line.map(|l| format!(":{l}")).unwrap_or_default()
}

impl ConfigError {
    /// This error with the line of its key in `text` (the text it was
    /// found in, see [`key_line`]), for an [`ConfigError::Invalid`] without
    /// one; any other error as it is.
    #[must_use]
    pub fn with_line_in(mut self, text: &str) -> Self {
        if let Self::Invalid {
            key,
            line: line @ None,
            ..
        } = &mut self
        {
            *line = key_line(text, key);
        }
        self
    }
}

/// Parses `text` (from `origin`, used in errors) into `T`, naming the key
/// and the line on failure.
///
/// # Errors
/// [`ConfigError::Parse`] with the dotted key path of the first problem.
pub fn load_str<T: DeserializeOwned>(text: &str, origin: &str) -> Result<T, ConfigError> {
    let de = toml::Deserializer::parse(text).map_err(|e| ConfigError::Parse {
        origin: origin.to_owned(),
        key: ".".to_owned(),
        line: None,
        message: e.to_string().trim().to_owned(),
    })?;
    serde_path_to_error::deserialize(de).map_err(|e| {
        let key = e.path().to_string();
        let e = e.into_inner();
        ConfigError::Parse {
            origin: origin.to_owned(),
            key,
            line: e.span().map(|s| line_of(text, s.start)),
            message: e.message().trim().to_owned(),
        }
    })
}

/// The 1-based line of byte `offset` of `text`.
fn line_of(text: &str, offset: usize) -> usize {
    let before = text.as_bytes().get(..offset).unwrap_or(text.as_bytes());
    before.iter().filter(|&&b| b == b'\n').count() + 1
}

/// The 1-based line where the dotted `key` (`devices.imu.protocol`) is
/// written in the TOML `text`; for a key the file leaves out, the line of
/// the nearest table above it that the file writes (`[devices.imu]`).
/// `None` when the text does not parse or writes none of the path. An
/// index (`optional[2]`) is ignored, and the walk stops at the first value
/// that is not a table.
#[must_use]
pub fn key_line(text: &str, key: &str) -> Option<usize> {
    let root = toml::de::DeTable::parse(text).ok()?;
    let mut table = root.get_ref();
    let mut at = None;
    for part in key.split('.') {
        let name = part.split('[').next().unwrap_or(part);
        let Some((k, v)) = table.iter().find(|(k, _)| k.get_ref().as_ref() == name) else {
            break;
        };
        at = Some(k.span().start);
        match v.get_ref() {
            toml::de::DeValue::Table(t) => table = t,
            _ => break,
        }
    }
    at.map(|offset| line_of(text, offset))
}

/// Reads and parses a TOML file into `T`.
///
/// # Errors
/// [`ConfigError::Read`] when the file cannot be read, else as [`load_str`].
pub fn load_file<T: DeserializeOwned>(path: &Path) -> Result<T, ConfigError> {
    load_str(&read_text(path)?, &path.display().to_string())
}

/// Reads a configuration file's text (for a caller that also needs the
/// text, e.g. for [`ConfigError::with_line_in`]).
///
/// # Errors
/// [`ConfigError::Read`] naming the file.
pub fn read_text(path: &Path) -> Result<String, ConfigError> {
    std::fs::read_to_string(path).map_err(|error| ConfigError::Read {
        path: path.to_owned(),
        error,
    })
}

/// Builds a [`ConfigError::Invalid`] for `origin` and `key`.
///
/// Its line is unknown: [`ConfigError::with_line_in`] finds it.
#[must_use]
pub fn invalid(origin: &str, key: &str, message: impl Into<String>) -> ConfigError {
    ConfigError::Invalid {
        origin: origin.to_owned(),
        key: key.to_owned(),
        line: None,
        message: message.into(),
    }
}

/// A built-in configuration text.
#[derive(Debug, Clone, Copy)]
pub struct Builtin {
    /// Its name (`paper-3.4`, `util`).
    pub name: &'static str,
    /// Where it lives in the source tree, for messages.
    pub origin: &'static str,
    /// The TOML text.
    pub text: &'static str,
}

macro_rules! builtin_file {
    ($name:literal, $path:literal) => {
        Builtin {
            name: $name,
            origin: concat!("<built-in> ", $path),
            text: include_str!(concat!("../../../", $path)),
        }
    };
}

/// The built-in scenarios (`config/scenarios/*.toml`).
pub const SCENARIOS: &[Builtin] = &[
    builtin_file!("paper-3.4", "config/scenarios/paper-3.4.toml"),
    builtin_file!("paper-4.3-static", "config/scenarios/paper-4.3-static.toml"),
    builtin_file!(
        "paper-4.4-dynamic",
        "config/scenarios/paper-4.4-dynamic.toml"
    ),
    builtin_file!("nlos-long", "config/scenarios/nlos-long.toml"),
    builtin_file!("nlos-long-twr", "config/scenarios/nlos-long-twr.toml"),
    builtin_file!("ground-outage", "config/scenarios/ground-outage.toml"),
    builtin_file!("twr-3.4", "config/scenarios/twr-3.4.toml"),
];

/// The built-in presets (`config/*.toml`).
pub const PRESETS: &[Builtin] = &[
    builtin_file!("util", "config/util.toml"),
    builtin_file!("robot", "config/robot.toml"),
];

/// Finds a built-in of `kind` ("scenario" or "preset") by name.
///
/// # Errors
/// [`ConfigError::UnknownBuiltin`] listing the names that exist.
pub fn builtin(kind: &'static str, name: &str) -> Result<&'static Builtin, ConfigError> {
    let list = if kind == "scenario" {
        SCENARIOS
    } else {
        PRESETS
    };
    list.iter()
        .find(|b| b.name == name)
        .ok_or_else(|| ConfigError::UnknownBuiltin {
            kind,
            name: name.to_owned(),
            known: list.iter().map(|b| b.name).collect::<Vec<_>>().join(", "),
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Inner {
        gamma: f64,
    }
    #[derive(Debug, serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Outer {
        filter: Inner,
    }

    #[test]
    fn errors_name_file_and_nested_key() {
        let e = load_str::<Outer>("[filter]\ngamma = 'high'\n", "robot.toml").unwrap_err();
        let s = e.to_string();
        assert!(s.starts_with("robot.toml:2: key 'filter.gamma'"), "{s}");
        let e = load_str::<Outer>("[filter]\ngama = 2.0\n", "robot.toml").unwrap_err();
        assert!(e.to_string().contains("gama"), "{e}");
        let e = load_str::<Outer>("[filter\n", "robot.toml").unwrap_err();
        assert!(e.to_string().starts_with("robot.toml"), "{e}");
    }

    #[test]
    fn the_line_of_a_key_or_of_its_nearest_table() {
        let text = "top = 1\n[a]\nx = 2\n\n[a.b]\ny = [1, 2]\n[c]\nd.e = 3\n";
        assert_eq!(key_line(text, "top"), Some(1));
        assert_eq!(key_line(text, "a.x"), Some(3));
        assert_eq!(key_line(text, "a.b.y"), Some(6));
        assert_eq!(key_line(text, "a.b.y[1]"), Some(6));
        assert_eq!(key_line(text, "a.b.missing"), Some(5), "its table");
        assert_eq!(key_line(text, "c.d.e"), Some(8), "dotted key");
        assert_eq!(key_line(text, "top.below"), Some(1), "not a table");
        assert_eq!(key_line(text, "nothing.here"), None);
        assert_eq!(key_line("[a\n", "a"), None, "does not parse");
        let e = invalid("r.toml", "a.b.y", "too long").with_line_in(text);
        assert_eq!(e.to_string(), "r.toml:6: key 'a.b.y': too long");
        let e = invalid("r.toml", "nothing", "missing").with_line_in(text);
        assert_eq!(e.to_string(), "r.toml: key 'nothing': missing");
    }

    #[test]
    fn missing_file_is_named() {
        let e = load_file::<Outer>(Path::new("/nonexistent/x.toml")).unwrap_err();
        assert!(e.to_string().contains("/nonexistent/x.toml"));
    }

    #[test]
    fn every_builtin_is_valid_toml() {
        for b in SCENARIOS.iter().chain(PRESETS) {
            let v: Result<toml::Table, _> = load_str(b.text, b.origin);
            assert!(v.is_ok(), "{}: {:?}", b.name, v.err());
        }
        assert!(builtin("scenario", "nope").is_err());
    }
}
