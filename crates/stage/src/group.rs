//! The robot group configuration (`config/robot.toml`): deployment (prefix,
//! run directory), sensor sources, fusion settings, logger and restart
//! policy. Every stage and the launcher read the same file, so they agree.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use insuwb_fusion::config::FusionConfig;
use insuwb_msg::{FilterKind, StageRole};
use serde::{Deserialize, Serialize};

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
    /// IMU source: `sim`, `replay:FILE` (an insuwb log), `device` or
    /// `ros2:/TOPIC` (`sensor_msgs/Imu` over DDS, node, namespace and domain
    /// from `[ros2]`; see `crate::ros2_source`).
    pub imu: String,
    /// UWB source: `sim` or `replay:FILE`.
    pub uwb: String,
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

impl Default for SourcesConfig {
    fn default() -> Self {
        Self {
            imu: "sim".into(),
            uwb: "sim".into(),
            scenario: "nlos-long".into(),
            seed: 1,
            speed: 1.0,
        }
    }
}

/// Fusion stage settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FusionStageConfig {
    /// Filter: kf, shaf, stf, iakf, iakf_tdoa.
    pub filter: FilterKind,
    /// Fusion settings file (with a `[fusion]` table); empty: the scenario's
    /// (sim sources) or the replayed log's own.
    pub config: String,
    /// Checkpoint period, s (a restarted fusion stage resumes from it).
    pub checkpoint_period_s: f64,
    /// Predict through INS states as they arrive, keeping the newest this
    /// many seconds buffered for UWB samples still on their way, s (see
    /// `FusionEngineConfig::eager_lag_s`): takes the prediction off the
    /// fix-to-fused path and lets the coasting covariance grow. The result is
    /// the lazy engine's while a UWB sample of time t arrives before the INS
    /// state at t + one IMU period + this lag (15 ms at 100 Hz with the
    /// default 5 ms; the fix usually arrives first); a later one is applied
    /// on the INS state interpolated at t, one older than the INS interval
    /// processed last is dropped (counted). Each 10 ms of lag keeps one more
    /// covariance prediction on the fix-to-fused path. Negative: off.
    /// Ignored at `speed = "max"` (the drivers run ahead there).
    pub eager_lag_s: f64,
}

impl Default for FusionStageConfig {
    fn default() -> Self {
        Self {
            filter: FilterKind::Iakf,
            config: String::new(),
            checkpoint_period_s: 0.5,
            eager_lag_s: 0.005,
        }
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
            wrong_baud_bytes: 4096,
            reconnect_initial_ms: 50,
            reconnect_max_ms: 500,
        }
    }
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
    /// Fusion stage.
    pub fusion: FusionStageConfig,
    /// Logger.
    pub logger: LoggerConfig,
    /// Stages to run, in start order (default: imu, uwb, ins, fusion,
    /// logger; `ros2`, `foxglove` and `zenoh` run only where listed, always
    /// after fusion, in that order, and always optional).
    pub stages: Vec<StageRole>,
    /// Restart policy of the launcher.
    pub launch: insuwb_launch::RestartPolicy,
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
    /// `cpus = [1]`, `fifo_priority = 50`); none by default.
    pub realtime: std::collections::BTreeMap<String, insuwb_runtime::realtime::RealtimeConfig>,
}

impl RobotConfig {
    /// Loads and checks a robot config file; relative paths become relative to its folder.
    pub fn load(path: &Path) -> Result<Self> {
        let mut c: Self = insuwb_config::load_file(path)?;
        let base = path.parent().unwrap_or(Path::new("."));
        // Relative paths in the file are relative to its folder, made
        // absolute here (the iceoryx2 root must be absolute).
        let base = if base.is_absolute() {
            base.to_path_buf()
        } else {
            std::env::current_dir()
                .context("reading the current directory")?
                .join(base)
        };
        c.resolve(&base, &path.display().to_string())?;
        Ok(c)
    }

    /// Parses a config text (for built-ins and tests).
    pub fn from_str(text: &str, origin: &str, base: &Path) -> Result<Self> {
        let mut c: Self = insuwb_config::load_str(text, origin)?;
        c.resolve(base, origin)?;
        Ok(c)
    }

    fn resolve(&mut self, base: &Path, origin: &str) -> Result<()> {
        if self.stages.is_empty() {
            self.stages = StageRole::DEFAULT.to_vec();
        }
        self.place_optional();
        check_path(origin, "group.run_dir", &self.group.run_dir)?;
        if self.group.run_dir.is_relative() {
            self.group.run_dir = base.join(&self.group.run_dir);
        }
        if let Some(dir) = &self.logger.dir {
            check_path(origin, "logger.dir", dir)?;
            if dir.is_relative()
                && dir
                    .components()
                    .any(|c| matches!(c, std::path::Component::ParentDir))
            {
                bail!(
                    "{origin}: key 'logger.dir': a relative path must stay inside the run directory (no '..'), got {}",
                    dir.display()
                );
            }
        }
        for (key, src) in [
            ("sources.imu", &mut self.sources.imu),
            ("sources.uwb", &mut self.sources.uwb),
        ] {
            match src.split_once(':') {
                None if src == "sim" => {}
                None if src == "device" => {}
                Some(("replay", file)) => {
                    let p = Path::new(file);
                    let p = if p.is_relative() {
                        base.join(p)
                    } else {
                        p.to_owned()
                    };
                    if !p.is_file() {
                        bail!(
                            "{origin}: key '{key}': replay file {} does not exist",
                            p.display()
                        );
                    }
                    *src = format!("replay:{}", p.display());
                }
                Some(("ros2", topic)) if key == "sources.imu" => {
                    if let Err(e) = insuwb_ros2::config::check_topic_name(topic) {
                        bail!("{origin}: key '{key}': ros2:TOPIC: {e}");
                    }
                }
                Some(("ros2", _)) => bail!(
                    "{origin}: key '{key}': a ROS 2 source (ros2:TOPIC) is for the IMU only, got '{src}'"
                ),
                _ if key == "sources.imu" => bail!(
                    "{origin}: key '{key}': unknown source '{src}' (sim, replay:FILE, device or ros2:/TOPIC)"
                ),
                _ => bail!(
                    "{origin}: key '{key}': unknown source '{src}' (sim, replay:FILE or device)"
                ),
            }
        }
        for (key, want, dev, protocols) in [
            (
                "imu",
                self.sources.imu == "device",
                &self.devices.imu,
                ["witmotion", "mavlink"],
            ),
            (
                "uwb",
                self.sources.uwb == "device",
                &self.devices.uwb,
                ["nlink", "eliko"],
            ),
        ] {
            match (want, dev) {
                (true, None) => {
                    bail!("{origin}: key 'sources.{key}': \"device\" needs a [devices.{key}] table")
                }
                (_, Some(d)) => {
                    if !protocols.contains(&d.protocol.as_str()) {
                        bail!(
                            "{origin}: key 'devices.{key}.protocol': unknown protocol '{}' (known: {})",
                            d.protocol,
                            protocols.join(", ")
                        );
                    }
                    if let Err(e) = d.source.parse::<insuwb_devices::link::LinkSpec>() {
                        bail!("{origin}: key 'devices.{key}.source': {e}");
                    }
                    if d.baud == 0 || d.wrong_baud_bytes == 0 {
                        bail!(
                            "{origin}: key 'devices.{key}': baud and wrong_baud_bytes must be > 0"
                        );
                    }
                    if !(d.position_sigma_m.is_finite() && d.position_sigma_m > 0.0) {
                        bail!("{origin}: key 'devices.{key}.position_sigma_m': must be > 0");
                    }
                    if d.reconnect_initial_ms == 0 || d.reconnect_max_ms < d.reconnect_initial_ms {
                        bail!(
                            "{origin}: key 'devices.{key}': need 0 < reconnect_initial_ms <= reconnect_max_ms"
                        );
                    }
                    if d.rotation_deg
                        .iter()
                        .chain(&d.lever_arm_m)
                        .any(|v| !v.is_finite())
                    {
                        bail!("{origin}: key 'devices.{key}': rotation_deg and lever_arm_m must be finite");
                    }
                }
                (false, None) => {}
            }
        }
        for (stage, rt) in &self.realtime {
            if stage.parse::<StageRole>().is_err() {
                bail!(
                    "{origin}: key 'realtime.{stage}': unknown stage (known: {})",
                    StageRole::NAMES.join(", ")
                );
            }
            if let Err(e) = rt.validate() {
                bail!("{origin}: key 'realtime.{stage}': {e}");
            }
        }
        let sp = self.sources.speed;
        if !(sp > 0.0 && (sp <= 1000.0 || sp.is_infinite())) {
            bail!("{origin}: key 'sources.speed': must be in (0, 1000] or \"max\", got {sp}");
        }
        if !self.fusion.config.is_empty() {
            let p = Path::new(&self.fusion.config);
            let p = if p.is_relative() {
                base.join(p)
            } else {
                p.to_owned()
            };
            if !p.is_file() {
                bail!(
                    "{origin}: key 'fusion.config': file {} does not exist",
                    p.display()
                );
            }
            self.fusion.config = p.display().to_string();
        }
        let v = self.fusion.checkpoint_period_s;
        if !(v.is_finite() && v > 0.0) {
            bail!("{origin}: key 'fusion.checkpoint_period_s': must be > 0, got {v}");
        }
        self.launch
            .validate()
            .map_err(|e| anyhow::anyhow!("{origin}: key 'launch': {e}"))?;
        if let Some(s) = self
            .launch
            .optional
            .iter()
            .find(|s| s.parse::<StageRole>().is_err())
        {
            bail!(
                "{origin}: key 'launch.optional': unknown stage '{s}' (known: {})",
                StageRole::NAMES.join(", ")
            );
        }
        self.ros2
            .validate()
            .map_err(|e| anyhow::anyhow!("{origin}: {e}"))?;
        self.foxglove
            .validate()
            .map_err(|e| anyhow::anyhow!("{origin}: {e}"))?;
        self.zenoh.resolve_paths(base);
        if self.stages.contains(&StageRole::Zenoh) {
            self.zenoh.validate_enabled()
        } else {
            self.zenoh.validate()
        }
        .map_err(|e| anyhow::anyhow!("{origin}: {e}"))?;
        self.logger
            .segments
            .validate()
            .map_err(|e| anyhow::anyhow!("{origin}: key 'logger.segments': {e}"))?;
        if matches!(self.sources.imu.as_str(), "sim") || matches!(self.sources.uwb.as_str(), "sim")
        {
            insuwb_group::ScenarioFile::load(&self.sources.scenario)
                .with_context(|| format!("{origin}: key 'sources.scenario'"))?;
        }
        Ok(())
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
            realtime: self.realtime.get(name).cloned().unwrap_or_default(),
            ..insuwb_runtime::RuntimeConfig::default()
        }
    }

    /// The fusion settings every stage uses: `fusion.config`'s `[fusion]`
    /// table if set, else the scenario's (sim, INS start for `sources.seed`),
    /// else the replayed log's metadata.
    pub fn fusion_config(&self) -> Result<FusionConfig> {
        let mut f = self.fusion_config_file()?;
        // A UWB device's antenna lever arm (robot.toml) is the loose filters'.
        if let (true, Some(d)) = (self.sources.uwb == "device", &self.devices.uwb) {
            if d.lever_arm_m != [0.0; 3] {
                f.loose.lever_arm_m = d.lever_arm_m;
            }
        }
        Ok(f)
    }

    fn fusion_config_file(&self) -> Result<FusionConfig> {
        if !self.fusion.config.is_empty() {
            let text = std::fs::read_to_string(&self.fusion.config)
                .with_context(|| format!("{}: cannot read", self.fusion.config))?;
            // Only the [fusion] table matters here; other tables are the file's business.
            return Ok(insuwb_group::fusion_table(&text, &self.fusion.config)?);
        }
        if let Some(file) = self.sources.imu.strip_prefix("replay:") {
            let (_, _, header) =
                insuwb_log::read_all(file).with_context(|| format!("{file}: cannot read"))?;
            return Ok(match header.meta.entries.get("fusion_config") {
                Some(text) => insuwb_group::fusion_table(text, file)?,
                None => FusionConfig::default(),
            });
        }
        let sc = insuwb_group::ScenarioFile::load(&self.sources.scenario)?;
        Ok(sc.fusion_for_seed(self.sources.seed)?)
    }
}

/// A configured path must be non-empty and free of NUL bytes.
fn check_path(origin: &str, key: &str, p: &Path) -> Result<()> {
    let bytes = p.as_os_str().as_encoded_bytes();
    if bytes.is_empty() || bytes.contains(&0) {
        bail!("{origin}: key '{key}': must be a non-empty path without NUL bytes, got {p:?}");
    }
    Ok(())
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

    fn load(extra_top: &str, extra_tables: &str) -> Result<RobotConfig> {
        RobotConfig::from_str(
            &format!("{extra_top}{ROBOT}{extra_tables}"),
            "robot.toml",
            Path::new("/tmp"),
        )
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
        // Listed without a robot id or an endpoint: refused, naming the key.
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
            assert!(msg.contains(&format!("robot.toml: key '{key}'")), "{msg}");
        }
    }

    #[test]
    fn a_bad_zenoh_key_is_named_and_certificates_are_under_the_file() {
        let e = RobotConfig::from_str(
            "[zenoh]\nlisten = [\"udp/0.0.0.0:7447\"]\n",
            "robot.toml",
            Path::new("/tmp"),
        );
        let msg = format!("{:#}", e.unwrap_err());
        assert!(msg.contains("robot.toml: key 'zenoh.listen'"), "{msg}");
        let e = RobotConfig::from_str(
            "[zenoh.tls]\nroot_ca_certificate = \"certs/ca.pem\"\n",
            "robot.toml",
            Path::new("/nonexistent-insuwb"),
        );
        let msg = format!("{:#}", e.unwrap_err());
        assert!(
            msg.contains("key 'zenoh.tls.root_ca_certificate': file /nonexistent-insuwb/certs/ca.pem does not exist"),
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
        assert!(msg.contains("robot.toml: key 'foxglove.bind'"), "{msg}");
        let e = RobotConfig::from_str("[foxglove]\nport = 1\n", "robot.toml", Path::new("/tmp"));
        assert!(format!("{:#}", e.unwrap_err()).contains("foxglove"));
    }

    #[test]
    fn a_bad_ros2_key_is_named() {
        let text = ROBOT.replacen("frame_id = \"map\"", "frame_id = \"/map\"", 1);
        assert_ne!(text, ROBOT);
        let e = RobotConfig::from_str(&text, "robot.toml", Path::new("/tmp"));
        let msg = format!("{:#}", e.unwrap_err());
        assert!(msg.contains("robot.toml: key 'ros2.frame_id'"), "{msg}");
        let e = RobotConfig::from_str("[ros2]\nodom = \"x\"\n", "robot.toml", Path::new("/tmp"));
        assert!(format!("{:#}", e.unwrap_err()).contains("ros2"));
    }

    /// `sources.imu = "ros2:/TOPIC"`: a ROS topic name, IMU only; the
    /// error names the file and the key.
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
        assert_eq!(c.sources.imu, "ros2:/imu/data");
        with("ros2:imu", "sim").unwrap();
        for bad in ["ros2:/imu//data", "ros2:", "ros2:/9imu", "ros2:/imu/"] {
            let msg = format!("{:#}", with(bad, "sim").unwrap_err());
            assert!(msg.contains("robot.toml: key 'sources.imu'"), "{msg}");
        }
        let msg = format!("{:#}", with("sim", "ros2:/uwb").unwrap_err());
        assert!(
            msg.contains("robot.toml: key 'sources.uwb'") && msg.contains("IMU only"),
            "{msg}"
        );
        let msg = format!("{:#}", with("ros:/imu", "sim").unwrap_err());
        assert!(msg.contains("ros2:/TOPIC"), "{msg}");
    }
}
