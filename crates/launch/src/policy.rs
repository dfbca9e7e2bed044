//! The launcher's configuration: what to run ([`StageSpec`]) and how to keep
//! it running ([`RestartPolicy`]), with their validation.

use std::path::PathBuf;
use std::time::Duration;

use serde::{Deserialize, Serialize};

/// Environment variable giving a child its start generation (0 for the first
/// start of a stage, counting up on each restart).
pub const GENERATION_ENV: &str = "INSUWB_GENERATION";
/// Environment variable giving a child its stage name.
pub const STAGE_ENV: &str = "INSUWB_STAGE";
/// Longest stage name (bytes): the width of `insuwb_msg::Health::stage`, so a
/// heartbeat carries the name whole.
pub const MAX_STAGE_NAME_LEN: usize = 16;
/// Largest accepted `budget_restarts` (bounds the memory of the sliding window).
pub const MAX_BUDGET_RESTARTS: u32 = 10_000;
/// Largest accepted `stable_after_s` and `budget_window_s` (one day).
pub const MAX_WINDOW_S: f64 = 86_400.0;
/// Largest accepted `backoff_max_ms` (ten minutes).
pub const MAX_BACKOFF_MS: u64 = 600_000;
/// Largest accepted `heartbeat_timeout_ms`, `startup_grace_ms` and `grace_ms` (one hour).
pub const MAX_TIMEOUT_MS: u64 = 3_600_000;

/// How the supervisor restarts crashed stages, detects frozen ones and stops them.
///
/// ```
/// let p = insuwb_launch::RestartPolicy::default();
/// assert_eq!((p.backoff_initial_ms, p.backoff_max_ms), (50, 300));
/// assert!(p.validate().is_ok());
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RestartPolicy {
    /// Delay before the first restart after a fault, ms, in 1..=`backoff_max_ms`;
    /// it doubles after each fault. Default 50 (deployment choice: a crashed
    /// stage is back within a few IMU periods).
    pub backoff_initial_ms: u64,
    /// Cap of the restart delay, ms, at most [`MAX_BACKOFF_MS`]. Default 300
    /// (project requirement: backoff capped at a few hundred milliseconds).
    pub backoff_max_ms: u64,
    /// A stage that ran at least this long before exiting restarts after
    /// `backoff_initial_ms` again (the backoff resets), s, in (0, [`MAX_WINDOW_S`]].
    /// Default 5 (deployment choice).
    pub stable_after_s: f64,
    /// Restarts allowed per stage within any `budget_window_s`; one more fault
    /// in that window makes the supervisor [`Failed`](crate::SupervisorState::Failed).
    /// 0 means never restart. At most [`MAX_BUDGET_RESTARTS`]. Default 10 (deployment choice).
    pub budget_restarts: u32,
    /// Length of the sliding budget window, s, in (0, [`MAX_WINDOW_S`]]: restarts
    /// older than this no longer count, so sparse faults never exhaust the
    /// budget. Default 60 (deployment choice).
    pub budget_window_s: f64,
    /// A running stage whose last heartbeat is older than this is killed
    /// (SIGKILL) and treated as crashed, ms, at most [`MAX_TIMEOUT_MS`]; 0
    /// disables the watchdog. Default 500 (2.5 periods of the 5 Hz heartbeat
    /// of insuwb-runtime).
    pub heartbeat_timeout_ms: u64,
    /// Extra allowance for a stage's first heartbeat after each (re)start, ms,
    /// at most [`MAX_TIMEOUT_MS`]: the heartbeat clock of a new process runs
    /// out after `startup_grace_ms + heartbeat_timeout_ms`. Default 2000
    /// (deployment choice: iceoryx2 node and service set-up).
    pub startup_grace_ms: u64,
    /// At shutdown, how long each stage gets to exit after SIGTERM before it
    /// is SIGKILLed, ms, at most [`MAX_TIMEOUT_MS`]. Default 2000 (deployment choice).
    pub grace_ms: u64,
    /// Children get `PR_SET_PDEATHSIG = SIGKILL`: if the launcher dies (even by
    /// SIGKILL) its stages die with it instead of lingering as orphans that hold
    /// the sensors and iceoryx2 services. Linux ties this to the *thread* that
    /// spawned the child: call [`Supervisor::start`](crate::Supervisor::start)
    /// and [`Supervisor::poll`](crate::Supervisor::poll) from a thread that
    /// lives as long as the launcher (the main thread). Default `true`.
    pub die_with_launcher: bool,
    /// Stages the group can run without: when one of them exhausts its
    /// restart budget it is given up alone ([`Event::GaveUp`](crate::Event::GaveUp):
    /// left down, never restarted) and the supervisor keeps the rest running;
    /// any other stage exhausting its budget makes the supervisor
    /// [`Failed`](crate::SupervisorState::Failed). Names of stages that are not
    /// in the stage list are ignored. Default `["logger"]` (deployment choice:
    /// the robot needs its pose more than the recording of it).
    pub optional: Vec<String>,
}

impl Default for RestartPolicy {
    fn default() -> Self {
        Self {
            backoff_initial_ms: 50,
            backoff_max_ms: 300,
            stable_after_s: 5.0,
            budget_restarts: 10,
            budget_window_s: 60.0,
            heartbeat_timeout_ms: 500,
            startup_grace_ms: 2000,
            grace_ms: 2000,
            die_with_launcher: true,
            optional: vec![insuwb_msg::StageRole::Logger.name().to_owned()],
        }
    }
}

/// A [`RestartPolicy`] value that is not acceptable.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RestartPolicyError {
    /// `launch.backoff_initial_ms` is 0 or above `backoff_max_ms`.
    #[error("launch.backoff_initial_ms must be in 1..=launch.backoff_max_ms ({max}), got {value}")]
    BackoffInitial {
        /// The rejected value.
        value: u64,
        /// `backoff_max_ms`.
        max: u64,
    },
    /// `launch.backoff_max_ms` is above [`MAX_BACKOFF_MS`].
    #[error("launch.backoff_max_ms must be at most {MAX_BACKOFF_MS}, got {0}")]
    BackoffMax(u64),
    /// `launch.stable_after_s` is not in (0, [`MAX_WINDOW_S`]].
    #[error("launch.stable_after_s must be in (0, {MAX_WINDOW_S}], got {0}")]
    StableAfter(f64),
    /// `launch.budget_restarts` is above [`MAX_BUDGET_RESTARTS`].
    #[error("launch.budget_restarts must be at most {MAX_BUDGET_RESTARTS}, got {0}")]
    BudgetRestarts(u32),
    /// `launch.budget_window_s` is not in (0, [`MAX_WINDOW_S`]].
    #[error("launch.budget_window_s must be in (0, {MAX_WINDOW_S}], got {0}")]
    BudgetWindow(f64),
    /// An entry of `launch.optional` is not a valid stage name.
    #[error("launch.optional[{index}] must be 1..={MAX_STAGE_NAME_LEN} ASCII letters, digits, '_' or '-', got {value:?}")]
    Optional {
        /// Position in the list.
        index: usize,
        /// The rejected name.
        value: String,
    },
    /// A timeout (`launch.heartbeat_timeout_ms`, `launch.startup_grace_ms`,
    /// `launch.grace_ms`) is above [`MAX_TIMEOUT_MS`].
    #[error("launch.{key} must be at most {MAX_TIMEOUT_MS}, got {value}")]
    Timeout {
        /// The key without its section.
        key: &'static str,
        /// The rejected value.
        value: u64,
    },
}

fn seconds_ok(s: f64) -> bool {
    s.is_finite() && s > 0.0 && s <= MAX_WINDOW_S
}

impl RestartPolicy {
    /// Checks every field; the error names the key and the offending value.
    pub fn validate(&self) -> Result<(), RestartPolicyError> {
        if self.backoff_max_ms > MAX_BACKOFF_MS {
            return Err(RestartPolicyError::BackoffMax(self.backoff_max_ms));
        }
        if self.backoff_initial_ms == 0 || self.backoff_initial_ms > self.backoff_max_ms {
            return Err(RestartPolicyError::BackoffInitial {
                value: self.backoff_initial_ms,
                max: self.backoff_max_ms,
            });
        }
        if !seconds_ok(self.stable_after_s) {
            return Err(RestartPolicyError::StableAfter(self.stable_after_s));
        }
        if self.budget_restarts > MAX_BUDGET_RESTARTS {
            return Err(RestartPolicyError::BudgetRestarts(self.budget_restarts));
        }
        if !seconds_ok(self.budget_window_s) {
            return Err(RestartPolicyError::BudgetWindow(self.budget_window_s));
        }
        for (key, value) in [
            ("heartbeat_timeout_ms", self.heartbeat_timeout_ms),
            ("startup_grace_ms", self.startup_grace_ms),
            ("grace_ms", self.grace_ms),
        ] {
            if value > MAX_TIMEOUT_MS {
                return Err(RestartPolicyError::Timeout { key, value });
            }
        }
        if let Some((index, value)) = self
            .optional
            .iter()
            .enumerate()
            .find(|(_, n)| !is_plain_name(n, MAX_STAGE_NAME_LEN))
        {
            return Err(RestartPolicyError::Optional {
                index,
                value: value.clone(),
            });
        }
        Ok(())
    }

    /// Whether `stage` is in [`optional`](Self::optional).
    #[must_use]
    pub fn is_optional(&self, stage: &str) -> bool {
        self.optional.iter().any(|n| n == stage)
    }

    /// `stable_after_s` as a duration (valid policies only; 0 otherwise).
    pub(crate) fn stable_after(&self) -> Duration {
        Duration::try_from_secs_f64(self.stable_after_s).unwrap_or_default()
    }

    /// `budget_window_s` as a duration (valid policies only; 0 otherwise).
    pub(crate) fn budget_window(&self) -> Duration {
        Duration::try_from_secs_f64(self.budget_window_s).unwrap_or_default()
    }
}

/// One stage process to run and keep running.
///
/// The child also gets [`GENERATION_ENV`] and [`STAGE_ENV`]; its stdin is
/// `/dev/null`, its stdout and stderr are the launcher's.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StageSpec {
    /// Stage name: 1 to [`MAX_STAGE_NAME_LEN`] ASCII letters, digits, `_` or
    /// `-`, unique among the stages (the name its heartbeats carry).
    pub name: String,
    /// Program to execute (a path, or a name looked up in `PATH`).
    pub program: PathBuf,
    /// Arguments after the program name. Default none.
    #[serde(default)]
    pub args: Vec<String>,
    /// Extra environment variables `(key, value)` on top of the launcher's.
    /// Keys are non-empty without `=` or NUL and must not be [`GENERATION_ENV`]
    /// or [`STAGE_ENV`]. Default none.
    #[serde(default)]
    pub env: Vec<(String, String)>,
}

/// A [`StageSpec`] that is not acceptable (`index` is its position in the stage list).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum StageSpecError {
    /// The name is empty, too long, has a character outside `[A-Za-z0-9_-]`.
    #[error("launch.stages[{index}].name must be 1..={MAX_STAGE_NAME_LEN} ASCII letters, digits, '_' or '-', got {value:?}")]
    Name {
        /// Position in the stage list.
        index: usize,
        /// The rejected name.
        value: String,
    },
    /// Two stages have the same name.
    #[error("launch.stages[{index}].name {value:?} is already used by another stage")]
    Duplicate {
        /// Position of the second stage with this name.
        index: usize,
        /// The repeated name.
        value: String,
    },
    /// The program path is empty or holds a NUL.
    #[error("launch.stages[{index}].program must be a non-empty path without NUL, got {value:?}")]
    Program {
        /// Position in the stage list.
        index: usize,
        /// The rejected program (lossy).
        value: String,
    },
    /// An argument holds a NUL.
    #[error("launch.stages[{index}].args holds a NUL byte in {value:?}")]
    Arg {
        /// Position in the stage list.
        index: usize,
        /// The rejected argument.
        value: String,
    },
    /// An environment key is empty, holds `=` or NUL, or is reserved; or a value holds NUL.
    #[error("launch.stages[{index}].env entry {key:?} is not allowed (empty key, '=' or NUL, or reserved {GENERATION_ENV}/{STAGE_ENV})")]
    Env {
        /// Position in the stage list.
        index: usize,
        /// The rejected key.
        key: String,
    },
}

/// True when `s` is 1..=max bytes of `[A-Za-z0-9_-]`.
fn is_plain_name(s: &str, max: usize) -> bool {
    !s.is_empty()
        && s.len() <= max
        && s.bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
}

impl StageSpec {
    /// A stage running `program` with `args`, no extra environment.
    #[must_use]
    pub fn new(name: &str, program: impl Into<PathBuf>, args: &[&str]) -> Self {
        Self {
            name: name.to_owned(),
            program: program.into(),
            args: args.iter().map(|&a| a.to_owned()).collect(),
            env: Vec::new(),
        }
    }

    /// Checks this stage alone (`index`: its position, for the error message).
    pub fn validate(&self, index: usize) -> Result<(), StageSpecError> {
        if !is_plain_name(&self.name, MAX_STAGE_NAME_LEN) {
            return Err(StageSpecError::Name {
                index,
                value: self.name.clone(),
            });
        }
        let program = self.program.as_os_str();
        if program.is_empty() || program.as_encoded_bytes().contains(&0) {
            return Err(StageSpecError::Program {
                index,
                value: self.program.to_string_lossy().into_owned(),
            });
        }
        if let Some(a) = self.args.iter().find(|a| a.contains('\0')) {
            return Err(StageSpecError::Arg {
                index,
                value: a.clone(),
            });
        }
        for (k, v) in &self.env {
            let bad = k.is_empty()
                || k.contains('=')
                || k.contains('\0')
                || v.contains('\0')
                || k == GENERATION_ENV
                || k == STAGE_ENV;
            if bad {
                return Err(StageSpecError::Env {
                    index,
                    key: k.clone(),
                });
            }
        }
        Ok(())
    }

    /// Checks every stage and that names are unique.
    pub fn validate_all(stages: &[StageSpec]) -> Result<(), StageSpecError> {
        for (index, s) in stages.iter().enumerate() {
            s.validate(index)?;
            if stages.iter().take(index).any(|o| o.name == s.name) {
                return Err(StageSpecError::Duplicate {
                    index,
                    value: s.name.clone(),
                });
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_the_documented_ones() {
        let p = RestartPolicy::default();
        assert_eq!(p.backoff_initial_ms, 50);
        assert_eq!(p.backoff_max_ms, 300);
        assert_eq!(p.stable_after_s, 5.0);
        assert_eq!(p.budget_restarts, 10);
        assert_eq!(p.budget_window_s, 60.0);
        assert_eq!(p.heartbeat_timeout_ms, 500);
        assert_eq!(p.startup_grace_ms, 2000);
        assert_eq!(p.grace_ms, 2000);
        assert!(p.die_with_launcher);
        assert_eq!(p.optional, ["logger"]);
        assert!(p.is_optional("logger") && !p.is_optional("fusion"));
        p.validate().unwrap();
        assert_eq!(p.stable_after(), Duration::from_secs(5));
        assert_eq!(p.budget_window(), Duration::from_secs(60));
    }

    #[test]
    fn serde_defaults_and_unknown_keys() {
        let p: RestartPolicy = serde_json::from_str(r#"{"backoff_max_ms": 400}"#).unwrap();
        assert_eq!(p.backoff_max_ms, 400);
        assert_eq!(p.backoff_initial_ms, 50);
        let e = serde_json::from_str::<RestartPolicy>(r#"{"backof_max_ms": 400}"#).unwrap_err();
        assert!(e.to_string().contains("backof_max_ms"), "{e}");
        let s: StageSpec =
            serde_json::from_str(r#"{"name": "imu", "program": "/bin/true"}"#).unwrap();
        assert_eq!(s, StageSpec::new("imu", "/bin/true", &[]));
        assert!(serde_json::from_str::<StageSpec>(r#"{"name":"a","program":"b","x":1}"#).is_err());
    }

    #[test]
    fn policy_errors_name_the_key_and_value() {
        let cases: [(RestartPolicy, &str, &str); 8] = [
            (
                RestartPolicy {
                    backoff_initial_ms: 0,
                    ..Default::default()
                },
                "launch.backoff_initial_ms",
                "got 0",
            ),
            (
                RestartPolicy {
                    backoff_initial_ms: 301,
                    ..Default::default()
                },
                "launch.backoff_initial_ms",
                "got 301",
            ),
            (
                RestartPolicy {
                    backoff_max_ms: 600_001,
                    ..Default::default()
                },
                "launch.backoff_max_ms",
                "got 600001",
            ),
            (
                RestartPolicy {
                    stable_after_s: f64::NAN,
                    ..Default::default()
                },
                "launch.stable_after_s",
                "NaN",
            ),
            (
                RestartPolicy {
                    budget_window_s: -1.0,
                    ..Default::default()
                },
                "launch.budget_window_s",
                "got -1",
            ),
            (
                RestartPolicy {
                    budget_restarts: 10_001,
                    ..Default::default()
                },
                "launch.budget_restarts",
                "got 10001",
            ),
            (
                RestartPolicy {
                    grace_ms: MAX_TIMEOUT_MS + 1,
                    ..Default::default()
                },
                "launch.grace_ms",
                "got 3600001",
            ),
            (
                RestartPolicy {
                    optional: vec!["logger".into(), "log ger".into()],
                    ..Default::default()
                },
                "launch.optional[1]",
                "\"log ger\"",
            ),
        ];
        for (p, key, val) in cases {
            let e = p.validate().unwrap_err().to_string();
            assert!(e.contains(key) && e.contains(val), "{e}");
        }
        // Boundaries that are fine: budget 0 (never restart), watchdog off.
        RestartPolicy {
            budget_restarts: 0,
            heartbeat_timeout_ms: 0,
            backoff_initial_ms: 300,
            ..Default::default()
        }
        .validate()
        .unwrap();
    }

    #[test]
    fn stage_errors_name_the_stage() {
        let ok = StageSpec::new("imu_drv-1", "/bin/true", &["a"]);
        StageSpec::validate_all(std::slice::from_ref(&ok)).unwrap();

        let e = StageSpec::new("x".repeat(17).as_str(), "/bin/true", &[])
            .validate(3)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("launch.stages[3].name") && e.contains(&"x".repeat(17)),
            "{e}"
        );
        let e = StageSpec::new("a b", "/bin/true", &[])
            .validate(0)
            .unwrap_err();
        assert!(matches!(e, StageSpecError::Name { .. }));
        let e = StageSpec::new("a", "", &[])
            .validate(1)
            .unwrap_err()
            .to_string();
        assert!(e.contains("launch.stages[1].program"), "{e}");
        let e = StageSpec::new("a", "/bin/true", &["x\0y"])
            .validate(0)
            .unwrap_err();
        assert!(matches!(e, StageSpecError::Arg { .. }));
        for key in [GENERATION_ENV, STAGE_ENV, "", "A=B"] {
            let mut s = ok.clone();
            s.env.push((key.to_owned(), "1".to_owned()));
            let e = s.validate(2).unwrap_err().to_string();
            assert!(e.contains("launch.stages[2].env"), "{e}");
        }
        let e = StageSpec::validate_all(&[ok.clone(), StageSpec::new("b", "/bin/true", &[]), ok])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("launch.stages[2].name") && e.contains("imu_drv-1"),
            "{e}"
        );
    }
}
