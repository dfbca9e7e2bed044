//! The runtime's configuration: service prefix, iceoryx2 root folder, stage
//! identity, wait mode and heartbeat period, with its validation.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

/// Longest accepted service prefix (bytes). iceoryx2 file names hold 255
/// bytes; the prefix is followed by a service hash and a suffix.
pub const MAX_PREFIX_LEN: usize = 48;
/// Longest accepted stage name (bytes): the width of [`insuwb_msg::Health::stage`],
/// so a heartbeat carries the name whole.
pub const MAX_STAGE_NAME_LEN: usize = 16;
/// Longest accepted iceoryx2 root path (bytes): iceoryx2 paths hold 255 bytes and
/// append their own folder names.
pub const MAX_ROOT_PATH_LEN: usize = 200;
/// Environment variable with the stage's start generation (set by the launcher,
/// counting restarts).
pub const GENERATION_ENV: &str = "INSUWB_GENERATION";

/// Configuration of one stage's runtime.
///
/// ```
/// let cfg = insuwb_runtime::RuntimeConfig {
///     prefix: "insuwb_robot1_".into(),
///     stage_name: "fusion".into(),
///     ..Default::default()
/// };
/// assert!(cfg.validate().is_ok());
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RuntimeConfig {
    /// Prefix of every iceoryx2 file of this deployment (e.g. `insuwb_robot1_`):
    /// stages with the same prefix (and root path) see each other, others do not.
    /// ASCII letters, digits, `_` and `-`, 1 to [`MAX_PREFIX_LEN`] bytes.
    /// Default `insuwb_` (deployment choice).
    pub prefix: String,
    /// iceoryx2 root folder for node and service records (e.g. `<run dir>/iox2`);
    /// absolute, at most [`MAX_ROOT_PATH_LEN`] bytes. Default `None`: iceoryx2's
    /// own default, `/tmp/iceoryx2/`.
    pub root_path: Option<PathBuf>,
    /// Name of the stage: the iceoryx2 node name and the heartbeat's stage
    /// field. ASCII letters, digits, `_` and `-`, 1 to [`MAX_STAGE_NAME_LEN`] bytes.
    /// Default `stage`.
    pub stage_name: String,
    /// Start generation stamped in every header (a restarted stage counts up).
    /// `None` (default): read [`GENERATION_ENV`], set by the launcher; 0 when unset.
    pub generation: Option<u32>,
    /// Source id stamped in every header. `None` (default): a 16-bit FNV-1a
    /// hash of `stage_name` (deterministic; set it explicitly where two stage
    /// names could collide).
    pub source_id: Option<u16>,
    /// Busy-poll instead of sleeping in the [`crate::Waiter`]'s `epoll_wait`:
    /// lower wake-up latency (no scheduler wake-up) at the price of one CPU
    /// core spinning at 100 %. For latency experiments only. Default `false`
    /// (a sleeping waiter wakes within tens of microseconds; busy polling on
    /// 2 loaded cores gave millisecond outliers, see BENCHMARKS.md).
    pub busy_poll: bool,
    /// Heartbeat ([`insuwb_msg::Health`]) period, seconds, in [0.01, 60].
    /// Default 0.2 (5 Hz, the project's heartbeat rate).
    pub heartbeat_period_s: f64,
    /// CPU affinity and SCHED_FIFO, applied when the stage starts (default: none).
    pub realtime: crate::realtime::RealtimeConfig,
}

impl Default for RuntimeConfig {
    fn default() -> Self {
        Self {
            prefix: "insuwb_".to_owned(),
            root_path: None,
            stage_name: "stage".to_owned(),
            generation: None,
            source_id: None,
            busy_poll: false,
            heartbeat_period_s: 0.2,
            realtime: crate::realtime::RealtimeConfig::default(),
        }
    }
}

/// A [`RuntimeConfig`] value that is not acceptable.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RuntimeConfigError {
    /// `runtime.prefix` is empty, too long or has a character outside `[A-Za-z0-9_-]`.
    #[error("runtime.prefix must be 1..={max} ASCII letters, digits, '_' or '-', got {value:?}")]
    Prefix {
        /// The rejected prefix.
        value: String,
        /// The length limit.
        max: usize,
    },
    /// `runtime.stage_name` is empty, too long or has a character outside `[A-Za-z0-9_-]`.
    #[error(
        "runtime.stage_name must be 1..={max} ASCII letters, digits, '_' or '-', got {value:?}"
    )]
    StageName {
        /// The rejected name.
        value: String,
        /// The length limit.
        max: usize,
    },
    /// `runtime.root_path` is relative, not UTF-8, too long or holds a NUL.
    #[error(
        "runtime.root_path must be an absolute UTF-8 path of at most {max} bytes, got {value:?}"
    )]
    RootPath {
        /// The rejected path (lossy).
        value: String,
        /// The length limit.
        max: usize,
    },
    /// `runtime.heartbeat_period_s` is outside [0.01, 60] or not finite.
    #[error("runtime.heartbeat_period_s must be in [0.01, 60], got {0}")]
    HeartbeatPeriod(f64),
}

/// True when `s` is 1..=max bytes of `[A-Za-z0-9_-]`.
pub(crate) fn is_plain_name(s: &str, max: usize) -> bool {
    !s.is_empty()
        && s.len() <= max
        && s.bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
}

impl RuntimeConfig {
    /// Checks every field; the error names the key and the offending value.
    pub fn validate(&self) -> Result<(), RuntimeConfigError> {
        if !is_plain_name(&self.prefix, MAX_PREFIX_LEN) {
            return Err(RuntimeConfigError::Prefix {
                value: self.prefix.clone(),
                max: MAX_PREFIX_LEN,
            });
        }
        if !is_plain_name(&self.stage_name, MAX_STAGE_NAME_LEN) {
            return Err(RuntimeConfigError::StageName {
                value: self.stage_name.clone(),
                max: MAX_STAGE_NAME_LEN,
            });
        }
        if let Some(root) = &self.root_path {
            let ok = root.is_absolute()
                && root
                    .to_str()
                    .is_some_and(|s| s.len() <= MAX_ROOT_PATH_LEN && !s.contains('\0'));
            if !ok {
                return Err(RuntimeConfigError::RootPath {
                    value: root.to_string_lossy().into_owned(),
                    max: MAX_ROOT_PATH_LEN,
                });
            }
        }
        let hb = self.heartbeat_period_s;
        if !(hb.is_finite() && (0.01..=60.0).contains(&hb)) {
            return Err(RuntimeConfigError::HeartbeatPeriod(hb));
        }
        Ok(())
    }

    /// The source id this configuration stamps: `source_id`, or the 16-bit
    /// FNV-1a hash of `stage_name`.
    #[must_use]
    pub fn effective_source_id(&self) -> u16 {
        self.source_id
            .unwrap_or_else(|| fnv1a_16(self.stage_name.as_bytes()))
    }
}

/// 32-bit FNV-1a folded to 16 bits (xor of the halves).
#[must_use]
pub(crate) fn fnv1a_16(bytes: &[u8]) -> u16 {
    let mut h: u32 = 0x811c_9dc5;
    for &b in bytes {
        h ^= u32::from(b);
        h = h.wrapping_mul(0x0100_0193);
    }
    // Truncation is the point: fold the two halves.
    ((h >> 16) ^ (h & 0xffff)) as u16
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_is_valid_and_documented() {
        let c = RuntimeConfig::default();
        assert_eq!(c.prefix, "insuwb_");
        assert_eq!(c.heartbeat_period_s, 0.2);
        assert!(!c.busy_poll);
        c.validate().unwrap();
    }

    #[test]
    fn rejects_bad_values_naming_the_key() {
        let bad = RuntimeConfig {
            prefix: "../x".into(),
            ..Default::default()
        };
        let e = bad.validate().unwrap_err().to_string();
        assert!(e.contains("runtime.prefix") && e.contains("../x"), "{e}");

        let long = RuntimeConfig {
            stage_name: "a".repeat(17),
            ..Default::default()
        };
        assert!(long
            .validate()
            .unwrap_err()
            .to_string()
            .contains("runtime.stage_name"));

        let rel = RuntimeConfig {
            root_path: Some("run/iox2".into()),
            ..Default::default()
        };
        assert!(matches!(
            rel.validate(),
            Err(RuntimeConfigError::RootPath { .. })
        ));

        for hb in [0.0, f64::NAN, 61.0] {
            let c = RuntimeConfig {
                heartbeat_period_s: hb,
                ..Default::default()
            };
            assert!(c
                .validate()
                .unwrap_err()
                .to_string()
                .contains("runtime.heartbeat_period_s"));
        }
    }

    #[test]
    fn deserializes_with_defaults_and_rejects_unknown_keys() {
        let c: RuntimeConfig =
            serde_json::from_str(r#"{"prefix":"insuwb_r2_","stage_name":"imu"}"#).unwrap();
        assert_eq!(c.prefix, "insuwb_r2_");
        assert_eq!(c.heartbeat_period_s, 0.2);
        assert!(serde_json::from_str::<RuntimeConfig>(r#"{"prefx":"a"}"#).is_err());
    }

    #[test]
    fn fnv_source_id_known_answer() {
        // FNV-1a 32 of "" is the offset basis 0x811c9dc5 -> 0x811c ^ 0x9dc5.
        assert_eq!(fnv1a_16(b""), 0x811c ^ 0x9dc5);
        // FNV-1a 32 of "a" is 0xe40c292c (published test vector).
        assert_eq!(fnv1a_16(b"a"), 0xe40c ^ 0x292c);
        let c = RuntimeConfig {
            source_id: Some(7),
            ..Default::default()
        };
        assert_eq!(c.effective_source_id(), 7);
    }
}
