//! Process-group supervisor of the insuwb stages (`insuwb launch`).
//!
//! It owns the life cycle of the stage processes on the robot PC: spawning
//! them (each in its own process group, with `INSUWB_GENERATION` and
//! `INSUWB_STAGE` set), reaping them (a zombie looks alive, so every exit is
//! collected with `waitpid`), restarting them with a capped exponential
//! backoff within a sliding-window budget (a stage that exhausts it fails
//! the group, unless it is optional: then it alone is given up), killing
//! stages whose heartbeat went silent (liveness comes from heartbeats, not
//! from iceoryx2 publisher counts), and stopping them in a chosen order. It has no iceoryx2
//! dependency: the caller forwards heartbeats ([`Supervisor::note_heartbeat`])
//! and cleans a dead stage's resources in the before-restart hook
//! ([`Supervisor::set_before_restart`]).
//!
//! ```no_run
//! use std::time::{Duration, Instant};
//! use insuwb_launch::{RestartPolicy, StageSpec, Supervisor, SupervisorState};
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let stages = vec![
//!     StageSpec::new("imu", "/usr/bin/insuwb-stage-imu", &["--config", "robot.toml"]),
//!     StageSpec::new("logger", "/usr/bin/insuwb-stage-logger", &[]),
//! ];
//! let mut sup = Supervisor::new(RestartPolicy::default(), stages)?;
//! sup.set_before_restart(Box::new(|stage| eprintln!("cleaning {stage}")));
//! sup.start(Instant::now())?;
//! # let shutdown_requested = || true;
//! while !shutdown_requested() && sup.state() == SupervisorState::Running {
//!     // Wait for heartbeats here (sup.note_heartbeat(name, Instant::now())).
//!     std::thread::sleep(Duration::from_millis(50));
//!     sup.poll(Instant::now());
//! }
//! sup.shutdown(&["imu", "logger"]);
//! # Ok(())
//! # }
//! ```
#![warn(missing_docs)]

mod backoff;
pub mod policy;
pub mod supervisor;
mod sys;

pub use policy::{
    RestartPolicy, RestartPolicyError, StageSpec, StageSpecError, GENERATION_ENV,
    MAX_STAGE_NAME_LEN, STAGE_ENV,
};
pub use supervisor::{
    BeforeRestart, Event, ExitKind, KillError, LaunchError, Supervisor, SupervisorState,
};
