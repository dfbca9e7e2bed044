//! Deterministic simulator: trajectories, IMU errors, UWB TDOA or two-way
//! ranging (TWR) with noise and NLOS outlier bursts, wheel odometry and
//! optical flow.
//!
//! A [`Scenario`] (the `[sim]` table of a scenario file) and a seed give,
//! through [`simulate`], bit-identical [`insuwb_msg::ImuSample`],
//! [`insuwb_msg::UwbTdoa`] (or, with `[sim.uwb] kind = "twr"`,
//! [`insuwb_msg::UwbRange`]), [`insuwb_msg::GroundTruth`] and, when the
//! scenario has `[sim.odometry]` or `[sim.flow]`,
//! [`insuwb_msg::BodyVelocity`] streams (times in ns from 0, `seq` from 0
//! per stream). The randomness comes from one
//! seeded generator of the rand family, one stream per random quantity
//! ([`rng`]).
//!
//! Scenario files keep the simulator's settings in a `[sim]` table (see
//! `config/scenarios/*.toml`, embedded as [`builtin`]); every table inside it
//! refuses unknown keys. [`Scenario::from_toml_str`] ignores other top-level
//! tables, so a file may also carry a filter preset: an application can
//! deserialize the whole file as `struct ScenarioFile { sim: Scenario, filter: ... }`
//! with `deny_unknown_fields`.
//!
//! ```
//! let sc = insuwb_sim::Scenario::builtin("paper-3.4").unwrap();
//! let out = insuwb_sim::simulate(&sc, sc.seed).unwrap();
//! assert_eq!(out.imu.len(), 1500);
//! assert_eq!(out.truth.len(), 1500);
//! assert_eq!(out.tdoa.len(), 1500 * 3);
//!
//! // The same room with two-way ranges: one range per anchor and epoch.
//! let sc = insuwb_sim::Scenario::builtin("twr-3.4").unwrap();
//! let out = insuwb_sim::simulate(&sc, sc.seed).unwrap();
//! assert_eq!(out.range.len(), 1500 * 4);
//! assert!(out.tdoa.is_empty());
//! ```
#![warn(missing_docs)]

pub mod rng;
pub mod run;
pub mod scenario;
pub mod trajectory;

pub use run::{
    simulate, ImuErrorRealisation, InitialState, RangeTruth, SimError, SimOutput, SimRecord,
    TdoaTruth,
};
pub use scenario::{
    Anchor, AnchorSet, Dimension, Dropout, FlowConfig, ImuErrors, InitialError, NoiseModel,
    OdometryConfig, OutlierBurst, PairMode, RandomNlos, Scenario, ScenarioConfigError,
    ScenarioError, UwbConfig, UwbKind,
};
pub use trajectory::{
    CirclePath, Figure8Path, Kinematics, LissajousPath, StaticPose, Trajectory, TrajectoryError,
    TrajectoryModel, WaypointPath,
};

/// The built-in scenarios: `(name, TOML text)`; the files live in `config/scenarios/`.
const BUILTINS: [(&str, &str); 7] = [
    (
        "paper-3.4",
        include_str!("../../../config/scenarios/paper-3.4.toml"),
    ),
    (
        "paper-4.3-static",
        include_str!("../../../config/scenarios/paper-4.3-static.toml"),
    ),
    (
        "paper-4.4-dynamic",
        include_str!("../../../config/scenarios/paper-4.4-dynamic.toml"),
    ),
    (
        "nlos-long",
        include_str!("../../../config/scenarios/nlos-long.toml"),
    ),
    (
        "nlos-long-twr",
        include_str!("../../../config/scenarios/nlos-long-twr.toml"),
    ),
    (
        "ground-outage",
        include_str!("../../../config/scenarios/ground-outage.toml"),
    ),
    (
        "twr-3.4",
        include_str!("../../../config/scenarios/twr-3.4.toml"),
    ),
];

/// Names of the built-in scenarios (the file names without `.toml`).
const BUILTIN_NAMES: [&str; 7] = [
    BUILTINS[0].0,
    BUILTINS[1].0,
    BUILTINS[2].0,
    BUILTINS[3].0,
    BUILTINS[4].0,
    BUILTINS[5].0,
    BUILTINS[6].0,
];

/// The TOML text of a built-in scenario, by name (e.g. `"paper-3.4"`).
#[must_use]
pub fn builtin(name: &str) -> Option<&'static str> {
    BUILTINS.iter().find(|(n, _)| *n == name).map(|(_, t)| *t)
}

/// Names of the built-in scenarios.
#[must_use]
pub fn builtin_names() -> &'static [&'static str] {
    &BUILTIN_NAMES
}
