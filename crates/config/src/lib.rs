//! Configuration loading (TOML, errors naming file and key) and the built-in presets and scenarios.
#![warn(missing_docs)]
