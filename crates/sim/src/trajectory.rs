//! Robot trajectories: their configuration ([`Trajectory`]) and their exact
//! kinematics ([`TrajectoryModel`]): position, velocity, acceleration, yaw
//! and yaw rate at any time, from closed-form derivatives.
//!
//! The robot moves in a horizontal plane at a fixed height with zero roll and
//! pitch. Its body x axis points along the path (a non-holonomic robot): yaw
//! is the heading of the path tangent (counter-clockwise from east), so the
//! yaw rate is `speed * curvature`.
//!
//! Waypoint paths are C2 cubic splines through the points (chord-length
//! knots), travelled at constant speed along the arc length with cycloidal
//! speed ramps: position, velocity, acceleration (hence specific force), jerk
//! along the path and yaw rate are all continuous, as a real IMU sees them.

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Most waypoints a path may have (bounds the spline's memory and solve).
pub const MAX_WAYPOINTS: usize = 256;

/// Sub-intervals per spline segment in the arc-length table.
const ARC_SUBDIV: usize = 16;

/// 5-point Gauss-Legendre nodes on [-1, 1].
const GL_X: [f64; 5] = [
    0.0,
    -0.538_469_310_105_683_1,
    0.538_469_310_105_683_1,
    -0.906_179_845_938_664,
    0.906_179_845_938_664,
];
/// 5-point Gauss-Legendre weights.
const GL_W: [f64; 5] = [
    0.568_888_888_888_888_9,
    0.478_628_670_499_366_5,
    0.478_628_670_499_366_5,
    0.236_926_885_056_189_1,
    0.236_926_885_056_189_1,
];

/// The path the robot follows (one TOML sub-table: `[sim.trajectory.<kind>]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum Trajectory {
    /// Standing still (paper section 4.3).
    Static(StaticPose),
    /// A smooth path through waypoints, from rest (paper sections 3.4, 4.4).
    Waypoints(WaypointPath),
    /// Constant-speed circle.
    Circle(CirclePath),
    /// Lissajous curve `x = a_x sin(2 pi t / T_x + phi_x)`, same for y.
    Lissajous(LissajousPath),
    /// Figure eight: `x = a_x sin(w t)`, `y = a_y sin(2 w t)`, `w = 2 pi / period`.
    Figure8(Figure8Path),
}

impl Default for Trajectory {
    /// Static at the origin, facing east.
    fn default() -> Self {
        Self::Static(StaticPose::default())
    }
}

/// A robot standing still.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StaticPose {
    /// Horizontal position `[east, north]`, m (default the origin).
    pub pos_m: [f64; 2],
    /// Heading, counter-clockwise from east, rad (default 0).
    pub yaw_rad: f64,
}

/// A smooth path through waypoints, started from rest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WaypointPath {
    /// Points `[east, north]` the path passes through, m (at least 2; 3 when closed).
    pub points: Vec<[f64; 2]>,
    /// Cruise speed along the path, m/s.
    pub speed_mps: f64,
    /// Heading at the first point, rad (default: the natural spline's tangent).
    #[serde(default)]
    pub start_yaw_rad: Option<f64>,
    /// The path loops back to the first point and is travelled repeatedly
    /// (default false: the robot stops at the last point and stays there).
    #[serde(default)]
    pub closed: bool,
    /// Duration of each speed ramp (start, and stop for an open path), s
    /// (default 2 s). Ramps are cycloidal (continuous jerk); the peak
    /// tangential acceleration is `2 speed_mps / ramp_s`.
    #[serde(default = "default_ramp_s")]
    pub ramp_s: f64,
    /// Time at rest on the first point before moving, s (default 0).
    #[serde(default)]
    pub hold_start_s: f64,
}

fn default_ramp_s() -> f64 {
    2.0
}

impl Default for WaypointPath {
    /// A 4 m straight line east at 0.5 m/s.
    fn default() -> Self {
        Self {
            points: vec![[0.0, 0.0], [4.0, 0.0]],
            speed_mps: 0.5,
            start_yaw_rad: None,
            closed: false,
            ramp_s: default_ramp_s(),
            hold_start_s: 0.0,
        }
    }
}

/// A circle at constant speed (moving from t = 0).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CirclePath {
    /// Centre `[east, north]`, m (default the origin).
    pub centre_m: [f64; 2],
    /// Radius, m (default 2).
    pub radius_m: f64,
    /// Speed, m/s (default 0.5).
    pub speed_mps: f64,
    /// Angle of the start point from the centre, counter-clockwise from east, rad (default 0).
    pub start_angle_rad: f64,
    /// Travel clockwise (default false: counter-clockwise).
    pub clockwise: bool,
}

impl Default for CirclePath {
    fn default() -> Self {
        Self {
            centre_m: [0.0, 0.0],
            radius_m: 2.0,
            speed_mps: 0.5,
            start_angle_rad: 0.0,
            clockwise: false,
        }
    }
}

/// A Lissajous curve `p = centre + a * sin(2 pi t / period + phase)` per axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LissajousPath {
    /// Centre `[east, north]`, m (default the origin).
    pub centre_m: [f64; 2],
    /// Amplitudes `[east, north]`, m (default [3, 2]).
    pub amplitude_m: [f64; 2],
    /// Periods `[east, north]`, s (default [20, 10]).
    pub period_s: [f64; 2],
    /// Phases `[east, north]`, rad (default [0, 0]).
    pub phase_rad: [f64; 2],
}

impl Default for LissajousPath {
    fn default() -> Self {
        Self {
            centre_m: [0.0, 0.0],
            amplitude_m: [3.0, 2.0],
            period_s: [20.0, 10.0],
            phase_rad: [0.0, 0.0],
        }
    }
}

/// A figure eight: `x = a_x sin(w t)`, `y = a_y sin(2 w t)`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Figure8Path {
    /// Centre (the crossing point) `[east, north]`, m (default the origin).
    pub centre_m: [f64; 2],
    /// Half-sizes `[east, north]`, m (default [3, 2]).
    pub half_size_m: [f64; 2],
    /// Time for one full eight, s (default 30).
    pub period_s: f64,
}

impl Default for Figure8Path {
    fn default() -> Self {
        Self {
            centre_m: [0.0, 0.0],
            half_size_m: [3.0, 2.0],
            period_s: 30.0,
        }
    }
}

/// Why a trajectory cannot be built or evaluated.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum TrajectoryError {
    /// Too few waypoints.
    #[error("needs at least {need} points, got {got}")]
    TooFewPoints {
        /// Minimum.
        need: usize,
        /// Given.
        got: usize,
    },
    /// Too many waypoints.
    #[error("at most {max} points, got {got}")]
    TooManyPoints {
        /// Maximum ([`MAX_WAYPOINTS`]).
        max: usize,
        /// Given.
        got: usize,
    },
    /// Two consecutive waypoints coincide.
    #[error("point {index} coincides with the point before it")]
    RepeatedPoint {
        /// Index of the repeated point.
        index: usize,
    },
    /// `start_yaw_rad` was given for a closed path (whose tangent is fixed by periodicity).
    #[error("start_yaw_rad cannot be set on a closed path")]
    StartYawOnClosed,
    /// The spline's parameterisation stalls (a cusp): the points turn too sharply.
    #[error("the spline through the points has a cusp near point {index}; spread the points out")]
    Cusp {
        /// Segment start index.
        index: usize,
    },
    /// The open path is shorter than the speed ramps need.
    #[error("path is {length_m} m long, but speeding up and stopping need {needed_m} m (speed_mps * ramp_s)")]
    PathTooShort {
        /// Path length, m.
        length_m: f64,
        /// Distance covered by the two ramps, m.
        needed_m: f64,
    },
    /// The heading is undefined because the speed vanishes (Lissajous or figure eight).
    #[error("speed is zero at t = {t_s} s, so the heading is undefined")]
    ZeroSpeed {
        /// Time, s.
        t_s: f64,
    },
    /// The arc-length inversion did not converge (should not happen).
    #[error("arc-length inversion failed at s = {s_m} m")]
    ArcLength {
        /// Arc length, m.
        s_m: f64,
    },
}

/// Exact kinematics of the robot at one instant (ENU, body FLU with zero tilt).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Kinematics {
    /// Position, m (z is the scenario's height).
    pub pos_m: [f64; 3],
    /// Velocity, m/s (z zero).
    pub vel_mps: [f64; 3],
    /// Kinematic acceleration (gravity not included), m/s^2.
    pub accel_mps2: [f64; 3],
    /// Yaw, counter-clockwise from east, in (-pi, pi], rad.
    pub yaw_rad: f64,
    /// Yaw rate, rad/s.
    pub yaw_rate_rps: f64,
}

impl Kinematics {
    /// Attitude quaternion `[w, x, y, z]` body to ENU (pure yaw, `w >= 0`).
    #[must_use]
    pub fn quat(&self) -> [f64; 4] {
        let (s, c) = (0.5 * self.yaw_rad).sin_cos();
        [c, 0.0, 0.0, s]
    }

    /// Specific force in the body frame, m/s^2: `R^T (a + [0, 0, g])`.
    #[must_use]
    pub fn specific_force_body(&self, gravity_mps2: f64) -> [f64; 3] {
        let (s, c) = self.yaw_rad.sin_cos();
        let [ae, an, au] = self.accel_mps2;
        [c * ae + s * an, -s * ae + c * an, au + gravity_mps2]
    }

    /// Angular rate in the body frame, rad/s (the Earth's rotation is not simulated).
    #[must_use]
    pub fn body_rate(&self) -> [f64; 3] {
        [0.0, 0.0, self.yaw_rate_rps]
    }
}

/// A trajectory ready to evaluate.
#[derive(Debug, Clone, PartialEq)]
pub struct TrajectoryModel {
    height_m: f64,
    kind: ModelKind,
}

#[derive(Debug, Clone, PartialEq)]
enum ModelKind {
    Static {
        pos: [f64; 2],
        yaw: f64,
    },
    Spline {
        spline: Spline,
        profile: SpeedProfile,
    },
    Circle {
        centre: [f64; 2],
        radius: f64,
        speed: f64,
        angle0: f64,
        dir: f64,
    },
    Lissajous {
        centre: [f64; 2],
        amp: [f64; 2],
        omega: [f64; 2],
        phase: [f64; 2],
    },
}

impl TrajectoryModel {
    /// Builds the model (for waypoints: solves the spline and tabulates its arc length).
    /// Values are assumed finite (checked by `Scenario::validate`).
    pub fn new(trajectory: &Trajectory, height_m: f64) -> Result<Self, TrajectoryError> {
        let kind = match trajectory {
            Trajectory::Static(p) => ModelKind::Static {
                pos: p.pos_m,
                yaw: p.yaw_rad,
            },
            Trajectory::Waypoints(w) => {
                let spline = Spline::new(&w.points, w.start_yaw_rad, w.closed)?;
                let length = spline.length();
                if !w.closed && length < w.speed_mps * w.ramp_s {
                    return Err(TrajectoryError::PathTooShort {
                        length_m: length,
                        needed_m: w.speed_mps * w.ramp_s,
                    });
                }
                let profile = SpeedProfile {
                    hold_s: w.hold_start_s,
                    ramp_s: w.ramp_s,
                    speed: w.speed_mps,
                    stop_at: (!w.closed).then_some(length),
                };
                ModelKind::Spline { spline, profile }
            }
            Trajectory::Circle(c) => ModelKind::Circle {
                centre: c.centre_m,
                radius: c.radius_m,
                speed: c.speed_mps,
                angle0: c.start_angle_rad,
                dir: if c.clockwise { -1.0 } else { 1.0 },
            },
            Trajectory::Lissajous(l) => ModelKind::Lissajous {
                centre: l.centre_m,
                amp: l.amplitude_m,
                omega: [
                    core::f64::consts::TAU / l.period_s[0],
                    core::f64::consts::TAU / l.period_s[1],
                ],
                phase: l.phase_rad,
            },
            Trajectory::Figure8(f) => {
                let w = core::f64::consts::TAU / f.period_s;
                ModelKind::Lissajous {
                    centre: f.centre_m,
                    amp: f.half_size_m,
                    omega: [w, 2.0 * w],
                    phase: [0.0, 0.0],
                }
            }
        };
        Ok(Self { height_m, kind })
    }

    /// Length of a waypoint path (one lap when closed), m; `None` for other kinds.
    #[must_use]
    pub fn path_length_m(&self) -> Option<f64> {
        match &self.kind {
            ModelKind::Spline { spline, .. } => Some(spline.length()),
            _ => None,
        }
    }

    /// Kinematics at time `t_s` (seconds from the start).
    pub fn eval(&self, t_s: f64) -> Result<Kinematics, TrajectoryError> {
        let h = self.height_m;
        match &self.kind {
            ModelKind::Static { pos, yaw } => Ok(Kinematics {
                pos_m: [pos[0], pos[1], h],
                yaw_rad: wrap_pi(*yaw),
                ..Kinematics::default()
            }),
            ModelKind::Circle {
                centre,
                radius,
                speed,
                angle0,
                dir,
            } => {
                let theta = angle0 + dir * speed / radius * t_s;
                let (s, c) = theta.sin_cos();
                let a = speed * speed / radius;
                Ok(Kinematics {
                    pos_m: [centre[0] + radius * c, centre[1] + radius * s, h],
                    vel_mps: [-dir * speed * s, dir * speed * c, 0.0],
                    accel_mps2: [-a * c, -a * s, 0.0],
                    yaw_rad: wrap_pi(theta + dir * core::f64::consts::FRAC_PI_2),
                    yaw_rate_rps: dir * speed / radius,
                })
            }
            ModelKind::Lissajous {
                centre,
                amp,
                omega,
                phase,
            } => {
                let mut p = [0.0; 2];
                let mut d1 = [0.0; 2];
                let mut d2 = [0.0; 2];
                for i in 0..2 {
                    let (s, c) = (omega[i] * t_s + phase[i]).sin_cos();
                    p[i] = centre[i] + amp[i] * s;
                    d1[i] = amp[i] * omega[i] * c;
                    d2[i] = -amp[i] * omega[i] * omega[i] * s;
                }
                let v2 = d1[0] * d1[0] + d1[1] * d1[1];
                if v2 < 1e-12 {
                    return Err(TrajectoryError::ZeroSpeed { t_s });
                }
                Ok(Kinematics {
                    pos_m: [p[0], p[1], h],
                    vel_mps: [d1[0], d1[1], 0.0],
                    accel_mps2: [d2[0], d2[1], 0.0],
                    yaw_rad: d1[1].atan2(d1[0]),
                    yaw_rate_rps: (d1[0] * d2[1] - d1[1] * d2[0]) / v2,
                })
            }
            ModelKind::Spline { spline, profile } => {
                let (s, v, a_t) = profile.at(t_s);
                let s_in = if spline.closed {
                    s.rem_euclid(spline.length())
                } else {
                    s.clamp(0.0, spline.length())
                };
                let u = spline.u_of_s(s_in)?;
                let (p, d1, d2) = spline.eval(u);
                let n1 = d1[0].hypot(d1[1]);
                let tan = [d1[0] / n1, d1[1] / n1];
                let d2_t = d2[0] * tan[0] + d2[1] * tan[1];
                // Curvature vector dT/ds and signed curvature.
                let kv = [
                    (d2[0] - d2_t * tan[0]) / (n1 * n1),
                    (d2[1] - d2_t * tan[1]) / (n1 * n1),
                ];
                let kappa = (d1[0] * d2[1] - d1[1] * d2[0]) / (n1 * n1 * n1);
                Ok(Kinematics {
                    pos_m: [p[0], p[1], h],
                    vel_mps: [v * tan[0], v * tan[1], 0.0],
                    accel_mps2: [
                        a_t * tan[0] + v * v * kv[0],
                        a_t * tan[1] + v * v * kv[1],
                        0.0,
                    ],
                    yaw_rad: tan[1].atan2(tan[0]),
                    yaw_rate_rps: v * kappa,
                })
            }
        }
    }
}

/// Wraps an angle into (-pi, pi].
fn wrap_pi(a: f64) -> f64 {
    let w = a.rem_euclid(core::f64::consts::TAU);
    if w > core::f64::consts::PI {
        w - core::f64::consts::TAU
    } else {
        w
    }
}

/// Arc length, speed and tangential acceleration against time: hold, ramp up,
/// cruise, and (open paths) ramp down ending exactly at the end of the path.
///
/// The ramps are cycloidal: `a(tau) = (v / T) (1 - cos(2 pi tau / T))`, so the
/// acceleration and its derivative (jerk) are continuous everywhere; the peak
/// tangential acceleration is `2 v / T`.
#[derive(Debug, Clone, PartialEq)]
struct SpeedProfile {
    hold_s: f64,
    ramp_s: f64,
    speed: f64,
    /// Path length where the robot stops (`None`: never stops).
    stop_at: Option<f64>,
}

impl SpeedProfile {
    /// `(s, v, a)` of the ramp up, `tau` in `[0, ramp_s]`.
    fn ramp_up(&self, tau: f64) -> (f64, f64, f64) {
        use core::f64::consts::TAU;
        let (tr, v) = (self.ramp_s, self.speed);
        let (sn, cs) = (TAU * tau / tr).sin_cos();
        let s = v * (tau * tau / (2.0 * tr) + tr / (TAU * TAU) * (cs - 1.0));
        (s, v * (tau / tr - sn / TAU), v / tr * (1.0 - cs))
    }

    /// `(s, v, a)` at time `t`.
    fn at(&self, t: f64) -> (f64, f64, f64) {
        let (tr, v) = (self.ramp_s, self.speed);
        let tau = t - self.hold_s;
        if tau <= 0.0 {
            return (0.0, 0.0, 0.0);
        }
        // Start of the ramp down (infinite for closed paths).
        let t_down = match self.stop_at {
            Some(len) => tr + (len - v * tr) / v,
            None => f64::INFINITY,
        };
        if tau < tr && tau < t_down {
            return self.ramp_up(tau);
        }
        if tau < t_down {
            return (0.5 * v * tr + v * (tau - tr), v, 0.0);
        }
        let len = self.stop_at.unwrap_or(0.0);
        let td = tau - t_down;
        if td >= tr {
            return (len, 0.0, 0.0);
        }
        // Mirror of the ramp up: v_down(td) = v - v_up(td).
        let (su, vu, au) = self.ramp_up(td);
        let s_d = len - 0.5 * v * tr;
        (s_d + v * td - su, v - vu, -au)
    }
}

/// A 2-D cubic spline with chord-length knots and an arc-length table.
#[derive(Debug, Clone, PartialEq)]
struct Spline {
    /// Knots `u_0 = 0 < u_1 < ... < u_m` (`m` segments).
    knots: Vec<f64>,
    /// Points at the knots (a closed path repeats the first at the end).
    pts: Vec<[f64; 2]>,
    /// Second derivatives at the knots.
    m2: Vec<[f64; 2]>,
    /// Cumulative arc length at the `ARC_SUBDIV` sub-interval boundaries of each segment.
    arc: Vec<f64>,
    closed: bool,
}

impl Spline {
    fn new(
        points: &[[f64; 2]],
        start_yaw: Option<f64>,
        closed: bool,
    ) -> Result<Self, TrajectoryError> {
        let need = if closed { 3 } else { 2 };
        if points.len() < need {
            return Err(TrajectoryError::TooFewPoints {
                need,
                got: points.len(),
            });
        }
        if points.len() > MAX_WAYPOINTS {
            return Err(TrajectoryError::TooManyPoints {
                max: MAX_WAYPOINTS,
                got: points.len(),
            });
        }
        if closed && start_yaw.is_some() {
            return Err(TrajectoryError::StartYawOnClosed);
        }
        let mut pts: Vec<[f64; 2]> = points.to_vec();
        if closed {
            pts.push(points[0]);
        }
        let mut knots = Vec::with_capacity(pts.len());
        knots.push(0.0);
        let mut h = Vec::with_capacity(pts.len());
        for (i, w) in pts.windows(2).enumerate() {
            let d = (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]);
            if d < 1e-6 {
                return Err(TrajectoryError::RepeatedPoint {
                    index: (i + 1) % points.len(),
                });
            }
            h.push(d);
            knots.push(knots[i] + d);
        }
        let m2 = solve_second_derivatives(&pts, &h, start_yaw, closed);
        let mut spline = Self {
            knots,
            pts,
            m2,
            arc: Vec::new(),
            closed,
        };
        spline.tabulate_arc()?;
        Ok(spline)
    }

    fn segments(&self) -> usize {
        self.knots.len() - 1
    }

    fn length(&self) -> f64 {
        self.arc.last().copied().unwrap_or(0.0)
    }

    /// Position, first and second derivatives at parameter `u` (clamped to the knots).
    fn eval(&self, u: f64) -> ([f64; 2], [f64; 2], [f64; 2]) {
        let n = self.segments();
        let i = self
            .knots
            .partition_point(|&k| k <= u)
            .saturating_sub(1)
            .min(n - 1);
        self.eval_in(i, u)
    }

    fn eval_in(&self, i: usize, u: f64) -> ([f64; 2], [f64; 2], [f64; 2]) {
        let (u0, u1) = (self.knots[i], self.knots[i + 1]);
        let h = u1 - u0;
        let a = (u1 - u) / h;
        let b = (u - u0) / h;
        let (p0, p1) = (self.pts[i], self.pts[i + 1]);
        let (m0, m1) = (self.m2[i], self.m2[i + 1]);
        let mut p = [0.0; 2];
        let mut d1 = [0.0; 2];
        let mut d2 = [0.0; 2];
        for k in 0..2 {
            p[k] = a * p0[k]
                + b * p1[k]
                + ((a * a * a - a) * m0[k] + (b * b * b - b) * m1[k]) * h * h / 6.0;
            d1[k] = (p1[k] - p0[k]) / h - (3.0 * a * a - 1.0) / 6.0 * h * m0[k]
                + (3.0 * b * b - 1.0) / 6.0 * h * m1[k];
            d2[k] = a * m0[k] + b * m1[k];
        }
        (p, d1, d2)
    }

    fn speed_in(&self, i: usize, u: f64) -> f64 {
        let (_, d1, _) = self.eval_in(i, u);
        d1[0].hypot(d1[1])
    }

    /// Arc length from `ua` to `ub` inside segment `i` (5-point Gauss-Legendre).
    fn arc_in(&self, i: usize, ua: f64, ub: f64) -> f64 {
        let (c, r) = (0.5 * (ua + ub), 0.5 * (ub - ua));
        GL_X.iter()
            .zip(GL_W.iter())
            .map(|(x, w)| w * self.speed_in(i, c + r * x))
            .sum::<f64>()
            * r
    }

    fn tabulate_arc(&mut self) -> Result<(), TrajectoryError> {
        let n = self.segments();
        let mut arc = Vec::with_capacity(n * ARC_SUBDIV + 1);
        arc.push(0.0);
        let mut total = 0.0;
        for i in 0..n {
            let (u0, u1) = (self.knots[i], self.knots[i + 1]);
            let h = u1 - u0;
            for j in 0..ARC_SUBDIV {
                let ua = u0 + h * j as f64 / ARC_SUBDIV as f64;
                let ub = u0 + h * (j + 1) as f64 / ARC_SUBDIV as f64;
                // A parameter speed far below the chord-length scale means a cusp.
                for frac in [0.0, 0.25, 0.5, 0.75] {
                    if self.speed_in(i, ua + frac * (ub - ua)) < 1e-3 {
                        return Err(TrajectoryError::Cusp { index: i });
                    }
                }
                total += self.arc_in(i, ua, ub);
                arc.push(total);
            }
        }
        self.arc = arc;
        Ok(())
    }

    /// Spline parameter at arc length `s` (in `[0, length]`), by Newton iteration.
    fn u_of_s(&self, s: f64) -> Result<f64, TrajectoryError> {
        let n_sub = self.arc.len() - 1;
        let j = self
            .arc
            .partition_point(|&a| a <= s)
            .saturating_sub(1)
            .min(n_sub - 1);
        let i = j / ARC_SUBDIV;
        let k = j % ARC_SUBDIV;
        let (u0, u1) = (self.knots[i], self.knots[i + 1]);
        let h = u1 - u0;
        let ua = u0 + h * k as f64 / ARC_SUBDIV as f64;
        let ub = u0 + h * (k + 1) as f64 / ARC_SUBDIV as f64;
        let (sa, sb) = (self.arc[j], self.arc[j + 1]);
        let mut u = if sb > sa {
            ua + (ub - ua) * (s - sa) / (sb - sa)
        } else {
            ua
        };
        for _ in 0..50 {
            let f = sa + self.arc_in(i, ua, u) - s;
            if f.abs() < 1e-13 {
                return Ok(u);
            }
            u = (u - f / self.speed_in(i, u)).clamp(ua, ub);
        }
        let f = sa + self.arc_in(i, ua, u) - s;
        if f.abs() < 1e-10 {
            Ok(u)
        } else {
            Err(TrajectoryError::ArcLength { s_m: s })
        }
    }
}

/// Second derivatives at the knots: natural (or clamped start) for open paths,
/// periodic for closed ones. `pts` has `h.len() + 1` entries.
fn solve_second_derivatives(
    pts: &[[f64; 2]],
    h: &[f64],
    start_yaw: Option<f64>,
    closed: bool,
) -> Vec<[f64; 2]> {
    let nseg = h.len();
    // Unknowns: M_0..M_nseg (open) or M_0..M_{nseg-1} (closed, M_nseg = M_0).
    let n = if closed { nseg } else { nseg + 1 };
    let mut a = vec![0.0; n * n];
    let mut rhs = vec![[0.0; 2]; n];
    let slope = |i: usize, k: usize| (pts[i + 1][k] - pts[i][k]) / h[i];
    if closed {
        for i in 0..n {
            let im = (i + n - 1) % n;
            a[i * n + im] += h[im];
            a[i * n + i] += 2.0 * (h[im] + h[i]);
            a[i * n + (i + 1) % n] += h[i];
            rhs[i] = [0, 1].map(|k| 6.0 * (slope(i, k) - slope(im, k)));
        }
    } else {
        match start_yaw {
            Some(yaw) => {
                let d0 = [yaw.cos(), yaw.sin()];
                a[0] = 2.0 * h[0];
                a[1] = h[0];
                rhs[0] = [0, 1].map(|k| 6.0 * (slope(0, k) - d0[k]));
            }
            None => a[0] = 1.0,
        }
        for i in 1..nseg {
            a[i * n + i - 1] = h[i - 1];
            a[i * n + i] = 2.0 * (h[i - 1] + h[i]);
            a[i * n + i + 1] = h[i];
            rhs[i] = [0, 1].map(|k| 6.0 * (slope(i, k) - slope(i - 1, k)));
        }
        a[nseg * n + nseg] = 1.0;
    }
    let mut m = gauss_solve(&mut a, &mut rhs, n);
    if closed {
        let first = m.first().copied().unwrap_or([0.0; 2]);
        m.push(first);
    }
    m
}

/// Gaussian elimination with partial pivoting on a dense `n x n` system with
/// two right-hand sides. The spline matrices are strictly diagonally dominant,
/// so no pivot vanishes.
fn gauss_solve(a: &mut [f64], b: &mut [[f64; 2]], n: usize) -> Vec<[f64; 2]> {
    for col in 0..n {
        let piv = (col..n)
            .max_by(|&r1, &r2| a[r1 * n + col].abs().total_cmp(&a[r2 * n + col].abs()))
            .unwrap_or(col);
        if piv != col {
            for c in 0..n {
                a.swap(col * n + c, piv * n + c);
            }
            b.swap(col, piv);
        }
        let d = a[col * n + col];
        for r in col + 1..n {
            let f = a[r * n + col] / d;
            if f != 0.0 {
                for c in col..n {
                    a[r * n + c] -= f * a[col * n + c];
                }
                let bc = b[col];
                for (x, y) in b[r].iter_mut().zip(bc) {
                    *x -= f * y;
                }
            }
        }
    }
    let mut x = vec![[0.0; 2]; n];
    for r in (0..n).rev() {
        for k in 0..2 {
            let mut s = b[r][k];
            for c in r + 1..n {
                s -= a[r * n + c] * x[c][k];
            }
            x[r][k] = s / a[r * n + r];
        }
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wp(points: Vec<[f64; 2]>, speed: f64, closed: bool) -> Trajectory {
        Trajectory::Waypoints(WaypointPath {
            points,
            speed_mps: speed,
            closed,
            ..WaypointPath::default()
        })
    }

    #[test]
    fn straight_line_has_exact_length_and_profile() {
        let m = TrajectoryModel::new(&wp(vec![[0.0, 0.0], [4.0, 0.0]], 0.5, false), 1.0).unwrap();
        assert!((m.path_length_m().unwrap() - 4.0).abs() < 1e-12);
        // Ramp of 2 s covers 0.5 m; cruise 3 m takes 6 s; ramp down 2 s: stop at t = 10 s.
        let k = m.eval(1.0).unwrap();
        // Mid-ramp (tau = T/2 = 1): s = v (T/8 - T/(2 pi^2)), v/2, a = 2 v / T.
        let pi2 = core::f64::consts::PI * core::f64::consts::PI;
        let s1 = 0.5 * (0.25 - 1.0 / pi2);
        assert!((k.pos_m[0] - s1).abs() < 1e-12, "{}", k.pos_m[0]);
        assert!((k.vel_mps[0] - 0.25).abs() < 1e-12);
        assert!((k.accel_mps2[0] - 0.5).abs() < 1e-12);
        // End of the ramp: s = v T / 2, cruise speed, no acceleration.
        let k = m.eval(2.0).unwrap();
        assert!((k.pos_m[0] - 0.5).abs() < 1e-12);
        assert!((k.vel_mps[0] - 0.5).abs() < 1e-12);
        assert!(k.accel_mps2[0].abs() < 1e-12);
        assert_eq!(k.pos_m[2], 1.0);
        let k = m.eval(5.0).unwrap();
        assert!((k.pos_m[0] - (0.5 + 0.5 * 3.0)).abs() < 1e-12);
        let k = m.eval(10.0).unwrap();
        assert!((k.pos_m[0] - 4.0).abs() < 1e-12);
        assert_eq!(k.vel_mps[0], 0.0);
        let k = m.eval(9.0).unwrap();
        assert!((k.pos_m[0] - (4.0 - s1)).abs() < 1e-12);
        assert!((k.vel_mps[0] - 0.25).abs() < 1e-12);
        assert!((k.accel_mps2[0] + 0.5).abs() < 1e-12);
    }

    #[test]
    fn closed_spline_is_periodic_and_passes_through_its_points() {
        let pts = vec![[0.0, 0.0], [3.0, 0.0], [3.0, 3.0], [0.0, 3.0]];
        let s = Spline::new(&pts, None, true).unwrap();
        for (i, p) in pts.iter().enumerate() {
            let (q, _, _) = s.eval(s.knots[i]);
            assert!((q[0] - p[0]).abs() < 1e-12 && (q[1] - p[1]).abs() < 1e-12);
        }
        let (p0, d0, dd0) = s.eval(0.0);
        let (p1, d1, dd1) = s.eval(*s.knots.last().unwrap());
        for k in 0..2 {
            assert!((p0[k] - p1[k]).abs() < 1e-12);
            assert!((d0[k] - d1[k]).abs() < 1e-12);
            assert!((dd0[k] - dd1[k]).abs() < 1e-12);
        }
        // The periodic spline through a 3 m square's corners bulges outwards:
        // longer than the square (12 m), shorter than the circle through the
        // corners (2 pi * 3 / sqrt 2 = 13.33 m).
        assert!(s.length() > 12.0 && s.length() < 13.4, "{}", s.length());
    }

    #[test]
    fn arc_length_inversion_round_trips() {
        let pts = vec![[3.0, 4.0], [2.0, 2.0], [4.0, 1.0], [5.0, 3.0]];
        let s = Spline::new(&pts, None, false).unwrap();
        for q in 0..=100 {
            let target = s.length() * q as f64 / 100.0;
            let u = s.u_of_s(target).unwrap();
            let n = s.segments();
            let i = s
                .knots
                .partition_point(|&k| k <= u)
                .saturating_sub(1)
                .min(n - 1);
            let j = s
                .arc
                .partition_point(|&a| a <= target)
                .saturating_sub(1)
                .min(s.arc.len() - 2);
            let back = s.arc[j]
                + s.arc_in(
                    i,
                    s.knots[i]
                        + (s.knots[i + 1] - s.knots[i]) * (j % ARC_SUBDIV) as f64
                            / ARC_SUBDIV as f64,
                    u,
                );
            assert!((back - target).abs() < 1e-11, "{back} {target}");
        }
    }

    #[test]
    fn bad_paths_are_refused() {
        assert_eq!(
            TrajectoryModel::new(&wp(vec![[0.0, 0.0]], 0.5, false), 0.0),
            Err(TrajectoryError::TooFewPoints { need: 2, got: 1 })
        );
        assert_eq!(
            TrajectoryModel::new(&wp(vec![[0.0, 0.0], [0.0, 0.0]], 0.5, false), 0.0),
            Err(TrajectoryError::RepeatedPoint { index: 1 })
        );
        assert!(matches!(
            TrajectoryModel::new(&wp(vec![[0.0, 0.0], [0.5, 0.0]], 0.5, false), 0.0),
            Err(TrajectoryError::PathTooShort { .. })
        ));
        let l = Trajectory::Lissajous(LissajousPath {
            period_s: [10.0, 10.0],
            ..LissajousPath::default()
        });
        let m = TrajectoryModel::new(&l, 0.0).unwrap();
        assert_eq!(m.eval(2.5), Err(TrajectoryError::ZeroSpeed { t_s: 2.5 }));
    }

    #[test]
    fn wrap_pi_range() {
        assert!((wrap_pi(3.0 * core::f64::consts::PI) - core::f64::consts::PI).abs() < 1e-12);
        assert!((wrap_pi(-0.5) + 0.5).abs() < 1e-15);
    }
}
