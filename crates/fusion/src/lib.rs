//! The closed-loop INS/UWB fusion engine shared by `insuwb eval`, replay and
//! the INS and fusion stages.
//!
//! - [`config`]: the fusion configuration ([`config::FusionConfig`], the
//!   `[fusion]` table), its errors and the construction of the estimator it
//!   describes ([`config::build_estimator`]);
//! - [`ins_engine`]: [`ins_engine::InsEngine`] turns IMU samples into
//!   navigation states and applies corrections (the INS stage);
//! - [`engine`]: [`engine::FusionEngine`] turns navigation states and UWB
//!   measurements into fused states and corrections (the fusion stage);
//! - [`output`]: [`output::OutputPolicy`], what is published besides the
//!   updates (coasting while UWB is silent, stale INS input), used by the
//!   fusion stage and the runner;
//! - [`estimator`]: the [`estimator::Estimator`] interface and the paper's
//!   loosely coupled filters behind it; [`tight`] the tightly coupled
//!   error-state filter behind it;
//! - [`runner`]: the lockstep runner, the INS engine, the UWB fix builder
//!   and the fusion engine wired in one process exactly as the stage
//!   processes are (`insuwb eval`);
//! - [`vibration`]: the vibration the IMU measures as process noise for
//!   every filter;
//! - [`scenario`]: the scenario file, what to simulate and how to fuse it
//!   (`config/scenarios/`), read by `eval`, the `sim` sources and the
//!   emulators;
//! - [`aiding`]: velocity updates (odometry, flow) and each source's
//!   online scale factor;
//! - [`vehicle`]: the vehicle model (free, multirotor, ground) of the INS
//!   and the filters, and the measurements it yields.
#![warn(missing_docs)]

pub mod aiding;
pub mod config;
pub mod engine;
pub mod estimator;
pub mod ins_engine;
pub mod output;
pub mod runner;
pub mod scenario;
pub mod tight;
pub mod vehicle;
pub mod vibration;
