//! Test support: a seeded RNG, quaternion helpers, a small strapdown INS
//! (independent of the filter) and the circling scenario among 8 anchors.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used)]

use insuwb_eskf::{quat_to_rot, Correction, Eskf};
use nalgebra::{Matrix3, Vector3};
use rand::{RngExt as _, SeedableRng as _};
use rand_distr::StandardNormal;
use rand_xoshiro::Xoshiro256StarStar;

pub const G_MPS2: f64 = 9.81;
/// UTIL's antenna lever arm (body, m).
pub const LEVER_M: [f64; 3] = [-0.01245, 0.00127, 0.0908];
/// Level attitude, `[w, x, y, z]`.
pub const LEVEL: [f64; 4] = [1.0, 0.0, 0.0, 0.0];
/// The specific force at hover, ENU, m/s^2.
pub const HOVER_FORCE: [f64; 3] = [0.0, 0.0, G_MPS2];
/// Four anchors at the corners of an 8 m square, alternately low and high.
pub const ANCHORS4: [[f64; 3]; 4] = [
    [-4.0, -4.0, 0.2],
    [4.0, -4.0, 3.0],
    [4.0, 4.0, 0.2],
    [-4.0, 4.0, 3.0],
];

/// Seeded random numbers: `rand_xoshiro`'s xoshiro256**, `rand`'s uniform
/// and `rand_distr`'s standard normal laws.
pub struct Rng(Xoshiro256StarStar);
impl Rng {
    pub fn new(seed: u64) -> Self {
        Self(Xoshiro256StarStar::seed_from_u64(seed))
    }
    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        self.0.random()
    }
    pub fn normal(&mut self) -> f64 {
        self.0.sample(StandardNormal)
    }
    pub fn normal3(&mut self, s: f64) -> Vector3<f64> {
        Vector3::new(self.normal() * s, self.normal() * s, self.normal() * s)
    }
}

pub type Quat = [f64; 4];

pub fn qmul(a: Quat, b: Quat) -> Quat {
    let [aw, ax, ay, az] = a;
    let [bw, bx, by, bz] = b;
    [
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ]
}

pub fn qnorm(q: Quat) -> Quat {
    let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    q.map(|x| x / n)
}

/// Exp of a rotation vector.
pub fn qexp(v: Vector3<f64>) -> Quat {
    let a = v.norm();
    if a < 1e-300 {
        return [1.0, 0.0, 0.0, 0.0];
    }
    let s = (0.5 * a).sin() / a;
    [(0.5 * a).cos(), v.x * s, v.y * s, v.z * s]
}

/// Log of a unit quaternion (rotation vector, shortest).
pub fn qlog(q: Quat) -> Vector3<f64> {
    let q = if q[0] < 0.0 { q.map(|x| -x) } else { q };
    let v = Vector3::new(q[1], q[2], q[3]);
    let s = v.norm();
    if s < 1e-300 {
        return Vector3::zeros();
    }
    v * (2.0 * s.atan2(q[0]) / s)
}

pub fn qconj(q: Quat) -> Quat {
    [q[0], -q[1], -q[2], -q[3]]
}

pub fn rot(q: Quat) -> Matrix3<f64> {
    quat_to_rot(q)
}

pub fn yaw_of(q: Quat) -> f64 {
    let r = rot(q);
    r[(1, 0)].atan2(r[(0, 0)])
}

pub fn wrap(a: f64) -> f64 {
    (a + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI) - std::f64::consts::PI
}

/// A strapdown INS state: position, velocity (ENU), attitude (body->ENU),
/// and the bias estimates it compensates (`f = a_m - b_a`, `w = w_m - b_g`).
#[derive(Debug, Clone, Copy)]
pub struct Ins {
    pub p: Vector3<f64>,
    pub v: Vector3<f64>,
    pub q: Quat,
    pub ba: Vector3<f64>,
    pub bg: Vector3<f64>,
}

/// What one strapdown step used: the attitude at mid-step and the specific
/// force in ENU (the filter's predict inputs).
#[derive(Debug, Clone, Copy)]
pub struct StepInputs {
    pub q_mid: Quat,
    pub f_nav: Vector3<f64>,
}

impl Ins {
    /// One step with IMU samples taken at mid-interval: attitude exact for a
    /// constant rate, velocity by the midpoint rule, position trapezoidal.
    pub fn step(&mut self, accel_m: Vector3<f64>, gyro_m: Vector3<f64>, dt: f64) -> StepInputs {
        let f_b = accel_m - self.ba;
        let w = gyro_m - self.bg;
        let q_mid = qnorm(qmul(self.q, qexp(w * (0.5 * dt))));
        let f_nav = rot(q_mid) * f_b;
        let v_new = self.v + (f_nav + Vector3::new(0.0, 0.0, -G_MPS2)) * dt;
        self.p += (self.v + v_new) * (0.5 * dt);
        self.v = v_new;
        self.q = qnorm(qmul(self.q, qexp(w * dt)));
        StepInputs { q_mid, f_nav }
    }

    /// Applies a filter correction (closed loop), per the message conventions.
    pub fn apply(&mut self, c: &Correction) {
        self.p -= Vector3::from(c.d_pos_m);
        self.v -= Vector3::from(c.d_vel_mps);
        self.q = qnorm(qmul(qexp(-Vector3::from(c.d_att_rad)), self.q));
        self.ba += Vector3::from(c.d_accel_bias_mps2);
        self.bg += Vector3::from(c.d_gyro_bias_rps);
    }

    /// The error state of this INS against `truth` (same conventions as the
    /// filter: INS minus truth for p, v, θ; truth minus INS for the biases).
    pub fn error_against(&self, truth: &Ins) -> [f64; 15] {
        let dp = self.p - truth.p;
        let dv = self.v - truth.v;
        // q_ins = Exp(δθ) ⊗ q_true.
        let dth = qlog(qmul(self.q, qconj(truth.q)));
        let dba = truth.ba - self.ba;
        let dbg = truth.bg - self.bg;
        let mut out = [0.0; 15];
        for i in 0..3 {
            out[i] = dp[i];
            out[3 + i] = dv[i];
            out[6 + i] = dth[i];
            out[9 + i] = dba[i];
            out[12 + i] = dbg[i];
        }
        out
    }
}

/// Eight anchors at the corners of a 8 x 8 x 2.8 m room (UTIL-like).
pub fn anchors() -> [[f64; 3]; 8] {
    [
        [-4.0, -4.0, 0.2],
        [-4.0, 4.0, 2.9],
        [4.0, 4.0, 0.2],
        [4.0, -4.0, 3.0],
        [-4.0, -4.0, 3.0],
        [4.0, -4.0, 0.2],
        [4.0, 4.0, 3.1],
        [-4.0, 4.0, 0.2],
    ]
}

pub fn dist(a: &Vector3<f64>, b: &[f64; 3]) -> f64 {
    (a - Vector3::from(*b)).norm()
}

/// The true TDOA `|p_ant - b| - |p_ant - a|` of a state.
pub fn true_tdoa(truth: &Ins, a: &[f64; 3], b: &[f64; 3]) -> f64 {
    let p_ant = truth.p + rot(truth.q) * Vector3::from(LEVER_M);
    dist(&p_ant, b) - dist(&p_ant, a)
}

/// Truth of the circling scenario: radius 1.5 m about the origin, period
/// 6 s (1.57 m/s, 1.64 m/s^2 centripetal), height 1.5 m with a 0.2 m
/// vertical oscillation; the body stays level and, as a quadrotor holding
/// its heading, keeps a yaw of 0.5 rad with a slow +-0.3 rad oscillation.
/// (A body that yaws with the track sees a constant body-frame centripetal
/// force, which makes yaw and the body-x accelerometer bias inseparable.)
pub struct Circle {
    pub radius_m: f64,
    pub omega_rps: f64,
}

impl Default for Circle {
    fn default() -> Self {
        Self {
            radius_m: 1.5,
            omega_rps: 2.0 * std::f64::consts::PI / 6.0,
        }
    }
}

impl Circle {
    pub fn pos(&self, t: f64) -> Vector3<f64> {
        let a = self.omega_rps * t;
        Vector3::new(
            self.radius_m * a.cos(),
            self.radius_m * a.sin(),
            1.5 + 0.2 * (0.5 * t).sin(),
        )
    }
    pub fn vel(&self, t: f64) -> Vector3<f64> {
        let (w, a) = (self.omega_rps, self.omega_rps * t);
        Vector3::new(
            -self.radius_m * w * a.sin(),
            self.radius_m * w * a.cos(),
            0.1 * (0.5 * t).cos(),
        )
    }
    pub fn acc(&self, t: f64) -> Vector3<f64> {
        let (w, a) = (self.omega_rps, self.omega_rps * t);
        Vector3::new(
            -self.radius_m * w * w * a.cos(),
            -self.radius_m * w * w * a.sin(),
            -0.05 * (0.5 * t).sin(),
        )
    }
    pub fn yaw(&self, t: f64) -> f64 {
        0.5 + 0.3 * (0.5 * t).sin()
    }
    pub fn quat(&self, t: f64) -> Quat {
        qexp(Vector3::new(0.0, 0.0, self.yaw(t)))
    }
    /// Exact IMU samples for the interval `[t, t + dt]`: specific force at
    /// mid-interval and the mean body rate (exact for the strapdown's
    /// attitude update, the rotation being about a fixed axis).
    pub fn imu(&self, t: f64, dt: f64) -> (Vector3<f64>, Vector3<f64>) {
        let tm = t + 0.5 * dt;
        let r = rot(self.quat(tm));
        let f_b = r.transpose() * (self.acc(tm) + Vector3::new(0.0, 0.0, G_MPS2));
        let rate = (self.yaw(t + dt) - self.yaw(t)) / dt;
        (f_b, Vector3::new(0.0, 0.0, rate))
    }
    pub fn truth(&self, t: f64) -> Ins {
        Ins {
            p: self.pos(t),
            v: self.vel(t),
            q: self.quat(t),
            ba: Vector3::zeros(),
            bg: Vector3::zeros(),
        }
    }
}

/// Checks that `P` is finite, exactly symmetric and positive definite.
pub fn assert_spd(f: &Eskf, when: &str) {
    let p = f.covariance();
    assert!(p.iter().all(|v| v.is_finite()), "P not finite at {when}");
    assert_eq!(*p, p.transpose(), "P not symmetric at {when}");
    assert!(p.cholesky().is_some(), "P not positive definite at {when}");
}
