//! The scenario: everything the simulator needs (duration, rates, trajectory,
//! IMU errors, UWB kind (TDOA or TWR), anchors, noise, NLOS outliers,
//! dropouts, the optional wheel odometry and optical flow, initial INS
//! errors), its TOML form, and its validation.
//!
//! A scenario file keeps the simulator's part in a `[sim]` table; other
//! top-level tables (a filter preset, evaluation settings) belong to other
//! crates and are ignored by [`Scenario::from_toml_str`]. Every table inside
//! `[sim]` refuses unknown keys.

use serde::de::{self, SeqAccess, Visitor};
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use thiserror::Error;

use crate::trajectory::{Trajectory, TrajectoryModel};

/// Most samples a stream may hold (bounds memory: about 0.5 GB of IMU samples).
pub const MAX_SAMPLES: u64 = 5_000_000;

/// Highest accepted sensor rate, Hz (keeps nanosecond timestamps distinct).
pub const MAX_RATE_HZ: f64 = 100_000.0;

/// Most anchors a scenario may have.
pub const MAX_ANCHORS: usize = 64;

/// Most outlier bursts or dropouts a scenario may list.
pub const MAX_INTERVALS: usize = 10_000;

/// Most random NLOS events expected over a run (`rate * duration * anchors`).
pub const MAX_RANDOM_NLOS_EVENTS: f64 = 100_000.0;

/// Key prefix of every scenario key (the `[sim]` table).
const P: &str = "sim";

/// A simulation scenario (the `[sim]` table of a scenario file).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Scenario {
    /// Short name (default "default").
    pub name: String,
    /// What the scenario reproduces and where its numbers come from (default empty).
    pub description: String,
    /// Length of the run, s (default 15 s, paper section 3.4). Samples are taken
    /// at `k / rate` for `k / rate < duration_s`.
    pub duration_s: f64,
    /// IMU sample rate, Hz (default 100 Hz: paper sections 3.4 and 4.2).
    pub imu_rate_hz: f64,
    /// UWB epoch rate, Hz (default 10 Hz: the LINK UWB system of paper section 4.1).
    pub uwb_rate_hz: f64,
    /// Seed used when the caller gives none (default 1).
    pub seed: u64,
    /// Height of the tag and IMU above the floor (z), m (default 0; the robot moves in 2-D).
    pub height_m: f64,
    /// Gravity magnitude, m/s^2; also the value of one "g" in the IMU error
    /// settings (default 9.81, the project's convention).
    pub gravity_mps2: f64,
    /// The robot's path (default: static at the origin).
    pub trajectory: Trajectory,
    /// IMU error model (default: paper section 3.4 values).
    pub imu: ImuErrors,
    /// UWB system, TDOA or two-way ranging (default: TDOA with the paper's
    /// section 3.4 anchors, 0.05 m noise).
    pub uwb: UwbConfig,
    /// Initial INS errors (default: 1 m and 1 m/s per axis, paper section 3.4).
    pub initial_error: InitialError,
    /// Wheel odometry (`[sim.odometry]`; default none).
    pub odometry: Option<OdometryConfig>,
    /// Optical flow (`[sim.flow]`; default none).
    pub flow: Option<FlowConfig>,
}

impl Default for Scenario {
    fn default() -> Self {
        Self {
            name: "default".to_owned(),
            description: String::new(),
            duration_s: 15.0,
            imu_rate_hz: 100.0,
            uwb_rate_hz: 10.0,
            seed: 1,
            height_m: 0.0,
            gravity_mps2: 9.81,
            trajectory: Trajectory::default(),
            imu: ImuErrors::default(),
            uwb: UwbConfig::default(),
            initial_error: InitialError::default(),
            odometry: None,
            flow: None,
        }
    }
}

/// IMU errors, the same magnitude on each of the three axes of a sensor.
///
/// Constant biases get a random sign per axis, drawn from the seed. The
/// "random walk" figures of the paper are white-noise densities: the gyro's
/// angle random walk (deg/sqrt(h)) and the accelerometer's velocity random
/// walk ("1e-4 g s^1/2", read as g*sqrt(s) = (m/s^2)*sqrt(s), the unit of a
/// velocity random walk). A sample's noise standard deviation is the density
/// times `sqrt(rate)`. Optional bias random walks (default 0) drift the biases.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ImuErrors {
    /// Gyro constant bias magnitude, deg/h (default 0.5: paper section 3.4).
    pub gyro_bias_deg_per_h: f64,
    /// Gyro angle random walk (white rate noise density), deg/sqrt(h) (default 0.05: paper section 3.4).
    pub gyro_arw_deg_per_sqrt_h: f64,
    /// Gyro bias random walk, (deg/h)/sqrt(s) (default 0: not in the paper).
    pub gyro_bias_walk_deg_per_h_per_sqrt_s: f64,
    /// Accelerometer constant bias magnitude, g (default 1e-3: paper section 3.4).
    pub accel_bias_g: f64,
    /// Accelerometer velocity random walk (white specific-force noise density),
    /// g*sqrt(s) (default 1e-4: the paper's "random walk of 1e-4 g s^1/2").
    pub accel_vrw_g_sqrt_s: f64,
    /// Accelerometer bias random walk, g/sqrt(s) (default 0: not in the paper).
    pub accel_bias_walk_g_per_sqrt_s: f64,
}

impl Default for ImuErrors {
    fn default() -> Self {
        Self {
            gyro_bias_deg_per_h: 0.5,
            gyro_arw_deg_per_sqrt_h: 0.05,
            gyro_bias_walk_deg_per_h_per_sqrt_s: 0.0,
            accel_bias_g: 1e-3,
            accel_vrw_g_sqrt_s: 1e-4,
            accel_bias_walk_g_per_sqrt_s: 0.0,
        }
    }
}

impl ImuErrors {
    /// No errors at all (an ideal IMU).
    #[must_use]
    pub fn none() -> Self {
        Self {
            gyro_bias_deg_per_h: 0.0,
            gyro_arw_deg_per_sqrt_h: 0.0,
            gyro_bias_walk_deg_per_h_per_sqrt_s: 0.0,
            accel_bias_g: 0.0,
            accel_vrw_g_sqrt_s: 0.0,
            accel_bias_walk_g_per_sqrt_s: 0.0,
        }
    }
}

/// Dimension the UWB solution is meant for (sets the minimum anchor count).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub enum Dimension {
    /// Horizontal fix at a known height: at least 3 anchors, not collinear.
    #[default]
    #[serde(rename = "2d")]
    TwoD,
    /// Full 3-D fix: at least 4 anchors, not coplanar.
    #[serde(rename = "3d")]
    ThreeD,
}

/// Which anchor pairs form the TDOA differences of an epoch.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PairMode {
    /// Every other anchor against the reference anchor (`anchor_a` = reference),
    /// as a TDOA system synchronised on a reference anchor measures.
    #[default]
    Reference,
    /// Consecutive anchors in list order: (0,1), (1,2), ...
    Consecutive,
}

pub use insuwb_msg::UwbKind;

/// How the TDOA noise is generated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NoiseModel {
    /// Each anchor's arrival time gets independent noise of `tdoa_sigma_m / sqrt(2)`,
    /// so each difference has `tdoa_sigma_m` and differences sharing an anchor
    /// are correlated (coefficient 0.5), as in a real TDOA system.
    #[default]
    PerAnchor,
    /// Each difference gets independent noise of `tdoa_sigma_m`.
    PerDifference,
}

/// One UWB anchor.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Anchor {
    /// Anchor id (written to `UwbTdoa::anchor_a`/`anchor_b`, `UwbRange::anchor`).
    pub id: u32,
    /// Surveyed position (ENU), m.
    pub pos_m: [f64; 3],
    /// Constant range bias of this anchor (e.g. an uncalibrated antenna
    /// delay), m (default 0).
    #[serde(default)]
    pub range_bias_m: f64,
}

/// A set of anchors: `"all"` or a list of ids.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub enum AnchorSet {
    /// Every anchor.
    #[default]
    All,
    /// The listed anchor ids.
    Ids(Vec<u32>),
}

impl AnchorSet {
    /// Whether the set holds anchor `id`.
    #[must_use]
    pub fn contains(&self, id: u32) -> bool {
        match self {
            Self::All => true,
            Self::Ids(ids) => ids.contains(&id),
        }
    }
}

impl Serialize for AnchorSet {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            Self::All => s.serialize_str("all"),
            Self::Ids(ids) => ids.serialize(s),
        }
    }
}

impl<'de> Deserialize<'de> for AnchorSet {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = AnchorSet;
            fn expecting(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
                f.write_str("\"all\" or a list of anchor ids")
            }
            fn visit_str<E: de::Error>(self, v: &str) -> Result<AnchorSet, E> {
                if v == "all" {
                    Ok(AnchorSet::All)
                } else {
                    Err(E::invalid_value(de::Unexpected::Str(v), &self))
                }
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<AnchorSet, A::Error> {
                let mut ids = Vec::new();
                while let Some(id) = seq.next_element::<u32>()? {
                    if ids.len() >= MAX_ANCHORS {
                        return Err(de::Error::invalid_length(ids.len() + 1, &"at most 64 ids"));
                    }
                    ids.push(id);
                }
                Ok(AnchorSet::Ids(ids))
            }
        }
        d.deserialize_any(V)
    }
}

/// A burst of NLOS outliers: while it lasts, each affected anchor's range gets,
/// at each epoch with probability `probability`, a positive excess path drawn
/// uniformly in `bias_m`. With TDOA every difference involving that anchor is
/// biased (positively when it is `anchor_b`, negatively when it is
/// `anchor_a`); with TWR the anchor's range is lengthened by the excess.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutlierBurst {
    /// Start, s from the beginning of the run.
    pub start_s: f64,
    /// Length, s (epochs with `start_s <= t < start_s + duration_s` are affected).
    pub duration_s: f64,
    /// Anchors whose signal is blocked (default "all").
    #[serde(default)]
    pub anchors: AnchorSet,
    /// Range of the excess path `[min, max]`, m (`min >= 0`: NLOS only lengthens a path).
    pub bias_m: [f64; 2],
    /// Probability that an affected anchor is hit at an epoch of the burst (default 1).
    #[serde(default = "one")]
    pub probability: f64,
}

fn one() -> f64 {
    1.0
}

/// Random NLOS: per anchor, events start as a Poisson process and last an
/// exponentially distributed time; each event adds a constant excess path
/// drawn uniformly in `bias_m` to that anchor's range (a TWR range is
/// lengthened by it, a TDOA difference biased as for [`OutlierBurst`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RandomNlos {
    /// Event rate per anchor, 1/s (default 0.02).
    pub rate_per_s: f64,
    /// Mean event length, s (default 1).
    pub mean_duration_s: f64,
    /// Range of the excess path `[min, max]`, m (default [0.3, 1.0]).
    pub bias_m: [f64; 2],
    /// Anchors that can be blocked (default "all").
    pub anchors: AnchorSet,
    /// No event starts before this time, s (default 0).
    pub start_s: f64,
}

impl Default for RandomNlos {
    fn default() -> Self {
        Self {
            rate_per_s: 0.02,
            mean_duration_s: 1.0,
            bias_m: [0.3, 1.0],
            anchors: AnchorSet::All,
            start_s: 0.0,
        }
    }
}

/// An interval without samples of a sensor: UWB epochs (`[[sim.uwb.dropouts]]`),
/// odometry or flow samples (`[[sim.odometry.dropouts]]`, `[[sim.flow.dropouts]]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Dropout {
    /// Start, s.
    pub start_s: f64,
    /// Length, s (samples with `start_s <= t < start_s + duration_s` are dropped).
    pub duration_s: f64,
}

/// The UWB system: TDOA (the default) or two-way ranging.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct UwbConfig {
    /// What is measured: "tdoa" or "twr" (default "tdoa").
    pub kind: UwbKind,
    /// Fix dimension: "2d" or "3d" (default "2d": the paper's model is planar).
    pub dimension: Dimension,
    /// Anchors (default: (-5,-5), (5,-5), (-5,5), (5,5) at z = 0, ids 0..3:
    /// paper section 3.4 with erratum 16).
    pub anchors: Vec<Anchor>,
    /// Pairing of the differences (default "reference").
    pub pairs: PairMode,
    /// Reference anchor id for `pairs = "reference"` (default: the first anchor).
    pub reference_id: Option<u32>,
    /// Standard deviation of each TDOA difference, m (default 0.05: chosen).
    pub tdoa_sigma_m: f64,
    /// Noise generation of the TDOA differences (default "per_anchor").
    pub noise_model: NoiseModel,
    /// Standard deviation of each TWR range, m: independent white noise
    /// per range (default 0.05: chosen, the order of a DW1000 range's
    /// line-of-sight noise).
    pub range_sigma_m: f64,
    /// Scheduled NLOS outlier bursts (default none).
    pub outliers: Vec<OutlierBurst>,
    /// Random NLOS events (default none).
    pub random_nlos: Option<RandomNlos>,
    /// Intervals without UWB (default none).
    pub dropouts: Vec<Dropout>,
}

impl Default for UwbConfig {
    fn default() -> Self {
        let a = |id: u32, x: f64, y: f64| Anchor {
            id,
            pos_m: [x, y, 0.0],
            range_bias_m: 0.0,
        };
        Self {
            kind: UwbKind::Tdoa,
            dimension: Dimension::TwoD,
            anchors: vec![
                a(0, -5.0, -5.0),
                a(1, 5.0, -5.0),
                a(2, -5.0, 5.0),
                a(3, 5.0, 5.0),
            ],
            pairs: PairMode::Reference,
            reference_id: None,
            tdoa_sigma_m: 0.05,
            noise_model: NoiseModel::PerAnchor,
            range_sigma_m: 0.05,
            outliers: Vec::new(),
            random_nlos: None,
            dropouts: Vec::new(),
        }
    }
}

impl UwbConfig {
    /// The anchor index pairs `(a, b)` of every epoch, in emission order
    /// (`diff = |p - b| - |p - a|`). Empty if the reference id is unknown.
    #[must_use]
    pub fn pair_indices(&self) -> Vec<(usize, usize)> {
        let n = self.anchors.len();
        match self.pairs {
            PairMode::Consecutive => (1..n).map(|i| (i - 1, i)).collect(),
            PairMode::Reference => {
                let r = match self.reference_id {
                    Some(id) => match self.anchors.iter().position(|a| a.id == id) {
                        Some(r) => r,
                        None => return Vec::new(),
                    },
                    None => 0,
                };
                (0..n).filter(|&i| i != r).map(|i| (r, i)).collect()
            }
        }
    }
}

/// Initial INS errors (standard deviations per horizontal axis). The caller
/// uses them as P_0 and to perturb the INS start; see `Scenario::initial_ins_state`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct InitialError {
    /// Position error per axis, m (default 1: paper section 3.4).
    pub pos_m: f64,
    /// Velocity error per axis, m/s (default 1: paper section 3.4).
    pub vel_mps: f64,
    /// Heading error, rad (default 0: the paper gives none).
    pub yaw_rad: f64,
}

impl Default for InitialError {
    fn default() -> Self {
        Self {
            pos_m: 1.0,
            vel_mps: 1.0,
            yaw_rad: 0.0,
        }
    }
}

/// Wheel odometry of a wheeled base (`[sim.odometry]`): the body-frame
/// forward velocity (x) as the wheels read it, `scale * v_x + noise`, and
/// the lateral velocity (y) reported as zero, the non-holonomic constraint
/// of a wheeled base, with the wheels' slip as white noise of
/// `lateral_sigma_mps` about it (the simulated robot has no lateral
/// velocity: its body x axis follows the path). The vertical axis is not
/// measured. Samples are taken at `offset_s + k / rate_hz` for times
/// before `duration_s` and outside the dropouts, each stating the standard
/// deviations it was drawn with ([`insuwb_msg::BodyVelocity::sigma_mps`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OdometryConfig {
    /// Sample rate, Hz (default 50).
    pub rate_hz: f64,
    /// Time of the first sample, s (default 0).
    pub offset_s: f64,
    /// Scale factor of the forward velocity, measured / true: a wheel
    /// radius off by 5 % reads 1.05 (default 1).
    pub scale: f64,
    /// White noise of the forward velocity, m/s; > 0 (default 0.02).
    pub sigma_mps: f64,
    /// White noise (the slip) of the lateral velocity about its reported
    /// zero, m/s; 0 leaves the lateral axis out (default 0.05).
    pub lateral_sigma_mps: f64,
    /// Intervals without odometry (default none).
    pub dropouts: Vec<Dropout>,
}

impl Default for OdometryConfig {
    fn default() -> Self {
        Self {
            rate_hz: 50.0,
            offset_s: 0.0,
            scale: 1.0,
            sigma_mps: 0.02,
            lateral_sigma_mps: 0.05,
            dropouts: Vec::new(),
        }
    }
}

/// Optical flow with a range finder (`[sim.flow]`): the body-frame x and y
/// velocity, `scale * v + noise` on each, the vertical axis not measured,
/// and, with `range_sigma_m` above 0, the range finder's distance to the
/// floor (the height: the simulated body does not tilt) plus its noise in
/// each sample's `range_mm` and as a height sample of its own
/// (`SimOutput::height`).
/// Samples are taken at `offset_s + k / rate_hz` for times before
/// `duration_s` and outside the dropouts.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FlowConfig {
    /// Sample rate, Hz (default 50).
    pub rate_hz: f64,
    /// Time of the first sample, s (default 0).
    pub offset_s: f64,
    /// Scale factor of the x and y velocity, measured / true (default 1).
    pub scale: f64,
    /// White noise of each axis, m/s; > 0 (default 0.05).
    pub sigma_mps: f64,
    /// White noise of the range, m; 0 (default): no range, no heights.
    pub range_sigma_m: f64,
    /// Intervals without flow (default none).
    pub dropouts: Vec<Dropout>,
}

impl Default for FlowConfig {
    fn default() -> Self {
        Self {
            rate_hz: 50.0,
            offset_s: 0.0,
            scale: 1.0,
            sigma_mps: 0.05,
            range_sigma_m: 0.0,
            dropouts: Vec::new(),
        }
    }
}

/// The sample times of a body-velocity sensor, ns: `offset + k / rate`
/// (rounded to the nanosecond) for `k / rate < duration - offset`.
pub(crate) fn velocity_times(
    duration_s: f64,
    rate_hz: f64,
    offset_s: f64,
) -> impl Iterator<Item = u64> {
    let n = sample_count(duration_s - offset_s, rate_hz);
    let offset_ns = (offset_s * 1e9).round().max(0.0) as u64;
    (0..n).map(move |k| offset_ns + (k as f64 * 1e9 / rate_hz).round() as u64)
}

/// A scenario value that is not acceptable; each variant names the key.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ScenarioConfigError {
    /// A number is NaN or infinite.
    #[error("{key} must be finite, got {value}")]
    NotFinite {
        /// Key path, e.g. `sim.duration_s`.
        key: String,
        /// Offending value.
        value: f64,
    },
    /// A number is outside its range.
    #[error("{key} must be {requirement}, got {value}")]
    OutOfRange {
        /// Key path.
        key: String,
        /// The rule, e.g. `> 0`.
        requirement: &'static str,
        /// Offending value.
        value: f64,
    },
    /// Not enough anchors for the dimension.
    #[error("{key} needs at least {need} anchors for a {dimension} fix, got {got}")]
    TooFewAnchors {
        /// Key path (`sim.uwb.anchors`).
        key: String,
        /// "2d" or "3d".
        dimension: &'static str,
        /// Minimum.
        need: usize,
        /// Given.
        got: usize,
    },
    /// A list is too long.
    #[error("{key} may hold at most {max} entries, got {got}")]
    TooMany {
        /// Key path.
        key: String,
        /// Maximum.
        max: usize,
        /// Given.
        got: usize,
    },
    /// Two anchors share an id.
    #[error("{key}: anchor id {id} is used twice")]
    DuplicateAnchorId {
        /// Key path.
        key: String,
        /// The id.
        id: u32,
    },
    /// A referenced anchor id does not exist.
    #[error("{key}: no anchor has id {id}")]
    UnknownAnchor {
        /// Key path.
        key: String,
        /// The id.
        id: u32,
    },
    /// The anchor geometry cannot give a fix.
    #[error("{key}: {reason}")]
    DegenerateAnchors {
        /// Key path.
        key: String,
        /// Why.
        reason: &'static str,
    },
    /// A stream would be too long.
    #[error("{key}: duration_s * rate gives {samples} samples, more than {max}")]
    TooManySamples {
        /// Key path of the rate.
        key: String,
        /// Samples asked for.
        samples: f64,
        /// Maximum ([`MAX_SAMPLES`]).
        max: u64,
    },
    /// The trajectory cannot be built.
    #[error("{key}: {reason}")]
    Trajectory {
        /// Key path.
        key: String,
        /// Why.
        reason: String,
    },
    /// Two velocity sensors would measure at the same time: the fusion's
    /// velocity input takes one sample per time.
    #[error("{key}: a flow sample at {time_s} s has the time of an odometry sample; give the sensors different offset_s or rates")]
    VelocityTimeShared {
        /// Key path (`sim.flow.offset_s`).
        key: String,
        /// The first shared time, s.
        time_s: f64,
    },
}

/// Why a scenario file could not be loaded.
#[derive(Debug, Error)]
pub enum ScenarioError {
    /// The TOML is malformed or a key/value does not fit the schema.
    #[error("{origin}: at `{path}`: {message}")]
    Parse {
        /// File name or other origin of the text.
        origin: String,
        /// Key path where it failed (`.` for the document root).
        path: String,
        /// The parser's message.
        message: String,
    },
    /// The values parse but are not acceptable.
    #[error("{origin}: {error}")]
    Invalid {
        /// File name or other origin of the text.
        origin: String,
        /// What is wrong.
        #[source]
        error: ScenarioConfigError,
    },
    /// The file could not be read.
    #[error("{origin}: cannot read: {error}")]
    Io {
        /// The path.
        origin: String,
        /// The I/O error.
        #[source]
        error: std::io::Error,
    },
    /// No built-in scenario has this name.
    #[error("no built-in scenario named {name:?} (known: {known})")]
    UnknownBuiltin {
        /// The name asked for.
        name: String,
        /// The known names, comma-separated.
        known: String,
    },
}

/// The document shape read by [`Scenario::from_toml_str`]: only `[sim]` matters.
#[derive(Deserialize)]
struct SimDocument {
    sim: Scenario,
}

impl Scenario {
    /// Parses the `[sim]` table of a scenario file and validates it. Other
    /// top-level tables are ignored. Errors name `origin` and the key path.
    pub fn from_toml_str(text: &str, origin: &str) -> Result<Self, ScenarioError> {
        let parse_err = |path: String, message: String| ScenarioError::Parse {
            origin: origin.to_owned(),
            path,
            message,
        };
        let de = toml::Deserializer::parse(text)
            .map_err(|e| parse_err(".".to_owned(), e.to_string().trim_end().to_owned()))?;
        let doc: SimDocument = serde_path_to_error::deserialize(de).map_err(|e| {
            let path = e.path().to_string();
            let inner = e.into_inner();
            let line = inner
                .span()
                .and_then(|sp| text.get(..sp.start))
                .map(|before| before.matches('\n').count() + 1);
            let message = match line {
                Some(l) => format!("{} (line {l})", inner.message()),
                None => inner.message().to_owned(),
            };
            parse_err(path, message)
        })?;
        doc.sim
            .validate()
            .map_err(|source| ScenarioError::Invalid {
                origin: origin.to_owned(),
                error: source,
            })?;
        Ok(doc.sim)
    }

    /// Reads and parses a scenario file.
    pub fn from_toml_path(path: &std::path::Path) -> Result<Self, ScenarioError> {
        let origin = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| ScenarioError::Io {
            origin: origin.clone(),
            error: source,
        })?;
        Self::from_toml_str(&text, &origin)
    }

    /// Parses a built-in scenario (see [`crate::builtin_names`]).
    pub fn builtin(name: &str) -> Result<Self, ScenarioError> {
        let text = crate::builtin(name).ok_or_else(|| ScenarioError::UnknownBuiltin {
            name: name.to_owned(),
            known: crate::builtin_names().join(", "),
        })?;
        Self::from_toml_str(text, &format!("builtin:{name}"))
    }

    /// Number of IMU samples (and truth samples) the scenario produces.
    #[must_use]
    pub fn imu_sample_count(&self) -> u64 {
        sample_count(self.duration_s, self.imu_rate_hz)
    }

    /// Number of UWB epochs before dropouts.
    #[must_use]
    pub fn uwb_epoch_count(&self) -> u64 {
        sample_count(self.duration_s, self.uwb_rate_hz)
    }

    /// Checks every value; the error names the first offending key.
    pub fn validate(&self) -> Result<(), ScenarioConfigError> {
        positive(&format!("{P}.duration_s"), self.duration_s)?;
        for (key, rate) in [
            ("imu_rate_hz", self.imu_rate_hz),
            ("uwb_rate_hz", self.uwb_rate_hz),
        ] {
            let key = format!("{P}.{key}");
            positive(&key, rate)?;
            if rate > MAX_RATE_HZ {
                return Err(out_of_range(&key, "<= 100000", rate));
            }
            let samples = self.duration_s * rate;
            if samples > MAX_SAMPLES as f64 {
                return Err(ScenarioConfigError::TooManySamples {
                    key,
                    samples,
                    max: MAX_SAMPLES,
                });
            }
        }
        finite(&format!("{P}.height_m"), self.height_m)?;
        positive(&format!("{P}.gravity_mps2"), self.gravity_mps2)?;
        self.validate_trajectory()?;
        self.validate_imu()?;
        self.validate_uwb()?;
        let ie = &self.initial_error;
        non_negative(&format!("{P}.initial_error.pos_m"), ie.pos_m)?;
        non_negative(&format!("{P}.initial_error.vel_mps"), ie.vel_mps)?;
        non_negative(&format!("{P}.initial_error.yaw_rad"), ie.yaw_rad)?;
        self.validate_velocity()?;
        Ok(())
    }

    /// Number of odometry and flow samples before dropouts (0 for a sensor
    /// that is not configured).
    #[must_use]
    pub fn velocity_sample_counts(&self) -> [u64; 2] {
        let n = |rate: f64, offset: f64| sample_count(self.duration_s - offset, rate);
        [
            self.odometry
                .as_ref()
                .map_or(0, |o| n(o.rate_hz, o.offset_s)),
            self.flow.as_ref().map_or(0, |f| n(f.rate_hz, f.offset_s)),
        ]
    }

    fn validate_velocity(&self) -> Result<(), ScenarioConfigError> {
        let sensor = |name: &str,
                      rate: f64,
                      offset: f64,
                      scale: f64,
                      sigma: f64,
                      dropouts: &[Dropout]|
         -> Result<(), ScenarioConfigError> {
            let key = |f: &str| format!("{P}.{name}.{f}");
            positive(&key("rate_hz"), rate)?;
            if rate > MAX_RATE_HZ {
                return Err(out_of_range(&key("rate_hz"), "<= 100000", rate));
            }
            let samples = self.duration_s * rate;
            if samples > MAX_SAMPLES as f64 {
                return Err(ScenarioConfigError::TooManySamples {
                    key: key("rate_hz"),
                    samples,
                    max: MAX_SAMPLES,
                });
            }
            non_negative(&key("offset_s"), offset)?;
            positive(&key("scale"), scale)?;
            if scale > 10.0 {
                return Err(out_of_range(&key("scale"), "<= 10", scale));
            }
            positive(&key("sigma_mps"), sigma)?;
            validate_dropouts(&key("dropouts"), dropouts)
        };
        if let Some(o) = &self.odometry {
            sensor(
                "odometry",
                o.rate_hz,
                o.offset_s,
                o.scale,
                o.sigma_mps,
                &o.dropouts,
            )?;
            non_negative(
                &format!("{P}.odometry.lateral_sigma_mps"),
                o.lateral_sigma_mps,
            )?;
        }
        if let Some(f) = &self.flow {
            sensor(
                "flow",
                f.rate_hz,
                f.offset_s,
                f.scale,
                f.sigma_mps,
                &f.dropouts,
            )?;
            non_negative(&format!("{P}.flow.range_sigma_m"), f.range_sigma_m)?;
        }
        if let (Some(o), Some(f)) = (&self.odometry, &self.flow) {
            // Both sorted: walk them together for a common time.
            let mut odo = velocity_times(self.duration_s, o.rate_hz, o.offset_s).peekable();
            for t in velocity_times(self.duration_s, f.rate_hz, f.offset_s) {
                while odo.next_if(|&u| u < t).is_some() {}
                if odo.peek() == Some(&t) {
                    return Err(ScenarioConfigError::VelocityTimeShared {
                        key: format!("{P}.flow.offset_s"),
                        time_s: t as f64 * 1e-9,
                    });
                }
            }
        }
        Ok(())
    }

    fn validate_trajectory(&self) -> Result<(), ScenarioConfigError> {
        let k = |kind: &str, field: &str| format!("{P}.trajectory.{kind}.{field}");
        match &self.trajectory {
            Trajectory::Static(s) => {
                finite_all(&k("static", "pos_m"), &s.pos_m)?;
                finite(&k("static", "yaw_rad"), s.yaw_rad)?;
            }
            Trajectory::Waypoints(w) => {
                if w.points.len() > crate::trajectory::MAX_WAYPOINTS {
                    return Err(ScenarioConfigError::TooMany {
                        key: k("waypoints", "points"),
                        max: crate::trajectory::MAX_WAYPOINTS,
                        got: w.points.len(),
                    });
                }
                for (i, p) in w.points.iter().enumerate() {
                    finite_all(&format!("{}[{i}]", k("waypoints", "points")), p)?;
                }
                positive(&k("waypoints", "speed_mps"), w.speed_mps)?;
                if let Some(y) = w.start_yaw_rad {
                    finite(&k("waypoints", "start_yaw_rad"), y)?;
                }
                positive(&k("waypoints", "ramp_s"), w.ramp_s)?;
                non_negative(&k("waypoints", "hold_start_s"), w.hold_start_s)?;
            }
            Trajectory::Circle(c) => {
                finite_all(&k("circle", "centre_m"), &c.centre_m)?;
                positive(&k("circle", "radius_m"), c.radius_m)?;
                positive(&k("circle", "speed_mps"), c.speed_mps)?;
                finite(&k("circle", "start_angle_rad"), c.start_angle_rad)?;
            }
            Trajectory::Lissajous(l) => {
                finite_all(&k("lissajous", "centre_m"), &l.centre_m)?;
                for (i, a) in l.amplitude_m.iter().enumerate() {
                    non_negative(&format!("{}[{i}]", k("lissajous", "amplitude_m")), *a)?;
                }
                for (i, t) in l.period_s.iter().enumerate() {
                    positive(&format!("{}[{i}]", k("lissajous", "period_s")), *t)?;
                }
                finite_all(&k("lissajous", "phase_rad"), &l.phase_rad)?;
            }
            Trajectory::Figure8(f) => {
                finite_all(&k("figure8", "centre_m"), &f.centre_m)?;
                for (i, a) in f.half_size_m.iter().enumerate() {
                    positive(&format!("{}[{i}]", k("figure8", "half_size_m")), *a)?;
                }
                positive(&k("figure8", "period_s"), f.period_s)?;
            }
        }
        TrajectoryModel::new(&self.trajectory, self.height_m).map_err(|e| {
            ScenarioConfigError::Trajectory {
                key: format!("{P}.trajectory"),
                reason: e.to_string(),
            }
        })?;
        Ok(())
    }

    fn validate_imu(&self) -> Result<(), ScenarioConfigError> {
        let i = &self.imu;
        for (key, v) in [
            ("gyro_bias_deg_per_h", i.gyro_bias_deg_per_h),
            ("gyro_arw_deg_per_sqrt_h", i.gyro_arw_deg_per_sqrt_h),
            (
                "gyro_bias_walk_deg_per_h_per_sqrt_s",
                i.gyro_bias_walk_deg_per_h_per_sqrt_s,
            ),
            ("accel_bias_g", i.accel_bias_g),
            ("accel_vrw_g_sqrt_s", i.accel_vrw_g_sqrt_s),
            (
                "accel_bias_walk_g_per_sqrt_s",
                i.accel_bias_walk_g_per_sqrt_s,
            ),
        ] {
            non_negative(&format!("{P}.imu.{key}"), v)?;
        }
        Ok(())
    }

    fn validate_uwb(&self) -> Result<(), ScenarioConfigError> {
        let u = &self.uwb;
        let akey = format!("{P}.uwb.anchors");
        if u.anchors.len() > MAX_ANCHORS {
            return Err(ScenarioConfigError::TooMany {
                key: akey,
                max: MAX_ANCHORS,
                got: u.anchors.len(),
            });
        }
        for (i, a) in u.anchors.iter().enumerate() {
            finite_all(&format!("{akey}[{i}].pos_m"), &a.pos_m)?;
            finite(&format!("{akey}[{i}].range_bias_m"), a.range_bias_m)?;
            if u.anchors.iter().take(i).any(|b| b.id == a.id) {
                return Err(ScenarioConfigError::DuplicateAnchorId {
                    key: format!("{akey}[{i}].id"),
                    id: a.id,
                });
            }
        }
        let (dimension, need) = match u.dimension {
            Dimension::TwoD => ("2d", 3),
            Dimension::ThreeD => ("3d", 4),
        };
        if u.anchors.len() < need {
            return Err(ScenarioConfigError::TooFewAnchors {
                key: akey,
                dimension,
                need,
                got: u.anchors.len(),
            });
        }
        check_geometry(&akey, &u.anchors, u.dimension)?;
        if let Some(id) = u.reference_id {
            if !u.anchors.iter().any(|a| a.id == id) {
                return Err(ScenarioConfigError::UnknownAnchor {
                    key: format!("{P}.uwb.reference_id"),
                    id,
                });
            }
        }
        non_negative(&format!("{P}.uwb.tdoa_sigma_m"), u.tdoa_sigma_m)?;
        non_negative(&format!("{P}.uwb.range_sigma_m"), u.range_sigma_m)?;
        if u.outliers.len() > MAX_INTERVALS {
            return Err(ScenarioConfigError::TooMany {
                key: format!("{P}.uwb.outliers"),
                max: MAX_INTERVALS,
                got: u.outliers.len(),
            });
        }
        for (i, o) in u.outliers.iter().enumerate() {
            let k = |f: &str| format!("{P}.uwb.outliers[{i}].{f}");
            non_negative(&k("start_s"), o.start_s)?;
            positive(&k("duration_s"), o.duration_s)?;
            check_bias_range(&k("bias_m"), o.bias_m)?;
            finite(&k("probability"), o.probability)?;
            if !(0.0..=1.0).contains(&o.probability) {
                return Err(out_of_range(&k("probability"), "in [0, 1]", o.probability));
            }
            check_anchor_set(&k("anchors"), &o.anchors, &u.anchors)?;
        }
        if let Some(r) = &u.random_nlos {
            let k = |f: &str| format!("{P}.uwb.random_nlos.{f}");
            non_negative(&k("rate_per_s"), r.rate_per_s)?;
            positive(&k("mean_duration_s"), r.mean_duration_s)?;
            check_bias_range(&k("bias_m"), r.bias_m)?;
            non_negative(&k("start_s"), r.start_s)?;
            check_anchor_set(&k("anchors"), &r.anchors, &u.anchors)?;
            let expected = r.rate_per_s * self.duration_s * u.anchors.len() as f64;
            if expected > MAX_RANDOM_NLOS_EVENTS {
                return Err(out_of_range(
                    &k("rate_per_s"),
                    "such that rate * duration * anchors <= 100000",
                    r.rate_per_s,
                ));
            }
        }
        validate_dropouts(&format!("{P}.uwb.dropouts"), &u.dropouts)
    }
}

/// Each dropout of the list under `key` (at most [`MAX_INTERVALS`]).
fn validate_dropouts(key: &str, dropouts: &[Dropout]) -> Result<(), ScenarioConfigError> {
    if dropouts.len() > MAX_INTERVALS {
        return Err(ScenarioConfigError::TooMany {
            key: key.to_owned(),
            max: MAX_INTERVALS,
            got: dropouts.len(),
        });
    }
    for (i, d) in dropouts.iter().enumerate() {
        non_negative(&format!("{key}[{i}].start_s"), d.start_s)?;
        positive(&format!("{key}[{i}].duration_s"), d.duration_s)?;
    }
    Ok(())
}

/// Samples at `k / rate` for `k / rate < duration` (a tiny tolerance keeps
/// `15 s * 100 Hz` at exactly 1500 despite rounding).
pub(crate) fn sample_count(duration_s: f64, rate_hz: f64) -> u64 {
    let x = duration_s * rate_hz;
    if !x.is_finite() || x <= 0.0 {
        return 0;
    }
    let n = (x - 1e-9).ceil();
    n.clamp(0.0, MAX_SAMPLES as f64) as u64
}

fn finite(key: &str, v: f64) -> Result<(), ScenarioConfigError> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(ScenarioConfigError::NotFinite {
            key: key.to_owned(),
            value: v,
        })
    }
}

fn finite_all(key: &str, v: &[f64]) -> Result<(), ScenarioConfigError> {
    for (i, x) in v.iter().enumerate() {
        finite(&format!("{key}[{i}]"), *x)?;
    }
    Ok(())
}

fn out_of_range(key: &str, requirement: &'static str, value: f64) -> ScenarioConfigError {
    ScenarioConfigError::OutOfRange {
        key: key.to_owned(),
        requirement,
        value,
    }
}

fn positive(key: &str, v: f64) -> Result<(), ScenarioConfigError> {
    finite(key, v)?;
    if v > 0.0 {
        Ok(())
    } else {
        Err(out_of_range(key, "> 0", v))
    }
}

fn non_negative(key: &str, v: f64) -> Result<(), ScenarioConfigError> {
    finite(key, v)?;
    if v >= 0.0 {
        Ok(())
    } else {
        Err(out_of_range(key, ">= 0", v))
    }
}

fn check_bias_range(key: &str, b: [f64; 2]) -> Result<(), ScenarioConfigError> {
    non_negative(&format!("{key}[0]"), b[0])?;
    finite(&format!("{key}[1]"), b[1])?;
    if b[1] < b[0] {
        return Err(out_of_range(&format!("{key}[1]"), ">= bias_m[0]", b[1]));
    }
    Ok(())
}

fn check_anchor_set(
    key: &str,
    set: &AnchorSet,
    anchors: &[Anchor],
) -> Result<(), ScenarioConfigError> {
    if let AnchorSet::Ids(ids) = set {
        for id in ids {
            if !anchors.iter().any(|a| a.id == *id) {
                return Err(ScenarioConfigError::UnknownAnchor {
                    key: key.to_owned(),
                    id: *id,
                });
            }
        }
    }
    Ok(())
}

/// 2-D: some three anchors span a triangle of area > 1e-3 m^2 (not collinear).
/// 3-D: some four anchors span a tetrahedron of volume > 1e-3 m^3 (not coplanar).
fn check_geometry(
    key: &str,
    anchors: &[Anchor],
    dim: Dimension,
) -> Result<(), ScenarioConfigError> {
    let p: Vec<[f64; 3]> = anchors.iter().map(|a| a.pos_m).collect();
    let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let cross = |a: [f64; 3], b: [f64; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    let n = p.len();
    let mut ok = false;
    'search: for i in 0..n {
        for j in i + 1..n {
            for k in j + 1..n {
                let u = sub(p[j], p[i]);
                let v = sub(p[k], p[i]);
                match dim {
                    Dimension::TwoD => {
                        if (0.5 * (u[0] * v[1] - u[1] * v[0])).abs() > 1e-3 {
                            ok = true;
                            break 'search;
                        }
                    }
                    Dimension::ThreeD => {
                        let c = cross(u, v);
                        for q in p.iter().skip(k + 1) {
                            let w = sub(*q, p[i]);
                            let vol = (c[0] * w[0] + c[1] * w[1] + c[2] * w[2]).abs() / 6.0;
                            if vol > 1e-3 {
                                ok = true;
                                break 'search;
                            }
                        }
                    }
                }
            }
        }
    }
    if ok {
        Ok(())
    } else {
        Err(ScenarioConfigError::DegenerateAnchors {
            key: key.to_owned(),
            reason: match dim {
                Dimension::TwoD => "the anchors are collinear in the horizontal plane",
                Dimension::ThreeD => "the anchors are coplanar",
            },
        })
    }
}
