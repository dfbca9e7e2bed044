//! The simulation run: samples the trajectory into ground truth and ideal
//! IMU readings, adds the IMU errors, measures UWB TDOA differences or
//! two-way ranges with noise, anchor biases, NLOS excess paths and
//! dropouts, and, when the scenario has them, body velocities from wheel
//! odometry and optical flow.
//!
//! Every random quantity draws from its own stream of the seed
//! ([`crate::rng::stream`]); the output is a pure function of the
//! scenario and the seed.

use insuwb_msg::{BodyVelocity, GroundTruth, Header, Height, ImuSample, UwbRange, UwbTdoa};
use thiserror::Error;

use crate::rng::{self, Noise};
use crate::scenario::{
    sample_count, velocity_times, Dropout, NoiseModel, Scenario, ScenarioConfigError, UwbKind,
};
use crate::trajectory::{TrajectoryError, TrajectoryModel};

/// Random stream of the IMU bias signs.
const STREAM_IMU_BIAS: u64 = 1;
/// Random stream of the IMU white noise and bias walks.
const STREAM_IMU_NOISE: u64 = 2;
/// Random stream of the UWB noise (TDOA or TWR: a run has one of them).
const STREAM_UWB_NOISE: u64 = 3;
/// Random stream of the scheduled outlier bursts.
const STREAM_OUTLIERS: u64 = 4;
/// Random stream of the random NLOS events.
const STREAM_RANDOM_NLOS: u64 = 5;
/// Random stream of the initial INS errors.
const STREAM_INITIAL: u64 = 6;
/// Random stream of the wheel odometry's noise.
const STREAM_ODOMETRY: u64 = 7;
/// Random stream of the optical flow's noise.
const STREAM_FLOW: u64 = 8;

/// Degrees to radians.
const DEG: f64 = core::f64::consts::PI / 180.0;

/// Why a simulation could not run.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum SimError {
    /// The scenario does not validate.
    #[error("invalid scenario: {0}")]
    Invalid(ScenarioConfigError),
    /// The trajectory cannot be evaluated at some time (e.g. zero speed on a Lissajous curve).
    #[error("trajectory at t = {t_s} s: {error}")]
    Trajectory {
        /// Time of the failure, s.
        t_s: f64,
        /// What failed.
        #[source]
        error: TrajectoryError,
    },
}

impl From<ScenarioConfigError> for SimError {
    fn from(e: ScenarioConfigError) -> Self {
        Self::Invalid(e)
    }
}

/// How each UWB difference was made: `diff_m = geometric_m + anchor_bias_m + nlos_m + noise_m`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TdoaTruth {
    /// Error-free range difference `|p - b| - |p - a|`, m.
    pub geometric_m: f64,
    /// Contribution of the anchors' constant range biases (`bias_b - bias_a`), m.
    pub anchor_bias_m: f64,
    /// Contribution of NLOS excess paths (`excess_b - excess_a`), m.
    pub nlos_m: f64,
    /// Contribution of the noise, m.
    pub noise_m: f64,
}

/// How each UWB two-way range was made:
/// `range_m = geometric_m + anchor_bias_m + nlos_m + noise_m`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RangeTruth {
    /// Error-free distance `|p - anchor|`, m.
    pub geometric_m: f64,
    /// The anchor's constant range bias (`range_bias_m`), m.
    pub anchor_bias_m: f64,
    /// NLOS excess path, m (`>= 0`: NLOS only lengthens a range).
    pub nlos_m: f64,
    /// Contribution of the noise, m.
    pub noise_m: f64,
}

/// The IMU error values drawn for a run (the turn-on biases, before any bias walk).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ImuErrorRealisation {
    /// Gyro bias per body axis, rad/s.
    pub gyro_bias_rps: [f64; 3],
    /// Accelerometer bias per body axis, m/s^2.
    pub accel_bias_mps2: [f64; 3],
}

/// Everything a run produces. Each stream is sorted by time with `seq`
/// counting from 0.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SimOutput {
    /// IMU samples (specific force and body rate with errors).
    pub imu: Vec<ImuSample>,
    /// TDOA differences; those of one epoch share `meas_time_ns`, the last
    /// one carries [`UwbTdoa::FLAG_EPOCH_END`]. Empty when the scenario's
    /// UWB is two-way ranging.
    pub tdoa: Vec<UwbTdoa>,
    /// Ground truth at the IMU times (`FLAG_VEL_VALID` set).
    pub truth: Vec<GroundTruth>,
    /// Decomposition of each entry of `tdoa` (same index).
    pub tdoa_truth: Vec<TdoaTruth>,
    /// Two-way ranges (`[sim.uwb] kind = "twr"`): per epoch one range per
    /// anchor, in anchor order, sharing `meas_time_ns`, the last one
    /// carrying [`UwbRange::FLAG_EPOCH_END`]; no quality
    /// ([`UwbRange::FLAG_QUALITY`] clear). Empty for a TDOA scenario.
    pub range: Vec<UwbRange>,
    /// Decomposition of each entry of `range` (same index).
    pub range_truth: Vec<RangeTruth>,
    /// Body-frame velocities of the wheel odometry
    /// ([`BodyVelocity::SOURCE_ODOMETRY`]) and the optical flow
    /// ([`BodyVelocity::SOURCE_FLOW`]) when the scenario has them, merged
    /// by time (no two at one time: the scenario's validation sees to
    /// it), `seq` counting from 0 over the merged stream. Empty without
    /// `[sim.odometry]` and `[sim.flow]`.
    pub velocity: Vec<BodyVelocity>,
    /// The flow deck's range finder ([`Height::SOURCE_RANGE_FINDER`]) with
    /// `[sim.flow] range_sigma_m` above 0: one height per flow sample, at
    /// its time, the range its `range_mm` holds. Empty otherwise.
    pub height: Vec<Height>,
    /// The IMU biases drawn for this run.
    pub imu_errors: ImuErrorRealisation,
}

/// One record of the merged stream.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SimRecord {
    /// Ground truth.
    Truth(GroundTruth),
    /// IMU sample.
    Imu(ImuSample),
    /// TDOA difference.
    Tdoa(UwbTdoa),
    /// Two-way range.
    Range(UwbRange),
    /// Body-frame velocity (odometry, flow).
    Velocity(BodyVelocity),
    /// Height (the flow deck's range finder).
    Height(Height),
}

impl SimRecord {
    /// Measurement time, ns.
    #[must_use]
    pub fn time_ns(&self) -> u64 {
        match self {
            Self::Truth(s) => s.header.meas_time_ns,
            Self::Imu(s) => s.header.meas_time_ns,
            Self::Tdoa(s) => s.header.meas_time_ns,
            Self::Range(s) => s.header.meas_time_ns,
            Self::Velocity(s) => s.header.meas_time_ns,
            Self::Height(s) => s.header.meas_time_ns,
        }
    }

    /// Tie-break rank at equal times: truth 0, IMU 1, UWB (TDOA 2, range
    /// 3), velocity 4, height 5.
    fn rank(&self) -> u8 {
        match self {
            Self::Truth(_) => 0,
            Self::Imu(_) => 1,
            Self::Tdoa(_) => 2,
            Self::Range(_) => 3,
            Self::Velocity(_) => 4,
            Self::Height(_) => 5,
        }
    }
}

impl SimOutput {
    /// All samples in one stream ordered by measurement time; at equal times
    /// truth comes first, then IMU, then UWB (TDOA differences, then
    /// ranges), then body velocities, then heights (each stream keeps its
    /// own order).
    #[must_use]
    pub fn merged(&self) -> Vec<SimRecord> {
        let mut out = Vec::with_capacity(
            self.imu.len()
                + self.tdoa.len()
                + self.range.len()
                + self.truth.len()
                + self.velocity.len()
                + self.height.len(),
        );
        let (mut t, mut i, mut u, mut r, mut v, mut h) = (
            self.truth.iter().peekable(),
            self.imu.iter().peekable(),
            self.tdoa.iter().peekable(),
            self.range.iter().peekable(),
            self.velocity.iter().peekable(),
            self.height.iter().peekable(),
        );
        loop {
            let cands = [
                t.peek().map(|s| SimRecord::Truth(**s)),
                i.peek().map(|s| SimRecord::Imu(**s)),
                u.peek().map(|s| SimRecord::Tdoa(**s)),
                r.peek().map(|s| SimRecord::Range(**s)),
                v.peek().map(|s| SimRecord::Velocity(**s)),
                h.peek().map(|s| SimRecord::Height(**s)),
            ];
            let best = cands
                .iter()
                .flatten()
                .min_by_key(|r| (r.time_ns(), r.rank()))
                .copied();
            let Some(rec) = best else { break };
            match rec {
                SimRecord::Truth(_) => {
                    t.next();
                }
                SimRecord::Imu(_) => {
                    i.next();
                }
                SimRecord::Tdoa(_) => {
                    u.next();
                }
                SimRecord::Range(_) => {
                    r.next();
                }
                SimRecord::Velocity(_) => {
                    v.next();
                }
                SimRecord::Height(_) => {
                    h.next();
                }
            }
            out.push(rec);
        }
        out
    }
}

/// The INS start a filter is given: the truth at t = 0 plus errors drawn
/// from the scenario's `initial_error` sigmas.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct InitialState {
    /// Position, ENU, m (z is the true height: the errors are horizontal).
    pub pos_m: [f64; 3],
    /// Velocity, ENU, m/s.
    pub vel_mps: [f64; 3],
    /// Heading, rad.
    pub yaw_rad: f64,
}

impl Scenario {
    /// A perturbed INS initial state: truth at t = 0 plus Gaussian errors
    /// with the `initial_error` sigmas on east and north position, east and
    /// north velocity, and yaw (drawn in that order from a stream of `seed`
    /// independent of those used by [`simulate`]).
    pub fn initial_ins_state(&self, seed: u64) -> Result<InitialState, SimError> {
        self.validate()?;
        let model = TrajectoryModel::new(&self.trajectory, self.height_m).map_err(|source| {
            SimError::Trajectory {
                t_s: 0.0,
                error: source,
            }
        })?;
        let k = model.eval(0.0).map_err(|source| SimError::Trajectory {
            t_s: 0.0,
            error: source,
        })?;
        let mut rng = rng::stream(seed, STREAM_INITIAL);
        let e = &self.initial_error;
        let dp = [rng.normal(e.pos_m), rng.normal(e.pos_m)];
        let dv = [rng.normal(e.vel_mps), rng.normal(e.vel_mps)];
        let dy = rng.normal(e.yaw_rad);
        Ok(InitialState {
            pos_m: [k.pos_m[0] + dp[0], k.pos_m[1] + dp[1], k.pos_m[2]],
            vel_mps: [k.vel_mps[0] + dv[0], k.vel_mps[1] + dv[1], k.vel_mps[2]],
            yaw_rad: k.yaw_rad + dy,
        })
    }
}

/// Time of sample `k` at `rate_hz`, ns (rounded to the nearest nanosecond).
fn time_ns(k: u64, rate_hz: f64) -> u64 {
    (k as f64 * 1e9 / rate_hz).round() as u64
}

/// Seconds to nanoseconds for interval bounds (clamped at 0).
fn to_ns(t_s: f64) -> u64 {
    (t_s * 1e9).round().max(0.0) as u64
}

/// A time interval `[start, end)` in ns affecting one anchor index with a fixed excess.
#[derive(Debug, Clone, Copy)]
struct NlosEvent {
    anchor: usize,
    start_ns: u64,
    end_ns: u64,
    excess_m: f64,
}

/// Runs the scenario with `seed`.
pub fn simulate(scenario: &Scenario, seed: u64) -> Result<SimOutput, SimError> {
    scenario.validate()?;
    let model =
        TrajectoryModel::new(&scenario.trajectory, scenario.height_m).map_err(|source| {
            SimError::Trajectory {
                t_s: 0.0,
                error: source,
            }
        })?;
    let (imu, truth, imu_errors) = simulate_imu(scenario, &model, seed)?;
    let uwb = simulate_uwb(scenario, &model, seed)?;
    let velocity = simulate_velocity(scenario, &model, seed)?;
    let height = velocity
        .iter()
        .filter_map(|v| {
            v.range_m().map(|range_m| Height {
                header: Header::new(0, v.header.meas_time_ns),
                range_m,
                source: Height::SOURCE_RANGE_FINDER,
            })
        })
        .enumerate()
        .map(|(k, mut h)| {
            h.header.seq = k as u64;
            h
        })
        .collect();
    Ok(SimOutput {
        imu,
        tdoa: uwb.tdoa,
        truth,
        tdoa_truth: uwb.tdoa_truth,
        range: uwb.range,
        range_truth: uwb.range_truth,
        velocity,
        height,
        imu_errors,
    })
}

/// Whether `t_ns` falls inside one of the dropouts.
fn dropped(dropouts: &[Dropout], t_ns: u64) -> bool {
    dropouts
        .iter()
        .any(|d| to_ns(d.start_s) <= t_ns && t_ns < to_ns(d.start_s + d.duration_s))
}

/// One body-velocity sensor of the scenario, as the simulation needs it.
struct VelocitySensor<'a> {
    source: u32,
    rate_hz: f64,
    offset_s: f64,
    dropouts: &'a [Dropout],
    stream: u64,
    /// Scale factor per body axis.
    scale: [f64; 3],
    /// Standard deviation per body axis; 0: not measured (reported 0).
    sigma: [f64; 3],
    /// Which axes report the true velocity (the others report zero plus
    /// their noise: the odometry's lateral axis).
    measures: [bool; 3],
    /// The range finder's noise, m; 0: no range.
    range_sigma_m: f64,
}

/// The odometry and flow samples of the run, merged by time.
fn simulate_velocity(
    sc: &Scenario,
    model: &TrajectoryModel,
    seed: u64,
) -> Result<Vec<BodyVelocity>, SimError> {
    let mut sensors = Vec::new();
    if let Some(o) = &sc.odometry {
        sensors.push(VelocitySensor {
            source: BodyVelocity::SOURCE_ODOMETRY,
            rate_hz: o.rate_hz,
            offset_s: o.offset_s,
            dropouts: &o.dropouts,
            stream: STREAM_ODOMETRY,
            scale: [o.scale, 1.0, 1.0],
            sigma: [o.sigma_mps, o.lateral_sigma_mps, 0.0],
            measures: [true, false, false],
            range_sigma_m: 0.0,
        });
    }
    if let Some(f) = &sc.flow {
        sensors.push(VelocitySensor {
            source: BodyVelocity::SOURCE_FLOW,
            rate_hz: f.rate_hz,
            offset_s: f.offset_s,
            dropouts: &f.dropouts,
            stream: STREAM_FLOW,
            scale: [f.scale, f.scale, 1.0],
            sigma: [f.sigma_mps, f.sigma_mps, 0.0],
            measures: [true, true, false],
            range_sigma_m: f.range_sigma_m,
        });
    }
    let mut out: Vec<BodyVelocity> = Vec::new();
    for s in &sensors {
        let mut rng = rng::stream(seed, s.stream);
        let mut samples = Vec::new();
        for t_ns in velocity_times(sc.duration_s, s.rate_hz, s.offset_s) {
            if dropped(s.dropouts, t_ns) {
                continue;
            }
            let t_s = t_ns as f64 * 1e-9;
            let kin = model
                .eval(t_s)
                .map_err(|source| SimError::Trajectory { t_s, error: source })?;
            // Body frame (pure yaw): R^T v.
            let (sn, cs) = kin.yaw_rad.sin_cos();
            let [ve, vn, vu] = kin.vel_mps;
            let body = [cs * ve + sn * vn, -sn * ve + cs * vn, vu];
            let mut vel = [0.0; 3];
            for a in 0..3 {
                let truth = if s.measures[a] {
                    s.scale[a] * body[a]
                } else {
                    0.0
                };
                vel[a] = truth + rng.normal(s.sigma[a]);
            }
            // The range to the floor at z = 0 along body z (no tilt), in
            // whole mm as the sensor reports it; drawn after the velocity,
            // so a range leaves the velocities' noise as it was.
            let range_mm = if s.range_sigma_m > 0.0 {
                BodyVelocity::range_mm_from_m(kin.pos_m[2] + rng.normal(s.range_sigma_m))
            } else {
                0
            };
            samples.push(BodyVelocity {
                header: Header::new(0, t_ns),
                vel_mps: vel,
                sigma_mps: s.sigma,
                source: s.source,
                range_mm,
            });
        }
        // Merge with what is there (both sorted by time; validation keeps
        // their times apart).
        let mut merged = Vec::with_capacity(out.len() + samples.len());
        let (mut a, mut b) = (out.into_iter().peekable(), samples.into_iter().peekable());
        loop {
            let take_a = match (a.peek(), b.peek()) {
                (Some(x), Some(y)) => x.header.meas_time_ns <= y.header.meas_time_ns,
                (Some(_), None) => true,
                (None, Some(_)) => false,
                (None, None) => break,
            };
            merged.extend(if take_a { a.next() } else { b.next() });
        }
        out = merged;
    }
    for (k, m) in out.iter_mut().enumerate() {
        m.header.seq = k as u64;
    }
    Ok(out)
}

type ImuRun = (Vec<ImuSample>, Vec<GroundTruth>, ImuErrorRealisation);

fn simulate_imu(sc: &Scenario, model: &TrajectoryModel, seed: u64) -> Result<ImuRun, SimError> {
    let e = &sc.imu;
    let g = sc.gravity_mps2;
    let rate = sc.imu_rate_hz;
    let dt = 1.0 / rate;

    let mut bias_rng = rng::stream(seed, STREAM_IMU_BIAS);
    let mut gyro_bias = [0.0; 3];
    let mut accel_bias = [0.0; 3];
    for b in &mut gyro_bias {
        *b = bias_rng.sign() * e.gyro_bias_deg_per_h * DEG / 3600.0;
    }
    for b in &mut accel_bias {
        *b = bias_rng.sign() * e.accel_bias_g * g;
    }
    let realised = ImuErrorRealisation {
        gyro_bias_rps: gyro_bias,
        accel_bias_mps2: accel_bias,
    };

    // Per-sample white noise: density * sqrt(rate).
    let gyro_sigma = e.gyro_arw_deg_per_sqrt_h * DEG / 60.0 * rate.sqrt();
    let accel_sigma = e.accel_vrw_g_sqrt_s * g * rate.sqrt();
    // Bias walk step per sample: density * sqrt(dt).
    let gyro_walk = e.gyro_bias_walk_deg_per_h_per_sqrt_s * DEG / 3600.0 * dt.sqrt();
    let accel_walk = e.accel_bias_walk_g_per_sqrt_s * g * dt.sqrt();
    let mut rng = rng::stream(seed, STREAM_IMU_NOISE);

    let n = sample_count(sc.duration_s, rate);
    let cap = usize::try_from(n).unwrap_or(0);
    let mut imu = Vec::with_capacity(cap);
    let mut truth = Vec::with_capacity(cap);
    for k in 0..n {
        let t_ns = time_ns(k, rate);
        let t_s = t_ns as f64 * 1e-9;
        let kin = model
            .eval(t_s)
            .map_err(|source| SimError::Trajectory { t_s, error: source })?;
        let mut gt = GroundTruth {
            header: Header::new(k, t_ns),
            pos_m: kin.pos_m,
            vel_mps: kin.vel_mps,
            quat: kin.quat(),
        };
        gt.header.flags |= GroundTruth::FLAG_VEL_VALID;
        truth.push(gt);

        let f = kin.specific_force_body(g);
        let w = kin.body_rate();
        let mut accel = [0.0; 3];
        let mut gyro = [0.0; 3];
        for a in 0..3 {
            gyro[a] = w[a] + gyro_bias[a] + rng.normal(gyro_sigma);
        }
        for a in 0..3 {
            accel[a] = f[a] + accel_bias[a] + rng.normal(accel_sigma);
        }
        imu.push(ImuSample {
            header: Header::new(k, t_ns),
            accel_mps2: accel,
            gyro_rps: gyro,
        });
        for b in &mut gyro_bias {
            *b += rng.normal(gyro_walk);
        }
        for b in &mut accel_bias {
            *b += rng.normal(accel_walk);
        }
    }
    Ok((imu, truth, realised))
}

/// Draws the random NLOS events of the run (per anchor, in anchor order).
fn random_nlos_events(sc: &Scenario, seed: u64) -> Vec<NlosEvent> {
    let mut events = Vec::new();
    let Some(r) = &sc.uwb.random_nlos else {
        return events;
    };
    if r.rate_per_s <= 0.0 {
        return events;
    }
    let mut rng = rng::stream(seed, STREAM_RANDOM_NLOS);
    // Hard cap on the number of events (validation bounds the expectation).
    let cap = (crate::scenario::MAX_RANDOM_NLOS_EVENTS * 2.0) as usize;
    for (ai, a) in sc.uwb.anchors.iter().enumerate() {
        if !r.anchors.contains(a.id) {
            continue;
        }
        let mut t = r.start_s;
        loop {
            t += rng.exponential(1.0 / r.rate_per_s);
            if t >= sc.duration_s || events.len() >= cap {
                break;
            }
            let d = rng.exponential(r.mean_duration_s);
            let excess = rng.uniform_in(r.bias_m[0], r.bias_m[1]);
            events.push(NlosEvent {
                anchor: ai,
                start_ns: to_ns(t),
                end_ns: to_ns(t + d),
                excess_m: excess,
            });
        }
    }
    events
}

/// The UWB measurements of a run: TDOA differences or two-way ranges
/// (the other pair of vectors empty).
#[derive(Default)]
struct UwbRun {
    tdoa: Vec<UwbTdoa>,
    tdoa_truth: Vec<TdoaTruth>,
    range: Vec<UwbRange>,
    range_truth: Vec<RangeTruth>,
}

/// The UWB epochs of the run. Per epoch, in this order: one noise draw per
/// anchor (anchor order; TDOA `per_anchor`: `tdoa_sigma_m / sqrt(2)`, TWR:
/// `range_sigma_m`), the outlier bursts' draws, then for TDOA
/// `per_difference` one draw per difference. Each anchor's NLOS excess
/// (bursts plus random events) is positive: it lengthens that anchor's
/// range, and biases a difference by `excess_b - excess_a`.
fn simulate_uwb(sc: &Scenario, model: &TrajectoryModel, seed: u64) -> Result<UwbRun, SimError> {
    let u = &sc.uwb;
    let twr = u.kind == UwbKind::Twr;
    let pairs = if twr { Vec::new() } else { u.pair_indices() };
    let na = u.anchors.len();
    let rate = sc.uwb_rate_hz;
    let n = sample_count(sc.duration_s, rate);
    let per_epoch = if twr { na } else { pairs.len() };
    let cap = usize::try_from(n).unwrap_or(0).saturating_mul(per_epoch);
    let mut run = UwbRun::default();
    if twr {
        run.range.reserve(cap);
        run.range_truth.reserve(cap);
    } else {
        run.tdoa.reserve(cap);
        run.tdoa_truth.reserve(cap);
    }

    let bursts: Vec<(u64, u64)> = u
        .outliers
        .iter()
        .map(|o| (to_ns(o.start_s), to_ns(o.start_s + o.duration_s)))
        .collect();
    let drops: Vec<(u64, u64)> = u
        .dropouts
        .iter()
        .map(|d| (to_ns(d.start_s), to_ns(d.start_s + d.duration_s)))
        .collect();
    let random = random_nlos_events(sc, seed);

    let mut noise_rng = rng::stream(seed, STREAM_UWB_NOISE);
    let mut burst_rng = rng::stream(seed, STREAM_OUTLIERS);
    let (anchor_sigma, diff_sigma) = match (u.kind, u.noise_model) {
        (UwbKind::Twr, _) => (u.range_sigma_m, 0.0),
        (UwbKind::Tdoa, NoiseModel::PerAnchor) => (u.tdoa_sigma_m / core::f64::consts::SQRT_2, 0.0),
        (UwbKind::Tdoa, NoiseModel::PerDifference) => (0.0, u.tdoa_sigma_m),
    };
    let mut range = vec![0.0; na];
    let mut excess = vec![0.0; na];
    let mut noise = vec![0.0; na];
    let mut seq = 0u64;
    for k in 0..n {
        let t_ns = time_ns(k, rate);
        if drops.iter().any(|&(a, b)| a <= t_ns && t_ns < b) {
            continue;
        }
        let t_s = t_ns as f64 * 1e-9;
        let kin = model
            .eval(t_s)
            .map_err(|source| SimError::Trajectory { t_s, error: source })?;
        let p = kin.pos_m;
        for (j, a) in u.anchors.iter().enumerate() {
            let d = [p[0] - a.pos_m[0], p[1] - a.pos_m[1], p[2] - a.pos_m[2]];
            range[j] = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            excess[j] = 0.0;
            noise[j] = noise_rng.normal(anchor_sigma);
        }
        for (o, &(b0, b1)) in u.outliers.iter().zip(&bursts) {
            if !(b0 <= t_ns && t_ns < b1) {
                continue;
            }
            for (j, a) in u.anchors.iter().enumerate() {
                if o.anchors.contains(a.id) && burst_rng.bernoulli(o.probability) {
                    // An excess path: never negative (validation keeps
                    // bias_m >= 0; the absolute value makes it certain).
                    excess[j] += burst_rng.uniform_in(o.bias_m[0], o.bias_m[1]).abs();
                }
            }
        }
        for ev in &random {
            if ev.start_ns <= t_ns && t_ns < ev.end_ns {
                if let Some(x) = excess.get_mut(ev.anchor) {
                    *x += ev.excess_m.abs();
                }
            }
        }
        if twr {
            let last = na.saturating_sub(1);
            for (j, a) in u.anchors.iter().enumerate() {
                let tr = RangeTruth {
                    geometric_m: range[j],
                    anchor_bias_m: a.range_bias_m,
                    nlos_m: excess[j],
                    noise_m: noise[j],
                };
                let mut m = UwbRange {
                    header: Header::new(seq, t_ns),
                    anchor: a.id,
                    quality: 0,
                    range_m: tr.geometric_m + tr.anchor_bias_m + tr.nlos_m + tr.noise_m,
                    anchor_pos_m: a.pos_m,
                };
                if j == last {
                    m.header.flags |= UwbRange::FLAG_EPOCH_END;
                }
                seq += 1;
                run.range.push(m);
                run.range_truth.push(tr);
            }
            continue;
        }
        let last = pairs.len().saturating_sub(1);
        for (pi, &(ia, ib)) in pairs.iter().enumerate() {
            let (aa, ab) = (&u.anchors[ia], &u.anchors[ib]);
            let tr = TdoaTruth {
                geometric_m: range[ib] - range[ia],
                anchor_bias_m: ab.range_bias_m - aa.range_bias_m,
                nlos_m: excess[ib] - excess[ia],
                noise_m: noise[ib] - noise[ia] + noise_rng.normal(diff_sigma),
            };
            let mut m = UwbTdoa {
                header: Header::new(seq, t_ns),
                anchor_a: aa.id,
                anchor_b: ab.id,
                diff_m: tr.geometric_m + tr.anchor_bias_m + tr.nlos_m + tr.noise_m,
                anchor_a_pos_m: aa.pos_m,
                anchor_b_pos_m: ab.pos_m,
            };
            if pi == last {
                m.header.flags |= UwbTdoa::FLAG_EPOCH_END;
            }
            seq += 1;
            run.tdoa.push(m);
            run.tdoa_truth.push(tr);
        }
    }
    Ok(run)
}
