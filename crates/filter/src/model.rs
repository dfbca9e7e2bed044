//! The paper's 14-state error model: the transition `F` (eq. 10, erratum 2
//! fixed, optional heading coupling of erratum 3), the process noise `Q`
//! (eq. 11, erratum 5), the measurement matrix `H = [I4 | 0]` (eq. 14) and the
//! configuration they are built from.
//!
//! State (0-based): `0 dPe, 1 dPn, 2 dVe, 3 dVn, 4 dtheta, 5..8 AR(3) block of
//! d a_e (k, k-1, k-2), 8..11 of d a_n, 11..14 of d omega`. Errors are "INS
//! minus truth" for position, velocity and heading; the `-T` entries of `F`
//! define `d a = a_true - a_meas` (erratum 4), so a caller compensates a
//! measured acceleration as `a_meas + d_a_hat`.
//!
//! # Time step and the AR blocks
//!
//! The AR(3) recursions (eqs. 4-8) are indexed by sensor sample, not by time:
//! one application of a companion block is one step at [`ModelConfig::ar_rate_hz`].
//! [`PaperModel::transition`] is therefore the transition of exactly one AR
//! step (its `dt_s` only scales the kinematic entries and the continuous
//! noise densities). A filter that predicts over an interval `dt_s` splits it
//! with [`PaperModel::steps`] into `n = round(dt_s * ar_rate_hz)` equal
//! sub-steps (erratum 6: predict at the IMU rate, where `n = 1`); an interval
//! shorter than half an AR step, or longer than
//! [`ModelConfig::max_steps_per_predict`] steps, is refused with an error.

use nalgebra::{SMatrix, SVector};
use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Number of error states of the paper's model.
pub const N_STATES: usize = 14;
/// Number of measurement components (`[dPe, dPn, dVe, dVn]`).
pub const N_MEAS: usize = 4;

/// A 14 x 14 matrix (covariances, dense transitions).
pub type Mat14 = SMatrix<f64, N_STATES, N_STATES>;
/// A 14-vector (error states).
pub type Vec14 = SVector<f64, N_STATES>;
/// A 4 x 4 matrix (measurement covariances).
pub type Mat4 = SMatrix<f64, N_MEAS, N_MEAS>;

/// Indices of the error states.
pub mod idx {
    /// East position error, m.
    pub const PE: usize = 0;
    /// North position error, m.
    pub const PN: usize = 1;
    /// East velocity error, m/s.
    pub const VE: usize = 2;
    /// North velocity error, m/s.
    pub const VN: usize = 3;
    /// Heading error, rad.
    pub const THETA: usize = 4;
    /// First state of the AR(3) block of the east acceleration error (m/s^2).
    pub const AR_AE: usize = 5;
    /// First state of the AR(3) block of the north acceleration error (m/s^2).
    pub const AR_AN: usize = 8;
    /// First state of the AR(3) block of the yaw-rate error (rad/s).
    pub const AR_W: usize = 11;
}

/// Which transition matrix to build.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ModelForm {
    /// `F` as printed in eq. 10, with erratum 2 fixed (row 5 is `-m1 -m2 -m3`).
    /// Heading and gyro states are unobservable with `H = [I4 | 0]`.
    Paper,
    /// `Paper` plus the heading coupling of erratum 3:
    /// `F[2,4] = -a_n * T`, `F[3,4] = +a_e * T` (ENU, yaw counter-clockwise from east).
    #[default]
    Physics,
}

/// AR(3) model of one sensor-error axis (eq. 4):
/// `a_k = -m1 a_{k-1} - m2 a_{k-2} - m3 a_{k-3} + w_k`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArConfig {
    /// Coefficients `[m1, m2, m3]` in the paper's sign convention (eq. 4; from
    /// Yule-Walker on a static record, `m = -phi`). Must describe a stable process.
    pub m: [f64; 3],
    /// Variance of the driving noise `w_k` per AR step at `ar_rate_hz`
    /// ((m/s^2)^2 for accelerometer axes, (rad/s)^2 for the gyro; Yule-Walker
    /// `sigma_w^2 = r0 - phi . r`, erratum 5).
    pub noise_var: f64,
}

impl ArConfig {
    const fn with_var(noise_var: f64) -> Self {
        // Erratum 19: a typical Yule-Walker fit of a MEMS static record.
        Self {
            m: [-0.004, -0.015, -0.003],
            noise_var,
        }
    }
}

/// Optional random-walk bias handling (erratum 19), fitted into the 14-state
/// layout: each AR block's recursion becomes the unit-root AR
/// `b_k = b_{k-1} + w_k` (first row `[1, 0, 0]`), so the block's first state
/// carries a random-walk bias and the lag states hold its previous values.
/// The AR coefficients and AR noise variances are then not used; white sensor
/// noise must be carried by `q_vel_m2_per_s3` / `q_theta_rad2_per_s`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BiasRandomWalk {
    /// Accelerometer bias random-walk variance per AR step, (m/s^2)^2
    /// (e.g. `(1e-4 g)^2 / ar_rate_hz` for the paper's simulation, section 3.4).
    pub accel_var_m2_per_s4: f64,
    /// Gyro bias random-walk variance per AR step, (rad/s)^2.
    pub gyro_var_rad2_per_s2: f64,
}

/// Configuration of the paper's error model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ModelConfig {
    /// Transition form (erratum 3). Default `physics`.
    pub form: ModelForm,
    /// AR(3) model of the east acceleration error. Default: erratum 19's typical
    /// fit `m = [-0.004, -0.015, -0.003]`, `noise_var = 1e-4 (m/s^2)^2`
    /// (0.01 m/s^2 per 100 Hz sample, the order of the paper's MEMS unit, Table 2).
    pub ar_accel_e: ArConfig,
    /// AR(3) model of the north acceleration error. Default as `ar_accel_e`.
    pub ar_accel_n: ArConfig,
    /// AR(3) model of the yaw-rate error. Default `m` as `ar_accel_e`,
    /// `noise_var = 2.115e-8 (rad/s)^2`: the paper's ARW of 0.05 deg/sqrt(h)
    /// (section 3.4) sampled at 100 Hz.
    pub ar_gyro: ArConfig,
    /// Rate at which the AR coefficients were fitted (one AR step), Hz.
    /// Default 100 (the paper's IMU rate, section 4.2).
    pub ar_rate_hz: f64,
    /// Position process noise density, m^2/s (erratum 5: small). Default 1e-4.
    pub q_pos_m2_per_s: f64,
    /// Velocity random walk density, m^2/s^3 (erratum 5). Default 9.6e-7:
    /// the paper's accelerometer random walk 1e-4 g read as 1e-4 g/sqrt(Hz).
    pub q_vel_m2_per_s3: f64,
    /// Heading noise density, rad^2/s. Default 2.115e-10: the paper's ARW
    /// 0.05 deg/sqrt(h) squared (section 3.4).
    pub q_theta_rad2_per_s: f64,
    /// Optional random-walk bias handling (erratum 19); `None` (default) keeps
    /// the AR(3) blocks.
    pub bias_random_walk: Option<BiasRandomWalk>,
    /// Most AR steps one predict may span (a longer interval is refused).
    /// Default 20 (0.2 s at 100 Hz, enough for the paper's 10 Hz filter).
    pub max_steps_per_predict: u32,
}

impl Default for ModelConfig {
    fn default() -> Self {
        Self {
            form: ModelForm::Physics,
            ar_accel_e: ArConfig::with_var(1e-4),
            ar_accel_n: ArConfig::with_var(1e-4),
            ar_gyro: ArConfig::with_var(2.115e-8),
            ar_rate_hz: 100.0,
            q_pos_m2_per_s: 1e-4,
            q_vel_m2_per_s3: 9.6e-7,
            q_theta_rad2_per_s: 2.115e-10,
            bias_random_walk: None,
            max_steps_per_predict: 20,
        }
    }
}

/// Why a [`ModelConfig`] was refused.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ModelConfigError {
    /// A value that must be finite and positive is not.
    #[error("model.{key} must be finite and > 0, got {value}")]
    NotPositive {
        /// Offending key.
        key: &'static str,
        /// Its value.
        value: f64,
    },
    /// A value that must be finite and non-negative is not.
    #[error("model.{key} must be finite and >= 0, got {value}")]
    Negative {
        /// Offending key.
        key: &'static str,
        /// Its value.
        value: f64,
    },
    /// AR coefficients that are not finite or describe an unstable process.
    #[error(
        "model.{key}.m = {m:?} is not a stable AR(3) model (non-finite, or a root on or outside the unit circle)"
    )]
    UnstableAr {
        /// Offending key.
        key: &'static str,
        /// Its coefficients.
        m: [f64; 3],
    },
    /// `max_steps_per_predict` is zero.
    #[error("model.max_steps_per_predict must be >= 1, got {value}")]
    ZeroMaxSteps {
        /// Its value.
        value: u32,
    },
}

fn positive(key: &'static str, value: f64) -> Result<(), ModelConfigError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(ModelConfigError::NotPositive { key, value })
    }
}

fn non_negative(key: &'static str, value: f64) -> Result<(), ModelConfigError> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(ModelConfigError::Negative { key, value })
    }
}

/// Whether `z^3 + m1 z^2 + m2 z + m3` has all roots strictly inside the unit
/// circle (Jury's test for a cubic), i.e. the AR(3) process of eq. 4 is stable.
#[must_use]
pub fn ar3_is_stable(m: &[f64; 3]) -> bool {
    let [a2, a1, a0] = *m;
    if !(a2.is_finite() && a1.is_finite() && a0.is_finite()) {
        return false;
    }
    let p_plus = 1.0 + a2 + a1 + a0; // P(1) > 0
    let p_minus = -1.0 + a2 - a1 + a0; // P(-1) < 0 (odd degree)
    p_plus > 0.0 && p_minus < 0.0 && a0.abs() < 1.0 && (1.0 - a0 * a0) > (a0 * a2 - a1).abs()
}

impl ModelConfig {
    /// Checks every key; the error names the first offending one.
    ///
    /// # Errors
    /// [`ModelConfigError`] naming the key and its value.
    pub fn validate(&self) -> Result<(), ModelConfigError> {
        positive("ar_rate_hz", self.ar_rate_hz)?;
        non_negative("q_pos_m2_per_s", self.q_pos_m2_per_s)?;
        non_negative("q_vel_m2_per_s3", self.q_vel_m2_per_s3)?;
        non_negative("q_theta_rad2_per_s", self.q_theta_rad2_per_s)?;
        if self.max_steps_per_predict == 0 {
            return Err(ModelConfigError::ZeroMaxSteps {
                value: self.max_steps_per_predict,
            });
        }
        match &self.bias_random_walk {
            Some(rw) => {
                non_negative(
                    "bias_random_walk.accel_var_m2_per_s4",
                    rw.accel_var_m2_per_s4,
                )?;
                non_negative(
                    "bias_random_walk.gyro_var_rad2_per_s2",
                    rw.gyro_var_rad2_per_s2,
                )?;
            }
            None => {
                for (key, var_key, ar) in [
                    ("ar_accel_e", "ar_accel_e.noise_var", &self.ar_accel_e),
                    ("ar_accel_n", "ar_accel_n.noise_var", &self.ar_accel_n),
                    ("ar_gyro", "ar_gyro.noise_var", &self.ar_gyro),
                ] {
                    if !ar3_is_stable(&ar.m) {
                        return Err(ModelConfigError::UnstableAr { key, m: ar.m });
                    }
                    non_negative(var_key, ar.noise_var)?;
                }
            }
        }
        Ok(())
    }
}

/// The transition `F` of one AR step in sparse form: the identity plus
/// `F[0,2] = F[1,3] = T`, `F[2,5] = F[3,8] = F[4,11] = -T`, the heading
/// coupling `F[2,4]`, `F[3,4]`, and three companion blocks (rows and columns
/// 5..8, 8..11, 11..14) with first row `ar_rows[b]` and a shifted identity
/// below. [`dense`] expands it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Transition14 {
    /// Step length `T`, s.
    pub dt_s: f64,
    /// `F[2,4]` (velocity east from heading): `-a_n * T` in the physics form, 0 in the paper form.
    pub f_ve_theta: f64,
    /// `F[3,4]` (velocity north from heading): `+a_e * T` in the physics form, 0 in the paper form.
    pub f_vn_theta: f64,
    /// First rows `[-m1, -m2, -m3]` of the companion blocks of `d a_e`, `d a_n`, `d omega`.
    pub ar_rows: [[f64; 3]; 3],
}

impl Transition14 {
    /// The 14 combinations `F v` for a vector given by an accessor; shared by
    /// the vector and matrix products so they use the same arithmetic.
    #[inline(always)]
    pub(crate) fn rows(&self, c: impl Fn(usize) -> f64) -> [f64; N_STATES] {
        let t = self.dt_s;
        let [ra, rn, rw] = self.ar_rows;
        [
            c(0) + t * c(2),
            c(1) + t * c(3),
            c(2) + self.f_ve_theta * c(4) - t * c(5),
            c(3) + self.f_vn_theta * c(4) - t * c(8),
            c(4) - t * c(11),
            ra[0] * c(5) + ra[1] * c(6) + ra[2] * c(7),
            c(5),
            c(6),
            rn[0] * c(8) + rn[1] * c(9) + rn[2] * c(10),
            c(8),
            c(9),
            rw[0] * c(11) + rw[1] * c(12) + rw[2] * c(13),
            c(11),
            c(12),
        ]
    }

    /// `F x` (sparse).
    #[must_use]
    pub fn apply(&self, x: &Vec14) -> Vec14 {
        Vec14::from(self.rows(|k| x[k]))
    }
}

/// Expands a sparse transition into the dense 14 x 14 `F`.
#[must_use]
pub fn dense(t: &Transition14) -> Mat14 {
    let mut f = Mat14::identity();
    f[(0, 2)] = t.dt_s;
    f[(1, 3)] = t.dt_s;
    f[(2, 5)] = -t.dt_s;
    f[(3, 8)] = -t.dt_s;
    f[(4, 11)] = -t.dt_s;
    f[(2, 4)] = t.f_ve_theta;
    f[(3, 4)] = t.f_vn_theta;
    for (b, row) in t.ar_rows.iter().enumerate() {
        let o = idx::AR_AE + 3 * b;
        for (j, &v) in row.iter().enumerate() {
            f[(o, o + j)] = v;
        }
        f[(o + 1, o + 1)] = 0.0;
        f[(o + 2, o + 2)] = 0.0;
        f[(o + 1, o)] = 1.0;
        f[(o + 2, o + 1)] = 1.0;
    }
    f
}

/// The measurement matrix `H = [I4 | 0]` of eq. 14 (rows `dPe, dPn, dVe, dVn`).
#[must_use]
pub fn h_matrix() -> SMatrix<f64, N_MEAS, N_STATES> {
    SMatrix::<f64, N_MEAS, N_STATES>::identity()
}

/// The position-only measurement matrix `[I2 | 0]` (rows `dPe, dPn`).
#[must_use]
pub fn h_matrix_pos() -> SMatrix<f64, 2, N_STATES> {
    SMatrix::<f64, 2, N_STATES>::identity()
}

/// How one predict interval is split into AR steps (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PredictSteps {
    /// Number of AR steps, >= 1.
    pub n: u32,
    /// Length of each step, s (`dt_s / n`).
    pub sub_dt_s: f64,
}

/// Why a predict interval was refused.
#[derive(Debug, Clone, Copy, PartialEq, Error)]
pub enum StepError {
    /// The interval is not finite and positive.
    #[error("predict interval dt_s must be finite and > 0, got {dt_s}")]
    InvalidDt {
        /// The interval, s.
        dt_s: f64,
    },
    /// The interval is shorter than half an AR step.
    #[error("predict interval {dt_s} s is shorter than half an AR step ({ar_step_s} s)")]
    BelowArStep {
        /// The interval, s.
        dt_s: f64,
        /// One AR step, s.
        ar_step_s: f64,
    },
    /// The interval spans more AR steps than allowed.
    #[error("predict interval {dt_s} s spans {steps} AR steps, more than model.max_steps_per_predict = {max}")]
    TooManySteps {
        /// The interval, s.
        dt_s: f64,
        /// AR steps it spans.
        steps: f64,
        /// The configured maximum.
        max: u32,
    },
}

/// The paper's 14-state error model built from a validated [`ModelConfig`].
#[derive(Debug, Clone, PartialEq)]
pub struct PaperModel {
    cfg: ModelConfig,
    ar_rows: [[f64; 3]; 3],
    ar_var: [f64; 3],
}

impl PaperModel {
    /// Validates `cfg` and builds the model.
    ///
    /// # Errors
    /// [`ModelConfigError`] when `cfg` does not validate.
    pub fn new(cfg: ModelConfig) -> Result<Self, ModelConfigError> {
        cfg.validate()?;
        let (ar_rows, ar_var) = match &cfg.bias_random_walk {
            Some(rw) => (
                [[1.0, 0.0, 0.0]; 3],
                [
                    rw.accel_var_m2_per_s4,
                    rw.accel_var_m2_per_s4,
                    rw.gyro_var_rad2_per_s2,
                ],
            ),
            None => {
                let row = |a: &ArConfig| [-a.m[0], -a.m[1], -a.m[2]];
                (
                    [
                        row(&cfg.ar_accel_e),
                        row(&cfg.ar_accel_n),
                        row(&cfg.ar_gyro),
                    ],
                    [
                        cfg.ar_accel_e.noise_var,
                        cfg.ar_accel_n.noise_var,
                        cfg.ar_gyro.noise_var,
                    ],
                )
            }
        };
        Ok(Self {
            cfg,
            ar_rows,
            ar_var,
        })
    }

    /// The configuration the model was built from.
    #[must_use]
    pub fn config(&self) -> &ModelConfig {
        &self.cfg
    }

    /// Length of one AR step, s (`1 / ar_rate_hz`).
    #[must_use]
    pub fn ar_step_s(&self) -> f64 {
        1.0 / self.cfg.ar_rate_hz
    }

    /// Splits a predict interval into AR steps: `n = round(dt_s * ar_rate_hz)`.
    ///
    /// # Errors
    /// [`StepError`] when `dt_s` is not finite and positive, is shorter than
    /// half an AR step, or spans more than `max_steps_per_predict` steps.
    pub fn steps(&self, dt_s: f64) -> Result<PredictSteps, StepError> {
        if !(dt_s.is_finite() && dt_s > 0.0) {
            return Err(StepError::InvalidDt { dt_s });
        }
        let steps = (dt_s * self.cfg.ar_rate_hz).round();
        if steps < 1.0 {
            return Err(StepError::BelowArStep {
                dt_s,
                ar_step_s: self.ar_step_s(),
            });
        }
        if steps > f64::from(self.cfg.max_steps_per_predict) {
            return Err(StepError::TooManySteps {
                dt_s,
                steps,
                max: self.cfg.max_steps_per_predict,
            });
        }
        // In range 1..=max_steps_per_predict (a u32), so the conversion is exact.
        let n = self.cfg.max_steps_per_predict.min(steps as u32).max(1);
        Ok(PredictSteps {
            n,
            sub_dt_s: dt_s / f64::from(n),
        })
    }

    /// The transition of one AR step of length `dt_s` (eq. 10, erratum 2;
    /// plus erratum 3's coupling in the physics form) at the ENU kinematic
    /// acceleration `a_e_mps2`, `a_n_mps2`.
    #[must_use]
    pub fn transition(&self, dt_s: f64, a_e_mps2: f64, a_n_mps2: f64) -> Transition14 {
        let (f_ve_theta, f_vn_theta) = match self.cfg.form {
            ModelForm::Paper => (0.0, 0.0),
            ModelForm::Physics => (-a_n_mps2 * dt_s, a_e_mps2 * dt_s),
        };
        Transition14 {
            dt_s,
            f_ve_theta,
            f_vn_theta,
            ar_rows: self.ar_rows,
        }
    }

    /// Diagonal of `Q` for one AR step of length `dt_s` (eq. 11): densities
    /// times `dt_s` on rows 0..5, the AR driving variances on rows 5, 8, 11,
    /// zero elsewhere.
    #[must_use]
    pub fn process_noise_diag(&self, dt_s: f64) -> Vec14 {
        let c = &self.cfg;
        let mut q = Vec14::zeros();
        q[idx::PE] = c.q_pos_m2_per_s * dt_s;
        q[idx::PN] = c.q_pos_m2_per_s * dt_s;
        q[idx::VE] = c.q_vel_m2_per_s3 * dt_s;
        q[idx::VN] = c.q_vel_m2_per_s3 * dt_s;
        q[idx::THETA] = c.q_theta_rad2_per_s * dt_s;
        q[idx::AR_AE] = self.ar_var[0];
        q[idx::AR_AN] = self.ar_var[1];
        q[idx::AR_W] = self.ar_var[2];
        q
    }

    /// `Q` for one AR step of length `dt_s` as a dense (diagonal) matrix.
    #[must_use]
    pub fn process_noise(&self, dt_s: f64) -> Mat14 {
        Mat14::from_diagonal(&self.process_noise_diag(dt_s))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(form: ModelForm) -> ModelConfig {
        ModelConfig {
            form,
            ar_accel_e: ArConfig {
                m: [0.1, 0.2, 0.3],
                noise_var: 1e-3,
            },
            ar_accel_n: ArConfig {
                m: [0.4, 0.5, 0.6],
                noise_var: 2e-3,
            },
            ar_gyro: ArConfig {
                m: [0.7, 0.8, 0.9],
                noise_var: 3e-6,
            },
            ar_rate_hz: 100.0,
            q_pos_m2_per_s: 0.5,
            q_vel_m2_per_s3: 0.25,
            q_theta_rad2_per_s: 0.125,
            bias_random_walk: None,
            max_steps_per_predict: 20,
        }
    }

    /// F of eq. 10 written out by hand for T = 0.01, with row 5 = -m_e (erratum 2).
    #[rustfmt::skip]
    fn paper_f_by_hand() -> [[f64; 14]; 14] {
        let t = 0.01;
        [
            [1.,0.,t ,0.,0.,  0.,  0.,  0.,  0.,  0.,  0.,  0.,  0.,  0.],
            [0.,1.,0.,t ,0.,  0.,  0.,  0.,  0.,  0.,  0.,  0.,  0.,  0.],
            [0.,0.,1.,0.,0., -t ,  0.,  0.,  0.,  0.,  0.,  0.,  0.,  0.],
            [0.,0.,0.,1.,0.,  0.,  0.,  0., -t ,  0.,  0.,  0.,  0.,  0.],
            [0.,0.,0.,0.,1.,  0.,  0.,  0.,  0.,  0.,  0., -t ,  0.,  0.],
            [0.,0.,0.,0.,0., -0.1,-0.2,-0.3, 0.,  0.,  0.,  0.,  0.,  0.],
            [0.,0.,0.,0.,0.,  1.,  0.,  0.,  0.,  0.,  0.,  0.,  0.,  0.],
            [0.,0.,0.,0.,0.,  0.,  1.,  0.,  0.,  0.,  0.,  0.,  0.,  0.],
            [0.,0.,0.,0.,0.,  0.,  0.,  0., -0.4,-0.5,-0.6, 0.,  0.,  0.],
            [0.,0.,0.,0.,0.,  0.,  0.,  0.,  1.,  0.,  0.,  0.,  0.,  0.],
            [0.,0.,0.,0.,0.,  0.,  0.,  0.,  0.,  1.,  0.,  0.,  0.,  0.],
            [0.,0.,0.,0.,0.,  0.,  0.,  0.,  0.,  0.,  0., -0.7,-0.8,-0.9],
            [0.,0.,0.,0.,0.,  0.,  0.,  0.,  0.,  0.,  0.,  1.,  0.,  0.],
            [0.,0.,0.,0.,0.,  0.,  0.,  0.,  0.,  0.,  0.,  0.,  1.,  0.],
        ]
    }

    fn assert_matrix_eq(f: &Mat14, want: &[[f64; 14]; 14]) {
        for (i, row) in want.iter().enumerate() {
            for (j, &w) in row.iter().enumerate() {
                assert_eq!(f[(i, j)], w, "F[{i},{j}]");
            }
        }
    }

    #[test]
    fn paper_f_matches_eq10_with_erratum2() {
        let m = PaperModel::new(cfg(ModelForm::Paper)).unwrap();
        let t = m.transition(0.01, 0.3, -0.2);
        assert_matrix_eq(&dense(&t), &paper_f_by_hand());
    }

    #[test]
    fn physics_f_adds_heading_coupling() {
        let m = PaperModel::new(cfg(ModelForm::Physics)).unwrap();
        let (a_e, a_n) = (0.3, -0.2);
        let t = m.transition(0.01, a_e, a_n);
        let mut want = paper_f_by_hand();
        // Erratum 3: yaw error d rotates the ENU acceleration by d (ccw):
        // d a_e = -a_n d, d a_n = +a_e d.
        want[2][4] = 0.2 * 0.01;
        want[3][4] = 0.3 * 0.01;
        assert_matrix_eq(&dense(&t), &want);
    }

    #[test]
    fn sparse_apply_equals_dense_product() {
        let m = PaperModel::new(cfg(ModelForm::Physics)).unwrap();
        let t = m.transition(0.02, 1.5, -0.7);
        let x = Vec14::from_fn(|i, _| (i as f64 * 0.37).sin() + 0.1 * i as f64);
        let d = dense(&t) * x;
        let s = t.apply(&x);
        for i in 0..14 {
            assert!((d[i] - s[i]).abs() < 1e-15, "{i}");
        }
    }

    #[test]
    fn q_is_eq11_diagonal() {
        let m = PaperModel::new(cfg(ModelForm::Paper)).unwrap();
        let q = m.process_noise(0.01);
        let want = [
            0.005, 0.005, 0.0025, 0.0025, 0.00125, 1e-3, 0.0, 0.0, 2e-3, 0.0, 0.0, 3e-6, 0.0, 0.0,
        ];
        for i in 0..14 {
            for j in 0..14 {
                let w = if i == j { want[i] } else { 0.0 };
                assert!((q[(i, j)] - w).abs() < 1e-18, "Q[{i},{j}] = {}", q[(i, j)]);
            }
        }
    }

    #[test]
    fn h_is_identity_then_zero() {
        let h = h_matrix();
        for i in 0..4 {
            for j in 0..14 {
                assert_eq!(h[(i, j)], if i == j { 1.0 } else { 0.0 });
            }
        }
        let hp = h_matrix_pos();
        assert_eq!(hp[(0, 0)], 1.0);
        assert_eq!(hp[(1, 1)], 1.0);
        assert_eq!(hp.sum(), 2.0);
    }

    #[test]
    fn jury_test_separates_stable_and_unstable() {
        // (z - 0.5)^3 = z^3 - 1.5 z^2 + 0.75 z - 0.125: stable.
        assert!(ar3_is_stable(&[-1.5, 0.75, -0.125]));
        // (z - 1.1)(z - 0.2)(z + 0.3): one root outside.
        let (r1, r2, r3) = (1.1_f64, 0.2_f64, -0.3_f64);
        let m = [
            -(r1 + r2 + r3),
            r1 * r2 + r1 * r3 + r2 * r3,
            -(r1 * r2 * r3),
        ];
        assert!(!ar3_is_stable(&m));
        // Complex pair of modulus 0.9 and a real root 0.5: stable.
        let (re, im, r) = (0.9_f64 * 0.6, 0.9_f64 * 0.8, 0.5);
        let s = re * re + im * im;
        let m = [-(2.0 * re + r), s + 2.0 * re * r, -(s * r)];
        assert!(ar3_is_stable(&m));
        // Same pair at modulus 1.05: unstable.
        let (re, im) = (1.05 * 0.6, 1.05 * 0.8);
        let s = re * re + im * im;
        let m = [-(2.0 * re + r), s + 2.0 * re * r, -(s * r)];
        assert!(!ar3_is_stable(&m));
        // Unit root (random walk) is not strictly stable.
        assert!(!ar3_is_stable(&[-1.0, 0.0, 0.0]));
        assert!(ar3_is_stable(&[0.0, 0.0, 0.0]));
        assert!(!ar3_is_stable(&[f64::NAN, 0.0, 0.0]));
    }

    #[test]
    fn validate_names_the_key() {
        let mut c = ModelConfig::default();
        c.validate().unwrap();
        c.ar_gyro.m = [-1.5, 0.0, 0.0];
        let e = c.validate().unwrap_err();
        assert!(e.to_string().contains("model.ar_gyro.m"), "{e}");
        let c = ModelConfig {
            ar_rate_hz: -1.0,
            ..ModelConfig::default()
        };
        assert_eq!(
            c.validate().unwrap_err().to_string(),
            "model.ar_rate_hz must be finite and > 0, got -1"
        );
        let c = ModelConfig {
            q_vel_m2_per_s3: f64::NAN,
            ..ModelConfig::default()
        };
        assert!(c
            .validate()
            .unwrap_err()
            .to_string()
            .starts_with("model.q_vel_m2_per_s3"));
        // With the random-walk bias, the AR coefficients are not used.
        let mut c = ModelConfig::default();
        c.ar_gyro.m = [-1.5, 0.0, 0.0];
        c.bias_random_walk = Some(BiasRandomWalk {
            accel_var_m2_per_s4: 1e-9,
            gyro_var_rad2_per_s2: 1e-12,
        });
        c.validate().unwrap();
    }

    #[test]
    fn bias_random_walk_uses_unit_root_blocks() {
        let mut c = cfg(ModelForm::Paper);
        c.bias_random_walk = Some(BiasRandomWalk {
            accel_var_m2_per_s4: 4e-8,
            gyro_var_rad2_per_s2: 9e-12,
        });
        let m = PaperModel::new(c).unwrap();
        let f = dense(&m.transition(0.01, 0.0, 0.0));
        for o in [5, 8, 11] {
            assert_eq!(f[(o, o)], 1.0);
            assert_eq!(f[(o, o + 1)], 0.0);
            assert_eq!(f[(o, o + 2)], 0.0);
            assert_eq!(f[(o + 1, o)], 1.0);
            assert_eq!(f[(o + 1, o + 1)], 0.0);
        }
        let q = m.process_noise_diag(0.01);
        assert_eq!((q[5], q[8], q[11]), (4e-8, 4e-8, 9e-12));
    }

    #[test]
    fn steps_split_the_interval() {
        let m = PaperModel::new(cfg(ModelForm::Paper)).unwrap();
        assert_eq!(m.steps(0.01).unwrap().n, 1);
        // Jitter within half a step is one step of the measured length.
        let s = m.steps(0.0123).unwrap();
        assert_eq!((s.n, s.sub_dt_s), (1, 0.0123));
        let s = m.steps(0.1).unwrap();
        assert_eq!(s.n, 10);
        assert!((s.sub_dt_s - 0.01).abs() < 1e-15);
        assert!(matches!(m.steps(0.004), Err(StepError::BelowArStep { .. })));
        assert!(matches!(
            m.steps(0.25),
            Err(StepError::TooManySteps { max: 20, .. })
        ));
        assert!(matches!(m.steps(-0.01), Err(StepError::InvalidDt { .. })));
        assert!(matches!(
            m.steps(f64::INFINITY),
            Err(StepError::InvalidDt { .. })
        ));
    }

    #[test]
    fn config_serde_defaults_and_unknown_keys() {
        let c: ModelConfig = serde_json::from_str(r#"{"form":"paper"}"#).unwrap();
        assert_eq!(c.form, ModelForm::Paper);
        assert_eq!(c.ar_rate_hz, 100.0);
        let back: ModelConfig =
            serde_json::from_str(&serde_json::to_string(&ModelConfig::default()).unwrap()).unwrap();
        assert_eq!(back, ModelConfig::default());
        assert!(serde_json::from_str::<ModelConfig>(r#"{"gamma":1}"#).is_err());
        assert!(
            serde_json::from_str::<ModelConfig>(r#"{"ar_gyro":{"m":[0,0,0]}}"#).is_err(),
            "ArConfig needs both keys"
        );
    }
}
