//! The robot group configuration (`config/robot.toml`): deployment (prefix,
//! run directory), sensor sources, the fusion process's table, logger,
//! restart policy and the bridges' tables. Every stage and the launcher read
//! the same file, so they agree. [`RobotConfig::load`] parses it (the
//! sources into [`Source`]s, the real-time tables' keys into
//! [`StageRole`]s), makes its relative paths absolute under the file's
//! folder and checks each section; an error names the file, the line and
//! the key ([`RobotConfigError`]).
//!
//! Two things are called "fusion": robot.toml's `[fusion]` table,
//! [`FusionProcessConfig`] (the fusion process: which filter, where its
//! estimator settings come from, checkpoints, the eager prediction's lag),
//! and the estimator's settings, [`insuwb_fusion::config::FusionConfig`]
//! (the `[fusion]` table of the file `fusion.config` names, of a scenario
//! or of a replayed log's metadata: INS, fix builder, filters), which
//! [`RobotConfig::fusion_config`] reads. Each setting has one home: an
//! estimator table written in robot.toml's `[fusion]` is refused with a
//! message saying where it goes.

use std::collections::BTreeMap;
use std::path::{Component, Path, PathBuf};

use insuwb_config::{invalid, ConfigError};
use insuwb_fusion::config::FusionConfig;
use insuwb_launch::RestartPolicy;
use insuwb_msg::{FilterKind, StageRole, UwbKind};
use insuwb_runtime::realtime::RealtimeConfig;
use serde::{Deserialize, Serialize};

use insuwb_fusion::scenario::{fusion_table, ScenarioError, ScenarioFile};

use crate::sources::Source;

/// Why a robot config could not be loaded, or its fusion settings read.
#[derive(Debug, thiserror::Error)]
pub enum RobotConfigError {
    /// A file could not be read or parsed, or a value is not acceptable;
    /// the message names the file, the line and the key.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The current directory, which a relative config path starts from,
    /// could not be read.
    #[error("reading the current directory: {0}")]
    CurrentDir(std::io::Error),
    /// The replayed log's header, whose metadata holds the fusion
    /// settings, could not be read.
    #[error("{path}: cannot read the log header: {error}")]
    Log {
        /// The log.
        path: String,
        /// Why.
        error: insuwb_log::OpenError,
    },
    /// The scenario, which holds the fusion settings of `sim` sources, could
    /// not be loaded.
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
}

/// Environment variable carrying the replay start epoch (CLOCK_MONOTONIC ns),
/// set by the launcher so the drivers replay in step.
pub const START_EPOCH_ENV: &str = "INSUWB_START_EPOCH_NS";

/// Deployment settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GroupConfig {
    /// Name of the robot (for logs).
    pub name: String,
    /// iceoryx2 service prefix: several robots (or test runs) on one PC never collide.
    pub prefix: String,
    /// Run directory: checkpoints, recorded logs, iceoryx2 root; non-empty,
    /// no NUL. Relative paths are taken from the config file's folder. The
    /// launcher creates it 0700 (an existing one is left as it is, with a
    /// warning when others can reach into it).
    pub run_dir: PathBuf,
}

impl Default for GroupConfig {
    fn default() -> Self {
        Self {
            name: "robot".into(),
            prefix: "insuwb_robot_".into(),
            run_dir: PathBuf::from("/tmp/insuwb-robot"),
        }
    }
}

/// Where the drivers get their samples.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SourcesConfig {
    /// IMU source: `sim`, `replay:FILE` (an insuwb log, absolute after
    /// loading), `device` or `ros2:/TOPIC` (`sensor_msgs/Imu` over DDS,
    /// node, namespace and domain from `[ros2]`; see
    /// `insuwb_stage::ros2_source`).
    pub imu: Source,
    /// UWB source: `sim`, `replay:FILE` or `device` (not `ros2:`).
    pub uwb: Source,
    /// Scenario for `sim` sources (built-in name or TOML file).
    pub scenario: String,
    /// Simulation seed.
    pub seed: u64,
    /// Replay/simulation speed: a factor (1 = real time) or `"max"`
    /// (lockstep with the consumers, never dropping a sample).
    #[serde(with = "speed_serde")]
    pub speed: f64,
}

mod speed_serde {
    use serde::{Deserialize, Deserializer, Serializer};

    #[derive(Deserialize)]
    #[serde(untagged)]
    enum Speed {
        Factor(f64),
        Name(String),
    }

    pub(super) fn serialize<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
        if v.is_infinite() {
            s.serialize_str("max")
        } else {
            s.serialize_f64(*v)
        }
    }

    pub(super) fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        match Speed::deserialize(d)? {
            Speed::Factor(f) => Ok(f),
            Speed::Name(n) if n == "max" => Ok(f64::INFINITY),
            Speed::Name(n) => Err(serde::de::Error::custom(format!(
                "expected a positive number or \"max\", got \"{n}\""
            ))),
        }
    }
}

/// `[realtime.<stage>]`: the tables, each named by a stage role.
mod realtime_serde {
    use std::collections::BTreeMap;

    use insuwb_msg::StageRole;
    use insuwb_runtime::realtime::RealtimeConfig;
    use serde::de::Error;
    use serde::{Deserialize, Deserializer};

    pub(super) fn deserialize<'de, D: Deserializer<'de>>(
        d: D,
    ) -> Result<BTreeMap<StageRole, RealtimeConfig>, D::Error> {
        BTreeMap::<String, RealtimeConfig>::deserialize(d)?
            .into_iter()
            .map(|(name, rt)| match name.parse::<StageRole>() {
                Ok(role) => Ok((role, rt)),
                Err(_) => Err(D::Error::custom(format!(
                    "[realtime.{name}]: unknown stage '{name}' (known: {})",
                    StageRole::NAMES.join(", ")
                ))),
            })
            .collect()
    }
}

impl Default for SourcesConfig {
    fn default() -> Self {
        Self {
            imu: Source::Sim,
            uwb: Source::Sim,
            scenario: "nlos-long".into(),
            seed: 1,
            speed: 1.0,
        }
    }
}

/// The fusion process's table, robot.toml's `[fusion]`: which filter it
/// runs, where its estimator settings come from, checkpoints and the eager
/// prediction. Not the estimator's settings
/// ([`insuwb_fusion::config::FusionConfig`], the `[fusion]` table of the
/// file `config` names), which every stage reads
/// ([`RobotConfig::fusion_config`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FusionProcessConfig {
    /// Filter: kf, shaf, stf, iakf, iakf_tdoa (the estimator settings'
    /// `[fusion.filter]` table is the adaptive filters' parameters).
    pub filter: FilterKind,
    /// The estimator settings' file (its `[fusion]` table, e.g.
    /// `config/util.toml`), relative to the robot config's folder; empty:
    /// the scenario's (sim sources) or the replayed log's own.
    pub config: String,
    /// Checkpoint period, s (a restarted fusion stage resumes from it).
    pub checkpoint_period_s: f64,
    /// Predict through INS states as they arrive, keeping the newest this
    /// many seconds buffered for UWB samples still on their way, s (the
    /// engine's `FusionEngineConfig::eager_lag_s`, whose one home this is:
    /// the estimator settings refuse `[fusion.engine] eager_lag_s`): takes
    /// the prediction off the fix-to-fused path and lets the coasting
    /// covariance grow. The result is
    /// the lazy engine's while a UWB sample of time t arrives before the INS
    /// state at t + one IMU period + this lag (15 ms at 100 Hz with the
    /// default 5 ms; the fix usually arrives first); a later one is applied
    /// on the INS state interpolated at t, one older than the INS interval
    /// processed last is dropped (counted). Each 10 ms of lag keeps one more
    /// covariance prediction on the fix-to-fused path. Negative: off.
    /// Ignored at `speed = "max"` (the drivers run ahead there).
    pub eager_lag_s: f64,
    /// The sources whose samples aid the filter: `flow` (an optical-flow
    /// deck: its body velocities on `body_vel` and its range finder's
    /// heights on `height`, e.g. a replayed UTIL flight's), `odometry` (a
    /// wheeled base's body velocities) and `range_finder` (heights alone);
    /// empty (default): none, the stage does not subscribe. Their weights
    /// and scale factors are the estimator settings' `[fusion.aiding]`.
    pub aiding_sources: Vec<AidingSource>,
}

/// An aiding source the fusion process may use (`[fusion] aiding_sources`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AidingSource {
    /// Optical flow with a range finder (`BodyVelocity::SOURCE_FLOW`, and
    /// the range finder's `Height`s).
    Flow,
    /// Wheel odometry (`BodyVelocity::SOURCE_ODOMETRY`).
    Odometry,
    /// A range finder alone (`Height::SOURCE_RANGE_FINDER`).
    RangeFinder,
}

impl AidingSource {
    /// The `BodyVelocity::source` code of its body velocities (`None`: it
    /// gives none).
    #[must_use]
    pub const fn velocity_code(self) -> Option<u32> {
        match self {
            Self::Flow => Some(insuwb_msg::BodyVelocity::SOURCE_FLOW),
            Self::Odometry => Some(insuwb_msg::BodyVelocity::SOURCE_ODOMETRY),
            Self::RangeFinder => None,
        }
    }

    /// Whether it gives heights (`Height::SOURCE_RANGE_FINDER`).
    #[must_use]
    pub const fn gives_height(self) -> bool {
        matches!(self, Self::Flow | Self::RangeFinder)
    }
}

impl Default for FusionProcessConfig {
    fn default() -> Self {
        Self {
            filter: FilterKind::Iakf,
            config: String::new(),
            checkpoint_period_s: 0.5,
            eager_lag_s: 0.005,
            aiding_sources: Vec::new(),
        }
    }
}

/// The log header entry naming what the log's UWB measurements are
/// ([`UwbKind::name`]), written by the logger and `insuwb import`.
pub const LOG_UWB_KIND: &str = "uwb_kind";

/// UWB driver settings (`[uwb]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct UwbStageConfig {
    /// What the robot's UWB system measures: `tdoa` (differences between
    /// anchor pairs, on `uwb_tdoa`, or a device's own positions) or `twr`
    /// (two-way ranges to each anchor, on `uwb_range`). The source must
    /// agree: the scenario's `[sim.uwb] kind`, a replayed log's `uwb_kind`,
    /// a device protocol that reports ranges.
    pub kind: UwbKind,
    /// A site calibration of the TDOA differences (`insuwb calibrate`),
    /// relative to the robot config's folder; empty: none. The UWB driver
    /// corrects every difference with it before the fixes and publishes
    /// the corrected difference, flagged.
    pub calibration: String,
    /// The calibration read from `calibration` when the file was loaded.
    #[serde(skip)]
    pub loaded: Option<std::sync::Arc<insuwb_uwb::calibration::SiteCalibration>>,
}

impl UwbStageConfig {
    /// `calibration`: a file, absolute under `base`, that reads as a calibration.
    fn resolve(&mut self, base: &Path, origin: &str) -> Result<(), ConfigError> {
        if self.calibration.is_empty() {
            return Ok(());
        }
        let p = under(base, &self.calibration);
        let c = insuwb_uwb::calibration::SiteCalibration::load(&p)
            .map_err(|e| invalid(origin, "uwb.calibration", e.to_string()))?;
        self.calibration = p.display().to_string();
        self.loaded = Some(std::sync::Arc::new(c));
        Ok(())
    }
}

/// Logger settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct LoggerConfig {
    /// Segment files (rotation, flush policy).
    pub segments: insuwb_log::SegmentConfig,
    /// Directory of the recording (default `log`): relative to the run
    /// directory and then without `..` (it stays inside), or absolute (a
    /// disk of its own).
    pub dir: Option<PathBuf>,
}

/// A real sensor behind a serial port or a TCP connection (`[devices.imu]`,
/// `[devices.uwb]`), read by a driver whose source is `device`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DeviceConfig {
    /// Where: `serial:/dev/ttyUSB0` (a tty, pseudo-terminal or udev symlink)
    /// or `tcp:HOST:PORT`.
    pub source: String,
    /// Protocol: `witmotion` or `mavlink` (IMU); `nlink` or `eliko` (UWB).
    pub protocol: String,
    /// Serial baud rate (ignored for TCP).
    pub baud: u32,
    /// UWB: the tag to follow (Eliko tag id, NLink tag id); 0 takes every tag.
    pub tag_id: u32,
    /// IMU: mounting rotation from the sensor frame to the body frame,
    /// roll, pitch, yaw in degrees (applied to accelerations and rates).
    pub rotation_deg: [f64; 3],
    /// UWB: the antenna's position in the body frame, m (lever arm); when
    /// not zero it becomes the loose filters' `[fusion.loose] lever_arm_m`.
    pub lever_arm_m: [f64; 3],
    /// UWB: standard deviation of a position fix the device reports, m.
    pub position_sigma_m: f64,
    /// UWB two-way ranging: the surveyed anchors (`[[devices.uwb.anchors]]`
    /// `id = 0x1A2B`, `pos_m = [x, y, z]`), ENU, m. A configured position
    /// wins over one the device reports (DWM1001 `lec`); a range to an
    /// anchor whose position neither gives is dropped and counted.
    pub anchors: Vec<AnchorConfig>,
    /// No valid frame within this many bytes read: the baud rate (or the
    /// protocol) is wrong, and the error says so.
    pub wrong_baud_bytes: u64,
    /// Reconnection: first retry, ms.
    pub reconnect_initial_ms: u64,
    /// Reconnection: cap of the backoff, ms.
    pub reconnect_max_ms: u64,
}

impl Default for DeviceConfig {
    fn default() -> Self {
        Self {
            source: String::new(),
            protocol: String::new(),
            baud: 115_200,
            tag_id: 0,
            rotation_deg: [0.0; 3],
            lever_arm_m: [0.0; 3],
            position_sigma_m: 0.1,
            anchors: Vec::new(),
            wrong_baud_bytes: 4096,
            reconnect_initial_ms: 50,
            reconnect_max_ms: 500,
        }
    }
}

/// One surveyed UWB anchor of a ranging device (`[[devices.uwb.anchors]]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AnchorConfig {
    /// The anchor's id as the device reports it (DWM1001: its 16-bit short
    /// address; NLink: its index 0-7).
    pub id: u32,
    /// Its position, ENU, m.
    pub pos_m: [f64; 3],
}

/// The device sources (`[devices]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct DevicesConfig {
    /// The IMU (when `sources.imu = "device"`).
    pub imu: Option<DeviceConfig>,
    /// The UWB positioning system (when `sources.uwb = "device"`).
    pub uwb: Option<DeviceConfig>,
}

/// The whole file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct RobotConfig {
    /// Deployment.
    pub group: GroupConfig,
    /// Sensor sources.
    pub sources: SourcesConfig,
    /// The fusion process (`[fusion]`; the estimator's settings are in the
    /// file its `config` names).
    pub fusion: FusionProcessConfig,
    /// UWB driver.
    pub uwb: UwbStageConfig,
    /// Logger.
    pub logger: LoggerConfig,
    /// Stages to run, in start order (default: imu, uwb, ins, fusion,
    /// logger; `ros2`, `foxglove` and `zenoh` run only where listed, always
    /// after fusion, in that order, and always optional).
    pub stages: Vec<StageRole>,
    /// Restart policy of the launcher.
    pub launch: RestartPolicy,
    /// Real sensors (drivers whose source is `device`).
    pub devices: DevicesConfig,
    /// The ROS 2 bridge (`insuwb-stage-ros2`, when `stages` lists `ros2`).
    pub ros2: insuwb_ros2::Ros2Config,
    /// The Foxglove live view (`insuwb-stage-foxglove`, when `stages` lists
    /// `foxglove`).
    pub foxglove: insuwb_foxglove::FoxgloveConfig,
    /// The Zenoh bridge to the fleet's station (`insuwb-stage-zenoh`, when
    /// `stages` lists `zenoh`); its certificate paths are relative to the
    /// file's folder.
    pub zenoh: insuwb_zenoh::ZenohConfig,
    /// Optional CPU pinning and SCHED_FIFO per stage (`[realtime.fusion]`
    /// `cpus = [1]`, `fifo_priority = 50`); none by default. A table whose
    /// name is not a stage role is refused, naming it.
    #[serde(deserialize_with = "realtime_serde::deserialize")]
    pub realtime: BTreeMap<StageRole, RealtimeConfig>,
}

impl RobotConfig {
    /// Loads and checks a robot config file; relative paths become relative to its folder.
    ///
    /// # Errors
    /// [`RobotConfigError::Config`] for a file that cannot be read or
    /// parsed or holds a value not accepted; [`RobotConfigError::CurrentDir`]
    /// when a relative `path` cannot be made absolute.
    pub fn load(path: &Path) -> Result<Self, RobotConfigError> {
        let text = insuwb_config::read_text(path)?;
        let origin = path.display().to_string();
        let mut c = Self::parse(&text, &origin)?;
        // Relative paths in the file are relative to its folder, made
        // absolute here (the iceoryx2 root must be absolute).
        let base = path.parent().unwrap_or(Path::new("."));
        let base = if base.is_absolute() {
            base.to_path_buf()
        } else {
            std::env::current_dir()
                .map_err(RobotConfigError::CurrentDir)?
                .join(base)
        };
        c.resolve(&base, &origin, &text)?;
        Ok(c)
    }

    /// Parses a config text (for built-ins and tests); relative paths
    /// become relative to `base`.
    ///
    /// # Errors
    /// [`RobotConfigError::Config`] for a text that does not parse or holds
    /// a value not accepted.
    pub fn from_str(text: &str, origin: &str, base: &Path) -> Result<Self, RobotConfigError> {
        let mut c = Self::parse(text, origin)?;
        c.resolve(base, origin, text)?;
        Ok(c)
    }

    /// Parses `text`: an estimator table in `[fusion]` first, with a
    /// message saying where it goes, then the whole.
    fn parse(text: &str, origin: &str) -> Result<Self, ConfigError> {
        check_fusion_keys(text, origin).map_err(|e| e.with_line_in(text))?;
        insuwb_config::load_str(text, origin)
    }

    /// Fills in the default stages, makes the relative paths absolute
    /// under `base` and checks each section; the error gets the line of its
    /// key in `text`.
    fn resolve(&mut self, base: &Path, origin: &str, text: &str) -> Result<(), ConfigError> {
        self.resolve_sections(base, origin)
            .map_err(|e| e.with_line_in(text))
    }

    /// [`RobotConfig::resolve`] without the line.
    fn resolve_sections(&mut self, base: &Path, origin: &str) -> Result<(), ConfigError> {
        if self.stages.is_empty() {
            self.stages = StageRole::DEFAULT.to_vec();
        }
        self.place_optional();
        self.group.resolve(base, origin)?;
        self.logger.check_dir(origin)?;
        self.sources.resolve(base, origin)?;
        self.devices.check(&self.sources, origin)?;
        check_realtime(&self.realtime, origin)?;
        self.sources.check_ros2_imu_only(origin)?;
        self.sources.check_speed(origin)?;
        self.fusion.resolve(base, origin)?;
        self.uwb.resolve(base, origin)?;
        check_launch(&self.launch, origin)?;
        self.check_bridges(base, origin)?;
        self.logger.check_segments(origin)?;
        self.sources.check_scenario(origin)?;
        self.check_uwb_kind(origin)
    }

    /// `[uwb] kind` agrees with the UWB source: the scenario's `[sim.uwb]
    /// kind`, a replayed log's header entry `uwb_kind` (a log without one
    /// is not checked), a device protocol that reports what it names; a
    /// site calibration (of TDOA differences) only with `tdoa`.
    fn check_uwb_kind(&self, origin: &str) -> Result<(), ConfigError> {
        let kind = self.uwb.kind;
        let other = match kind {
            UwbKind::Tdoa => UwbKind::Twr,
            UwbKind::Twr => UwbKind::Tdoa,
        };
        let mismatch = |what: String| {
            Err(invalid(
                origin,
                "uwb.kind",
                format!("is \"{kind}\", but {what}: set [uwb] kind = \"{other}\""),
            ))
        };
        match &self.sources.uwb {
            Source::Sim => {
                let sc = ScenarioFile::load(&self.sources.scenario)
                    .map_err(|e| invalid(origin, "sources.scenario", e.to_string()))?;
                if sc.sim.uwb.kind != kind {
                    return mismatch(format!(
                        "scenario '{}' simulates [sim.uwb] kind = \"{}\"",
                        self.sources.scenario, sc.sim.uwb.kind
                    ));
                }
            }
            Source::Replay(file) => {
                let header = insuwb_log::read_header_file(file).map_err(|e| {
                    invalid(origin, "sources.uwb", format!("{}: {e}", file.display()))
                })?;
                if let Some(k) = header.meta.entries.get(LOG_UWB_KIND) {
                    if k != kind.name() {
                        return mismatch(format!(
                            "the log {} holds uwb_kind = \"{k}\"",
                            file.display()
                        ));
                    }
                }
            }
            Source::Device => {
                if let Some(d) = &self.devices.uwb {
                    let ok = match d.protocol.as_str() {
                        "dwm1001" => kind == UwbKind::Twr,
                        "eliko" => kind == UwbKind::Tdoa,
                        _ => true,
                    };
                    if !ok {
                        return mismatch(format!(
                            "[devices.uwb] protocol = \"{}\" reports {}",
                            d.protocol,
                            if kind == UwbKind::Twr {
                                "positions, not ranges"
                            } else {
                                "ranges"
                            }
                        ));
                    }
                }
            }
            Source::Ros2 { .. } => {}
        }
        if kind == UwbKind::Twr && !self.uwb.calibration.is_empty() {
            return Err(invalid(
                origin,
                "uwb.calibration",
                "a site calibration corrects TDOA differences; [uwb] kind = \"twr\" has none"
                    .to_owned(),
            ));
        }
        Ok(())
    }

    /// The `[ros2]`, `[foxglove]` and `[zenoh]` tables, each as its bridge
    /// needs it (the Zenoh bridge's robot id and endpoint only where
    /// `stages` lists it); the Zenoh certificates' paths become absolute
    /// under `base`.
    fn check_bridges(&mut self, base: &Path, origin: &str) -> Result<(), ConfigError> {
        self.ros2
            .validate()
            .map_err(|e| invalid(origin, &format!("ros2.{}", e.key), e.reason))?;
        for (key, topic) in [
            ("odometry_in", &self.ros2.odometry_in),
            ("height_in", &self.ros2.height_in),
        ] {
            if !topic.is_empty() && !self.stages.contains(&StageRole::Ros2) {
                return Err(invalid(
                    origin,
                    &format!("ros2.{key}"),
                    format!(
                        "[ros2] {key} = {topic:?} is read by the ROS 2 bridge, which runs only where `stages` lists \"ros2\": add \"ros2\" to stages, or leave {key} empty"
                    ),
                ));
            }
        }
        self.foxglove
            .validate()
            .map_err(|e| invalid(origin, &format!("foxglove.{}", e.key), e.reason))?;
        self.zenoh.resolve_paths(base);
        if self.stages.contains(&StageRole::Zenoh) {
            self.zenoh.validate_enabled()
        } else {
            self.zenoh.validate()
        }
        .map_err(|e| invalid(origin, &format!("zenoh.{}", e.key), e.reason))
    }

    /// The ROS 2 bridge, the Foxglove live view and the Zenoh bridge, when
    /// listed, start after fusion (their input), in that order, and are
    /// optional: one that keeps failing is given up alone, the fix path
    /// keeps running.
    fn place_optional(&mut self) {
        let after = [StageRole::Fusion, StageRole::Ros2, StageRole::Foxglove];
        for (role, after) in [
            (StageRole::Ros2, &after[..1]),
            (StageRole::Foxglove, &after[..2]),
            (StageRole::Zenoh, &after[..]),
        ] {
            let Some(at) = self.stages.iter().position(|s| *s == role) else {
                continue;
            };
            if let Some(last) = self.stages.iter().rposition(|s| after.contains(s)) {
                if last > at {
                    self.stages.remove(at);
                    self.stages.insert(last, role);
                }
            }
            if !self.launch.is_optional(role.name()) {
                self.launch.optional.push(role.name().to_owned());
            }
        }
    }

    /// The filter to run.
    #[must_use]
    pub fn filter_kind(&self) -> FilterKind {
        self.fusion.filter
    }

    /// The iceoryx2 root folder of this group.
    #[must_use]
    pub fn iox_root(&self) -> PathBuf {
        self.group.run_dir.join("iox2")
    }

    /// The runtime config of stage `name`.
    #[must_use]
    pub fn runtime(&self, name: &str) -> insuwb_runtime::RuntimeConfig {
        insuwb_runtime::RuntimeConfig {
            prefix: self.group.prefix.clone(),
            root_path: Some(self.iox_root()),
            stage_name: name.to_owned(),
            realtime: name
                .parse::<StageRole>()
                .ok()
                .and_then(|role| self.realtime.get(&role))
                .cloned()
                .unwrap_or_default(),
            ..insuwb_runtime::RuntimeConfig::default()
        }
    }

    /// The estimator's settings every stage uses (the INS's, the UWB
    /// driver's fix builder's, the filters'; not robot.toml's `[fusion]`
    /// table, [`RobotConfig::fusion`]): `fusion.config`'s `[fusion]` table
    /// if set, else the replayed IMU log's metadata (read from its header
    /// alone), else the scenario's (INS start for `sources.seed`); with
    /// `[uwb] calibration`'s site calibration.
    ///
    /// # Errors
    /// [`RobotConfigError`] when that file, log header or scenario cannot
    /// be read.
    pub fn fusion_config(&self) -> Result<FusionConfig, RobotConfigError> {
        let mut f = self.fusion_config_file()?;
        f.calibration.clone_from(&self.uwb.loaded);
        // A UWB device's antenna lever arm (robot.toml) is the loose filters'.
        if let (Source::Device, Some(d)) = (&self.sources.uwb, &self.devices.uwb) {
            if d.lever_arm_m != [0.0; 3] {
                f.loose.lever_arm_m = d.lever_arm_m;
            }
        }
        Ok(f)
    }

    fn fusion_config_file(&self) -> Result<FusionConfig, RobotConfigError> {
        if !self.fusion.config.is_empty() {
            let text = insuwb_config::read_text(Path::new(&self.fusion.config))?;
            // Only the [fusion] table matters here; other tables are the file's business.
            return Ok(fusion_table(&text, &self.fusion.config)?);
        }
        if let Some(file) = self.sources.imu.replay_file() {
            let path = file.display().to_string();
            let header =
                insuwb_log::read_header_file(file).map_err(|error| RobotConfigError::Log {
                    path: path.clone(),
                    error,
                })?;
            return Ok(match header.meta.entries.get("fusion_config") {
                Some(text) => fusion_table(text, &path)?,
                None => FusionConfig::default(),
            });
        }
        let sc = ScenarioFile::load(&self.sources.scenario)?;
        Ok(sc.fusion_for_seed(self.sources.seed)?)
    }
}

impl GroupConfig {
    /// `run_dir`: a path, absolute under `base` where relative.
    fn resolve(&mut self, base: &Path, origin: &str) -> Result<(), ConfigError> {
        check_path(origin, "group.run_dir", &self.run_dir)?;
        if self.run_dir.is_relative() {
            self.run_dir = base.join(&self.run_dir);
        }
        Ok(())
    }
}

impl SourcesConfig {
    /// The drivers' sources, a replayed file's path absolute under `base`.
    fn resolve(&mut self, base: &Path, origin: &str) -> Result<(), ConfigError> {
        resolve_source("sources.imu", &mut self.imu, base, origin)?;
        resolve_source("sources.uwb", &mut self.uwb, base, origin)
    }

    /// A ROS 2 source is the IMU's only.
    fn check_ros2_imu_only(&self, origin: &str) -> Result<(), ConfigError> {
        if matches!(self.uwb, Source::Ros2 { .. }) {
            return Err(invalid(
                origin,
                "sources.uwb",
                format!(
                    "a ROS 2 source (ros2:TOPIC) is for the IMU only, got '{}'",
                    self.uwb
                ),
            ));
        }
        Ok(())
    }

    /// `speed`: a factor in (0, 1000] or `"max"`.
    fn check_speed(&self, origin: &str) -> Result<(), ConfigError> {
        let sp = self.speed;
        if sp > 0.0 && (sp <= 1000.0 || sp.is_infinite()) {
            return Ok(());
        }
        Err(invalid(
            origin,
            "sources.speed",
            format!("must be in (0, 1000] or \"max\", got {sp}"),
        ))
    }

    /// The scenario loads where a source is `sim`.
    fn check_scenario(&self, origin: &str) -> Result<(), ConfigError> {
        if self.imu == Source::Sim || self.uwb == Source::Sim {
            ScenarioFile::load(&self.scenario)
                .map_err(|e| invalid(origin, "sources.scenario", e.to_string()))?;
        }
        Ok(())
    }
}

/// One driver's source (`key`: `sources.imu` or `sources.uwb`): a
/// replayed file made absolute under `base`, which must exist.
fn resolve_source(
    key: &str,
    src: &mut Source,
    base: &Path,
    origin: &str,
) -> Result<(), ConfigError> {
    if let Source::Replay(file) = src {
        let p = if file.is_relative() {
            base.join(&*file)
        } else {
            file.clone()
        };
        if !p.is_file() {
            return Err(invalid(
                origin,
                key,
                format!("replay file {} does not exist", p.display()),
            ));
        }
        *file = p;
    }
    Ok(())
}

impl DevicesConfig {
    /// Each table present, and one for each driver whose source is `device`.
    fn check(&self, sources: &SourcesConfig, origin: &str) -> Result<(), ConfigError> {
        let imu_protocols: &[&str] = &["witmotion", "mavlink"];
        let uwb_protocols: &[&str] = &["nlink", "eliko", "dwm1001"];
        for (name, wanted, dev, protocols) in [
            (
                "imu",
                sources.imu == Source::Device,
                &self.imu,
                imu_protocols,
            ),
            (
                "uwb",
                sources.uwb == Source::Device,
                &self.uwb,
                uwb_protocols,
            ),
        ] {
            match dev {
                Some(d) => d.check(name, protocols, origin)?,
                None if wanted => {
                    return Err(invalid(
                        origin,
                        &format!("sources.{name}"),
                        format!("\"device\" needs a [devices.{name}] table"),
                    ))
                }
                None => {}
            }
        }
        Ok(())
    }
}

impl DeviceConfig {
    /// `[devices.<name>]`: a known protocol, a link, sane rates, backoff
    /// and geometry.
    fn check(&self, name: &str, protocols: &[&str], origin: &str) -> Result<(), ConfigError> {
        let table = format!("devices.{name}");
        let bad = |key: &str, message: String| Err(invalid(origin, key, message));
        if !protocols.contains(&self.protocol.as_str()) {
            return bad(
                &format!("{table}.protocol"),
                format!(
                    "unknown protocol '{}' (known: {})",
                    self.protocol,
                    protocols.join(", ")
                ),
            );
        }
        if let Err(e) = self.source.parse::<insuwb_devices::link::LinkSpec>() {
            return bad(&format!("{table}.source"), e.to_string());
        }
        if self.baud == 0 || self.wrong_baud_bytes == 0 {
            return bad(&table, "baud and wrong_baud_bytes must be > 0".to_owned());
        }
        if !(self.position_sigma_m.is_finite() && self.position_sigma_m > 0.0) {
            return bad(
                &format!("{table}.position_sigma_m"),
                "must be > 0".to_owned(),
            );
        }
        if self.reconnect_initial_ms == 0 || self.reconnect_max_ms < self.reconnect_initial_ms {
            return bad(
                &table,
                "need 0 < reconnect_initial_ms <= reconnect_max_ms".to_owned(),
            );
        }
        if self
            .rotation_deg
            .iter()
            .chain(&self.lever_arm_m)
            .any(|v| !v.is_finite())
        {
            return bad(
                &table,
                "rotation_deg and lever_arm_m must be finite".to_owned(),
            );
        }
        for (i, a) in self.anchors.iter().enumerate() {
            if a.pos_m.iter().any(|v| !v.is_finite()) {
                return bad(
                    &format!("{table}.anchors[{i}].pos_m"),
                    format!("anchor {} has a position that is not finite", a.id),
                );
            }
            if self.anchors.iter().take(i).any(|b| b.id == a.id) {
                return bad(
                    &format!("{table}.anchors[{i}].id"),
                    format!("anchor {} is listed twice", a.id),
                );
            }
        }
        Ok(())
    }
}

/// The keys of the estimator's settings (`insuwb_fusion::config::FusionConfig`'s
/// tables and values), which robot.toml's `[fusion]` does not hold.
const ESTIMATOR_KEYS: [&str; 15] = [
    "ins",
    "fix",
    "engine",
    "model",
    "filter",
    "setup",
    "loose",
    "eskf",
    "tight",
    "vibration",
    "vehicle",
    "multirotor",
    "ground",
    "output",
    "aiding",
];

/// robot.toml's `[fusion]` is the fusion process's table: one of the
/// estimator settings' keys written there (`[fusion.fix]`, a
/// `[fusion.filter]` table) is refused, saying where it goes. A text that
/// does not parse is left to the parser's message.
fn check_fusion_keys(text: &str, origin: &str) -> Result<(), ConfigError> {
    let Ok(doc) = toml::from_str::<toml::Table>(text) else {
        return Ok(());
    };
    let Some(toml::Value::Table(fusion)) = doc.get("fusion") else {
        return Ok(());
    };
    for (key, value) in fusion {
        let estimator = match key.as_str() {
            "filter" => value.is_table(),
            k => ESTIMATOR_KEYS.contains(&k),
        };
        if estimator {
            return Err(invalid(
                origin,
                &format!("fusion.{key}"),
                "an estimator setting, not the fusion process's: write it in the [fusion] table of the file that `fusion.config` names (e.g. config/util.toml; left empty, the scenario's or the replayed log's own are used); robot.toml's [fusion] holds filter (a name), config, checkpoint_period_s, eager_lag_s and aiding_sources",
            ));
        }
    }
    Ok(())
}

/// `[realtime.<stage>]`: valid settings (the keys, stage roles, were
/// checked as they were parsed).
fn check_realtime(
    realtime: &BTreeMap<StageRole, RealtimeConfig>,
    origin: &str,
) -> Result<(), ConfigError> {
    for (stage, rt) in realtime {
        let key = format!("realtime.{stage}");
        rt.validate()
            .map_err(|e| invalid(origin, &key, e.to_string()))?;
    }
    Ok(())
}

impl FusionProcessConfig {
    /// `config`: a file, absolute under `base`, whose `[fusion]` table
    /// reads as the estimator's settings (an error names that file and its
    /// key, before any stage starts); a positive checkpoint period.
    fn resolve(&mut self, base: &Path, origin: &str) -> Result<(), ConfigError> {
        if !self.config.is_empty() {
            let p = under(base, &self.config);
            if !p.is_file() {
                return Err(invalid(
                    origin,
                    "fusion.config",
                    format!("file {} does not exist", p.display()),
                ));
            }
            self.config = p.display().to_string();
            fusion_table(&insuwb_config::read_text(&p)?, &self.config)?;
        }
        let v = self.checkpoint_period_s;
        if !(v.is_finite() && v > 0.0) {
            return Err(invalid(
                origin,
                "fusion.checkpoint_period_s",
                format!("must be > 0, got {v}"),
            ));
        }
        Ok(())
    }
}

/// `[launch]`: a valid restart policy whose optional stages are stage roles.
fn check_launch(launch: &RestartPolicy, origin: &str) -> Result<(), ConfigError> {
    launch
        .validate()
        .map_err(|e| invalid(origin, "launch", e.to_string()))?;
    match launch
        .optional
        .iter()
        .find(|s| s.parse::<StageRole>().is_err())
    {
        Some(s) => Err(invalid(
            origin,
            "launch.optional",
            format!(
                "unknown stage '{s}' (known: {})",
                StageRole::NAMES.join(", ")
            ),
        )),
        None => Ok(()),
    }
}

impl LoggerConfig {
    /// `dir`: a path, relative ones without `..`.
    fn check_dir(&self, origin: &str) -> Result<(), ConfigError> {
        let Some(dir) = &self.dir else {
            return Ok(());
        };
        check_path(origin, "logger.dir", dir)?;
        if dir.is_relative() && dir.components().any(|c| matches!(c, Component::ParentDir)) {
            return Err(invalid(
                origin,
                "logger.dir",
                format!(
                    "a relative path must stay inside the run directory (no '..'), got {}",
                    dir.display()
                ),
            ));
        }
        Ok(())
    }

    /// `[logger.segments]`.
    fn check_segments(&self, origin: &str) -> Result<(), ConfigError> {
        self.segments
            .validate()
            .map_err(|e| invalid(origin, "logger.segments", e.to_string()))
    }
}

/// A configured path must be non-empty and free of NUL bytes.
fn check_path(origin: &str, key: &str, p: &Path) -> Result<(), ConfigError> {
    let bytes = p.as_os_str().as_encoded_bytes();
    if bytes.is_empty() || bytes.contains(&0) {
        return Err(invalid(
            origin,
            key,
            format!("must be a non-empty path without NUL bytes, got {p:?}"),
        ));
    }
    Ok(())
}

/// `file` under `base` where relative.
fn under(base: &Path, file: &str) -> PathBuf {
    let p = Path::new(file);
    if p.is_relative() {
        base.join(p)
    } else {
        p.to_owned()
    }
}

/// The start epoch from the environment, or one chosen now: the next epoch
/// ([`insuwb_runtime::epoch`]: a whole second plus 2.5 ms, off the kernel's
/// tick) at least 0.5 s ahead.
#[must_use]
pub fn start_epoch_ns() -> u64 {
    if let Some(v) = std::env::var(START_EPOCH_ENV)
        .ok()
        .and_then(|v| v.parse().ok())
    {
        return v;
    }
    choose_start_epoch(insuwb_runtime::monotonic_ns())
}

/// The first epoch ([`insuwb_runtime::epoch`]) at least 0.5 s after `now_ns`.
#[must_use]
pub fn choose_start_epoch(now_ns: u64) -> u64 {
    insuwb_runtime::epoch::epoch_at_or_after(now_ns.saturating_add(500_000_000))
}

#[cfg(test)]
mod tests {
    use super::*;

    const ROBOT: &str = include_str!("../../../config/robot.toml");

    fn load(extra_top: &str, extra_tables: &str) -> Result<RobotConfig, RobotConfigError> {
        RobotConfig::from_str(
            &format!("{extra_top}{ROBOT}{extra_tables}"),
            "robot.toml",
            Path::new("/tmp"),
        )
    }

    /// `[fusion] aiding_sources` names what aids the filter: the flow deck
    /// gives body velocities and heights, odometry velocities alone, a
    /// range finder heights alone; an unknown name is refused, naming it.
    #[test]
    fn aiding_sources_say_which_velocities_and_heights_the_filter_takes() {
        let at = |list: &str| {
            RobotConfig::from_str(
                &format!("[fusion]\naiding_sources = {list}\n"),
                "robot.toml",
                Path::new("/tmp"),
            )
        };
        let c = at(r#"["flow", "odometry", "range_finder"]"#).unwrap();
        let got: Vec<(Option<u32>, bool)> = c
            .fusion
            .aiding_sources
            .iter()
            .map(|s| (s.velocity_code(), s.gives_height()))
            .collect();
        assert_eq!(
            got,
            [
                (Some(insuwb_msg::BodyVelocity::SOURCE_FLOW), true),
                (Some(insuwb_msg::BodyVelocity::SOURCE_ODOMETRY), false),
                (None, true)
            ]
        );
        assert!(load("", "").unwrap().fusion.aiding_sources.is_empty());
        let e = at(r#"["sonar"]"#).unwrap_err().to_string();
        assert!(e.contains("sonar") && e.contains("range_finder"), "{e}");
    }

    /// `[uwb] kind` must agree with its source: the scenario, the device's
    /// protocol; the error names the key and the fix.
    #[test]
    fn the_uwb_kind_agrees_with_its_source() {
        let at = |text: &str| RobotConfig::from_str(text, "robot.toml", Path::new("/tmp"));
        let sim = |scenario: &str, kind: &str| {
            at(&format!(
                "[sources]\nimu = \"sim\"\nuwb = \"sim\"\nscenario = \"{scenario}\"\n[uwb]\nkind = \"{kind}\"\n"
            ))
        };
        assert_eq!(sim("nlos-long", "tdoa").unwrap().uwb.kind, UwbKind::Tdoa);
        assert_eq!(sim("nlos-long-twr", "twr").unwrap().uwb.kind, UwbKind::Twr);
        let e = sim("nlos-long-twr", "tdoa").unwrap_err().to_string();
        assert!(
            e.contains("uwb.kind") && e.contains("nlos-long-twr") && e.contains("kind = \"twr\""),
            "{e}"
        );
        let e = sim("nlos-long", "twr").unwrap_err().to_string();
        assert!(
            e.contains("uwb.kind") && e.contains("kind = \"tdoa\""),
            "{e}"
        );
        let e = sim("nlos-long", "aoa").unwrap_err().to_string();
        assert!(e.contains("aoa"), "{e}");
        let device = |protocol: &str, kind: &str, anchors: &str| {
            at(&format!(
                "[sources]\nuwb = \"device\"\n[uwb]\nkind = \"{kind}\"\n[devices.uwb]\nsource = \"serial:/dev/ttyACM0\"\nprotocol = \"{protocol}\"\n{anchors}"
            ))
        };
        let anchor = "[[devices.uwb.anchors]]\nid = 0x1A2B\npos_m = [1.0, 2.0, 3.0]\n";
        let c = device("dwm1001", "twr", anchor).unwrap();
        let d = c.devices.uwb.unwrap();
        assert_eq!(
            d.anchors,
            [AnchorConfig {
                id: 0x1A2B,
                pos_m: [1.0, 2.0, 3.0]
            }]
        );
        device("nlink", "twr", "").unwrap();
        device("nlink", "tdoa", "").unwrap();
        let e = device("dwm1001", "tdoa", "").unwrap_err().to_string();
        assert!(e.contains("uwb.kind") && e.contains("dwm1001"), "{e}");
        let e = device("eliko", "twr", "").unwrap_err().to_string();
        assert!(e.contains("uwb.kind") && e.contains("eliko"), "{e}");
        let e = device("dwm1001", "twr", &format!("{anchor}{anchor}"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("devices.uwb.anchors[1].id"), "{e}");
        let e = device(
            "dwm1001",
            "twr",
            "[[devices.uwb.anchors]]\nid = 1\npos_m = [1.0, nan, 3.0]\n",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("devices.uwb.anchors[0].pos_m"), "{e}");
    }

    /// Nothing is opened on the network by default: the ROS 2 bridge runs
    /// only where `stages` lists it, then after fusion and optional.
    #[test]
    fn ros2_runs_only_when_listed_after_fusion_and_optional() {
        let plain = load("", "").unwrap();
        assert_eq!(plain.stages, StageRole::DEFAULT);
        assert!(!plain.stages.contains(&StageRole::Ros2));
        assert_eq!(plain.ros2, insuwb_ros2::Ros2Config::default());
        let listed = load(
            "stages = [\"imu\", \"uwb\", \"ins\", \"ros2\", \"fusion\", \"logger\"]\n",
            "",
        )
        .unwrap();
        let mut want = StageRole::DEFAULT.to_vec();
        want.insert(4, StageRole::Ros2);
        assert_eq!(listed.stages, want, "ros2 moved after fusion");
        assert!(listed.launch.is_optional("ros2"));
        let mut c = RobotConfig::from_str(
            "stages = [\"imu\", \"uwb\", \"ins\", \"fusion\", \"ros2\"]\n[launch]\noptional = []\n",
            "robot.toml",
            Path::new("/tmp"),
        )
        .unwrap();
        assert!(c.launch.is_optional("ros2"), "{:?}", c.launch.optional);
        c.place_optional();
        assert_eq!(c.launch.optional, ["ros2"], "added once");
    }

    /// The Foxglove live view likewise, after the ROS 2 bridge too.
    #[test]
    fn foxglove_runs_only_when_listed_after_fusion_and_ros2_and_optional() {
        let plain = load("", "").unwrap();
        assert!(!plain.stages.contains(&StageRole::Foxglove));
        assert_eq!(plain.foxglove, insuwb_foxglove::FoxgloveConfig::default());
        let all = load(
            "stages = [\"foxglove\", \"imu\", \"uwb\", \"ins\", \"fusion\", \"ros2\", \"logger\"]\n",
            "",
        )
        .unwrap();
        let want: Vec<StageRole> = StageRole::ALL
            .into_iter()
            .filter(|r| *r != StageRole::Zenoh)
            .collect();
        assert_eq!(all.stages, want, "foxglove moved after ros2");
        assert!(all.launch.is_optional("foxglove") && all.launch.is_optional("ros2"));
        let mut c = RobotConfig::from_str(
            "stages = [\"imu\", \"foxglove\", \"uwb\", \"ins\", \"fusion\"]\n[launch]\noptional = []\n[foxglove]\nbind = \"127.0.0.1:0\"\npath_length = 10\n",
            "robot.toml",
            Path::new("/tmp"),
        )
        .unwrap();
        assert_eq!(c.stages.last(), Some(&StageRole::Foxglove));
        assert_eq!(c.foxglove.path_length, 10);
        c.place_optional();
        assert_eq!(c.launch.optional, ["foxglove"], "added once");
    }

    /// The Zenoh bridge likewise, last of the three; its table is checked
    /// as the bridge needs it only where it runs.
    #[test]
    fn zenoh_runs_only_when_listed_after_the_other_bridges_and_optional() {
        let plain = load("", "").unwrap();
        assert!(!plain.stages.contains(&StageRole::Zenoh));
        assert_eq!(plain.zenoh, insuwb_zenoh::ZenohConfig::default());
        let table = "[zenoh]\nrobot = \"r1\"\nconnect = [\"tcp/127.0.0.1:7447\"]\n";
        let all = RobotConfig::from_str(
            &format!("stages = [\"zenoh\", \"imu\", \"uwb\", \"ins\", \"fusion\", \"ros2\", \"foxglove\", \"logger\"]\n{table}"),
            "robot.toml",
            Path::new("/tmp"),
        )
        .unwrap();
        assert_eq!(all.stages, StageRole::ALL, "zenoh moved after foxglove");
        assert!(all.launch.is_optional("zenoh"));
        assert_eq!(all.zenoh.robot, "r1");
        // Listed without a robot id or an endpoint: refused, naming the key
        // and the line of its table.
        for (text, key) in [
            (
                "[zenoh]\nconnect = [\"tcp/127.0.0.1:7447\"]\n",
                "zenoh.robot",
            ),
            ("[zenoh]\nrobot = \"r1\"\n", "zenoh.connect"),
        ] {
            let e = RobotConfig::from_str(
                &format!("stages = [\"imu\", \"uwb\", \"ins\", \"fusion\", \"zenoh\"]\n{text}"),
                "robot.toml",
                Path::new("/tmp"),
            );
            let msg = format!("{:#}", e.unwrap_err());
            assert!(msg.contains(&format!("robot.toml:2: key '{key}'")), "{msg}");
        }
    }

    /// `[uwb] calibration`: read (relative to the file's folder) when the
    /// robot config is loaded and handed to every stage's fusion settings;
    /// a file that is missing or not a calibration is named with the line
    /// and the key.
    #[test]
    fn the_uwb_calibration_is_read_under_the_file() {
        let dir = std::env::temp_dir().join(format!("insuwb-robot-calib-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(
            dir.join("site.toml"),
            "format_version = 1\n[site]\nfamily = \"pair_constant\"\nanchors = [{ id = 0, pos_m = [0, 0, 0] }, { id = 1, pos_m = [1, 0, 0] }]\n[[pairs]]\na = 0\nb = 1\nbias_m = 0.1\nnoise_m = 0.2\n",
        )
        .unwrap();
        let c = RobotConfig::from_str("[uwb]\ncalibration = \"site.toml\"\n", "robot.toml", &dir)
            .unwrap();
        let f = c.fusion_config().unwrap();
        assert_eq!(f.calibration.unwrap().bias(1, 0, None), -0.1);
        let e = RobotConfig::from_str("[uwb]\ncalibration = \"nope.toml\"\n", "robot.toml", &dir);
        let msg = format!("{:#}", e.unwrap_err());
        assert!(
            msg.contains("robot.toml:2: key 'uwb.calibration'") && msg.contains("nope.toml"),
            "{msg}"
        );
        std::fs::write(
            dir.join("bad.toml"),
            "format_version = 1\n[site]\nfamily = \"x\"\nanchors = []\n",
        )
        .unwrap();
        let e = RobotConfig::from_str("[uwb]\ncalibration = \"bad.toml\"\n", "robot.toml", &dir);
        let msg = format!("{:#}", e.unwrap_err());
        assert!(msg.contains("key 'site.family'"), "{msg}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_bad_zenoh_key_is_named_and_certificates_are_under_the_file() {
        let e = RobotConfig::from_str(
            "[zenoh]\nlisten = [\"udp/0.0.0.0:7447\"]\n",
            "robot.toml",
            Path::new("/tmp"),
        );
        let msg = format!("{:#}", e.unwrap_err());
        assert!(msg.contains("robot.toml:2: key 'zenoh.listen'"), "{msg}");
        let e = RobotConfig::from_str(
            "[zenoh.tls]\nroot_ca_certificate = \"certs/ca.pem\"\n",
            "robot.toml",
            Path::new("/nonexistent-insuwb"),
        );
        let msg = format!("{:#}", e.unwrap_err());
        assert!(
            msg.contains("robot.toml:2: key 'zenoh.tls.root_ca_certificate': file /nonexistent-insuwb/certs/ca.pem does not exist"),
            "{msg}"
        );
        let e = RobotConfig::from_str(
            "[zenoh]\nscouting = true\n",
            "robot.toml",
            Path::new("/tmp"),
        );
        assert!(format!("{:#}", e.unwrap_err()).contains("zenoh"));
    }

    #[test]
    fn a_bad_foxglove_key_is_named() {
        let e = RobotConfig::from_str(
            "[foxglove]\nbind = \"0.0.0.0\"\n",
            "robot.toml",
            Path::new("/tmp"),
        );
        let msg = format!("{:#}", e.unwrap_err());
        assert!(msg.contains("robot.toml:2: key 'foxglove.bind'"), "{msg}");
        let e = RobotConfig::from_str("[foxglove]\nport = 1\n", "robot.toml", Path::new("/tmp"));
        assert!(format!("{:#}", e.unwrap_err()).contains("foxglove"));
    }

    #[test]
    fn a_bad_ros2_key_is_named() {
        let text = ROBOT.replacen("frame_id = \"map\"", "frame_id = \"/map\"", 1);
        assert_ne!(text, ROBOT);
        let line = 1 + text
            .lines()
            .position(|l| l.starts_with("frame_id = \"/map\""))
            .unwrap();
        let e = RobotConfig::from_str(&text, "robot.toml", Path::new("/tmp"));
        let msg = format!("{:#}", e.unwrap_err());
        assert!(
            msg.contains(&format!("robot.toml:{line}: key 'ros2.frame_id'")),
            "{msg}"
        );
        let e = RobotConfig::from_str("[ros2]\nodom = \"x\"\n", "robot.toml", Path::new("/tmp"));
        assert!(format!("{:#}", e.unwrap_err()).contains("ros2"));
    }

    /// robot.toml's `[fusion]` refuses exactly the estimator's keys: those
    /// `FusionConfig` writes, and its `output` (not written when absent).
    #[test]
    fn the_estimator_keys_are_fusion_config_s() {
        let t = toml::Table::try_from(FusionConfig::default()).unwrap();
        let mut want: Vec<&str> = t.keys().map(String::as_str).collect();
        want.push("output");
        want.sort_unstable();
        let mut have = ESTIMATOR_KEYS.to_vec();
        have.sort_unstable();
        assert_eq!(have, want);
    }

    /// `[ros2] odometry_in` and `height_in` are read by the bridge: refused,
    /// naming the key and `stages`, where `stages` does not list `ros2`.
    #[test]
    fn ros2_inputs_need_the_ros2_stage() {
        for (key, topic) in [("odometry_in", "/wheel/odom"), ("height_in", "/flow/range")] {
            let table = format!("[ros2]\n{key} = \"{topic}\"\n");
            let e = RobotConfig::from_str(&table, "robot.toml", Path::new("/tmp")).unwrap_err();
            let msg = format!("{e:#}");
            assert!(
                msg.contains(&format!("robot.toml:2: key 'ros2.{key}'")),
                "{msg}"
            );
            assert!(
                msg.contains(&format!("[ros2] {key}")) && msg.contains("stages"),
                "{msg}"
            );
            let c = RobotConfig::from_str(
                &format!("stages = [\"imu\", \"uwb\", \"ins\", \"fusion\", \"ros2\"]\n{table}"),
                "robot.toml",
                Path::new("/tmp"),
            )
            .unwrap();
            let name = match key {
                "odometry_in" => c.ros2.odometry_in_topic_name(),
                _ => c.ros2.height_in_topic_name(),
            };
            assert_eq!(name.as_deref(), Some(topic));
        }
        let bad = RobotConfig::from_str(
            "stages = [\"ros2\"]\n[ros2]\nodometry_in = \"/wheel/odom\"\nodometry_in_sigma_mps = -1.0\n",
            "robot.toml",
            Path::new("/tmp"),
        );
        let msg = format!("{:#}", bad.unwrap_err());
        assert!(
            msg.contains("robot.toml:4: key 'ros2.odometry_in_sigma_mps'"),
            "{msg}"
        );
    }

    /// `sources.imu = "ros2:/TOPIC"`: a ROS topic name, IMU only; the
    /// error names the file, the line and the key.
    #[test]
    fn a_ros2_imu_source_is_checked() {
        let with = |imu: &str, uwb: &str| {
            RobotConfig::from_str(
                &format!("[sources]\nimu = \"{imu}\"\nuwb = \"{uwb}\"\n"),
                "robot.toml",
                Path::new("/tmp"),
            )
        };
        let c = with("ros2:/imu/data", "sim").unwrap();
        assert_eq!(
            c.sources.imu,
            Source::Ros2 {
                topic: "/imu/data".into()
            }
        );
        with("ros2:imu", "sim").unwrap();
        for bad in ["ros2:/imu//data", "ros2:", "ros2:/9imu", "ros2:/imu/"] {
            let msg = format!("{:#}", with(bad, "sim").unwrap_err());
            assert!(msg.contains("robot.toml:2: key 'sources.imu'"), "{msg}");
        }
        let msg = format!("{:#}", with("sim", "ros2:/uwb").unwrap_err());
        assert!(
            msg.contains("robot.toml:3: key 'sources.uwb'") && msg.contains("IMU only"),
            "{msg}"
        );
        let msg = format!("{:#}", with("ros:/imu", "sim").unwrap_err());
        assert!(msg.contains("ros2:/TOPIC"), "{msg}");
    }
}
