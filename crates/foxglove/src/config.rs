//! The `[foxglove]` table of the robot config: the WebSocket server's
//! address, the topics' prefix, the frames, the path's length, the clock
//! of the stamps.
//!
//! ```
//! use insuwb_foxglove::config::FoxgloveConfig;
//! let c: FoxgloveConfig = toml::from_str("bind = \"127.0.0.1:9001\"\npath_length = 100").unwrap();
//! assert_eq!(c.socket_addr().unwrap().port(), 9001);
//! assert_eq!(c.url().unwrap(), "ws://127.0.0.1:9001");
//! let bad: FoxgloveConfig = toml::from_str("bind = \"localhost\"").unwrap();
//! assert_eq!(
//!     bad.validate().unwrap_err().to_string(),
//!     "key 'foxglove.bind': must be IP:PORT such as \"127.0.0.1:8765\", got \"localhost\""
//! );
//! ```

use std::net::SocketAddr;

use insuwb_report::clock::StampClock;
use serde::{Deserialize, Serialize};

/// The default address of the WebSocket server (loopback only).
pub const DEFAULT_BIND: &str = "127.0.0.1:8765";

/// The topics of the live view, under [`FoxgloveConfig::topic_prefix`]
/// (`truth` and `error` only for a source with ground truth, `body_vel`
/// from the first body velocity on, `height` from the first height on,
/// `uwb_range` from the first UWB two-way range on).
pub const TOPICS: [&str; 13] = [
    "pose",
    "tf",
    "path",
    "uwb_fix",
    "truth",
    "error",
    "anchors",
    "robot",
    "diag",
    "body_vel",
    "height",
    "uwb_range",
    "health",
];

/// The longest path [`FoxgloveConfig::path_length`] allows.
pub const MAX_PATH_LENGTH: usize = 100_000;

/// `[foxglove]`: the Foxglove live view stage (`insuwb-stage-foxglove`,
/// run when `stages` lists `foxglove`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FoxgloveConfig {
    /// Address of the WebSocket server, `IP:PORT` (port 0: any free port,
    /// logged at start). Another address than loopback serves the network.
    pub bind: String,
    /// Prefix of every topic, absolute (`/insuwb/pose`, ...).
    pub topic_prefix: String,
    /// Frame of the positions (ENU).
    pub frame_id: String,
    /// The robot's body frame: child of the fused pose's transform.
    pub child_frame_id: String,
    /// Poses kept in the path (the last N fused states).
    pub path_length: usize,
    /// Show only fused states flagged valid (aligned, converged, fresh).
    pub only_valid: bool,
    /// Clock of the timestamps and log times: `realtime` or `monotonic`.
    pub stamp_clock: StampClock,
    /// Period of the health, anchors and robot-model messages, s.
    pub health_period_s: f64,
    /// A stage whose last heartbeat is older than this is shown stale, s.
    pub stale_after_s: f64,
}

impl Default for FoxgloveConfig {
    fn default() -> Self {
        Self {
            bind: DEFAULT_BIND.into(),
            topic_prefix: "/insuwb".into(),
            frame_id: "map".into(),
            child_frame_id: "base_link".into(),
            path_length: 300,
            only_valid: true,
            stamp_clock: StampClock::Realtime,
            health_period_s: 1.0,
            stale_after_s: 1.0,
        }
    }
}

/// A `[foxglove]` key with a value the live view cannot use.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("key 'foxglove.{key}': {reason}")]
pub struct FoxgloveConfigError {
    /// The key, without `foxglove.`.
    pub key: &'static str,
    /// What is wrong, with the value.
    pub reason: String,
}

impl FoxgloveConfig {
    /// Checks every key; the error names the first bad one.
    ///
    /// # Errors
    /// [`FoxgloveConfigError`] naming the key.
    pub fn validate(&self) -> Result<(), FoxgloveConfigError> {
        let bad = |key, reason: String| Err(FoxgloveConfigError { key, reason });
        self.socket_addr()?;
        let p = &self.topic_prefix;
        let body = p.strip_prefix('/');
        if !body.is_some_and(|b| {
            b.is_empty()
                || (!b.ends_with('/')
                    && b.split('/').all(|t| {
                        !t.is_empty()
                            && t.chars()
                                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
                    }))
        }) {
            return bad(
                "topic_prefix",
                format!("must be \"/\" or \"/NAME[/NAME...]\" of letters, digits, '_' and '-', got {p:?}"),
            );
        }
        for (key, f) in [
            ("frame_id", &self.frame_id),
            ("child_frame_id", &self.child_frame_id),
        ] {
            if f.is_empty()
                || f.starts_with('/')
                || !f
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '/')
            {
                return bad(
                    key,
                    format!("a frame id is letters, digits, '_' and '/', not first '/', got {f:?}"),
                );
            }
        }
        if self.frame_id == self.child_frame_id {
            return bad(
                "child_frame_id",
                format!("must differ from frame_id, both {:?}", self.frame_id),
            );
        }
        if !(1..=MAX_PATH_LENGTH).contains(&self.path_length) {
            return bad(
                "path_length",
                format!("must be 1..={MAX_PATH_LENGTH}, got {}", self.path_length),
            );
        }
        for (key, v) in [
            ("health_period_s", self.health_period_s),
            ("stale_after_s", self.stale_after_s),
        ] {
            if !(v.is_finite() && v > 0.0 && v <= 3600.0) {
                return bad(key, format!("must be in (0, 3600] s, got {v}"));
            }
        }
        Ok(())
    }

    /// The server's address.
    ///
    /// # Errors
    /// [`FoxgloveConfigError`] for `bind` when it is not `IP:PORT`.
    pub fn socket_addr(&self) -> Result<SocketAddr, FoxgloveConfigError> {
        self.bind
            .parse::<SocketAddr>()
            .map_err(|_| FoxgloveConfigError {
                key: "bind",
                reason: format!(
                    "must be IP:PORT such as \"{DEFAULT_BIND}\", got {:?}",
                    self.bind
                ),
            })
    }

    /// The address to give the Foxglove app, `ws://IP:PORT`.
    ///
    /// # Errors
    /// [`FoxgloveConfigError`] for `bind` when it is not `IP:PORT`.
    pub fn url(&self) -> Result<String, FoxgloveConfigError> {
        Ok(format!("ws://{}", self.socket_addr()?))
    }

    /// The full name of topic `name` under the prefix.
    #[must_use]
    pub fn topic(&self, name: &str) -> String {
        if self.topic_prefix == "/" {
            format!("/{name}")
        } else {
            format!("{}/{name}", self.topic_prefix)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_loopback() {
        let c = FoxgloveConfig::default();
        c.validate().unwrap();
        let a = c.socket_addr().unwrap();
        assert!(a.ip().is_loopback());
        assert_eq!(a.port(), 8765);
        assert_eq!(c.url().unwrap(), "ws://127.0.0.1:8765");
        assert_eq!(c.topic("pose"), "/insuwb/pose");
        let root = FoxgloveConfig {
            topic_prefix: "/".into(),
            ..c
        };
        root.validate().unwrap();
        assert_eq!(root.topic("pose"), "/pose");
        let v6 = FoxgloveConfig {
            bind: "[::1]:0".into(),
            ..FoxgloveConfig::default()
        };
        v6.validate().unwrap();
        assert_eq!(v6.url().unwrap(), "ws://[::1]:0");
    }

    #[test]
    fn each_bad_value_names_its_key() {
        let d = FoxgloveConfig::default;
        let cases: [(&str, FoxgloveConfig); 10] = [
            (
                "bind",
                FoxgloveConfig {
                    bind: "127.0.0.1".into(),
                    ..d()
                },
            ),
            (
                "bind",
                FoxgloveConfig {
                    bind: "127.0.0.1:70000".into(),
                    ..d()
                },
            ),
            (
                "topic_prefix",
                FoxgloveConfig {
                    topic_prefix: "insuwb".into(),
                    ..d()
                },
            ),
            (
                "topic_prefix",
                FoxgloveConfig {
                    topic_prefix: "/a//b".into(),
                    ..d()
                },
            ),
            (
                "frame_id",
                FoxgloveConfig {
                    frame_id: "/map".into(),
                    ..d()
                },
            ),
            (
                "child_frame_id",
                FoxgloveConfig {
                    child_frame_id: "map".into(),
                    ..d()
                },
            ),
            (
                "path_length",
                FoxgloveConfig {
                    path_length: 0,
                    ..d()
                },
            ),
            (
                "path_length",
                FoxgloveConfig {
                    path_length: MAX_PATH_LENGTH + 1,
                    ..d()
                },
            ),
            (
                "health_period_s",
                FoxgloveConfig {
                    health_period_s: f64::NAN,
                    ..d()
                },
            ),
            (
                "stale_after_s",
                FoxgloveConfig {
                    stale_after_s: 0.0,
                    ..d()
                },
            ),
        ];
        for (key, c) in cases {
            let e = c.validate().unwrap_err();
            assert_eq!(e.key, key, "{e}");
            assert!(
                e.to_string()
                    .starts_with(&format!("key 'foxglove.{key}': ")),
                "{e}"
            );
        }
    }

    #[test]
    fn unknown_keys_are_refused() {
        assert!(toml::from_str::<FoxgloveConfig>("port = 8765").is_err());
        let c: FoxgloveConfig = toml::from_str("stamp_clock = \"monotonic\"").unwrap();
        assert_eq!(c.stamp_clock, StampClock::Monotonic);
    }
}
