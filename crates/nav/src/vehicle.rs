//! Vehicle models: what the mechanisation integrates as the body specific
//! force, and the constraints a vehicle puts on its body velocity.
//!
//! - [`VehicleKind::Free`]: the accelerometer is taken as measuring free
//!   3-axis specific force (the paper's INS; every axis integrated).
//! - [`VehicleKind::Multirotor`]: a multirotor's rotors push along its body
//!   z axis only; in the body x and y axes the only force is rotor drag,
//!   linear in the body velocity (`f_xy = -k v_xy`; Mueller, Hamer, D'Andrea,
//!   ICRA 2015; Leishman, Macdonald, Beard, McLain, IEEE Control Systems
//!   2014). The mechanisation integrates `[-k v_bx, -k v_by, f_z]`: the
//!   horizontal acceleration comes from the tilt of the thrust, and the
//!   accelerometer's horizontal channels, which on a multirotor hold drag,
//!   vibration and a vibration-rectified bias, become measurements of the
//!   drag (the filter's business, not the mechanisation's). The Crazyflie's
//!   onboard filter integrates the same way in flight (bitcraze
//!   crazyflie-firmware, `kalman_core.c`, thrust along body z only).
//! - [`VehicleKind::Ground`]: a wheeled robot does not slip sideways or
//!   leave the floor: its body velocity has no lateral and no vertical
//!   part (the non-holonomic constraint of land-vehicle INS). The
//!   mechanisation integrates every axis; the filters fuse the constraint
//!   as pseudo-measurements with a stated noise.
//!
//! The functions here are pure: the INS and the filters share them so that
//! the model the mechanisation integrates is the one the filters linearise.

use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// Which vehicle the IMU rides on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VehicleKind {
    /// Free 3-axis specific force (every accelerometer axis integrated).
    #[default]
    Free,
    /// Thrust along body z plus linear rotor drag in body x and y.
    Multirotor,
    /// Zero lateral and vertical body velocity (wheeled robot).
    Ground,
}

impl VehicleKind {
    /// The name used in config files and on the command line.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Free => "free",
            Self::Multirotor => "multirotor",
            Self::Ground => "ground",
        }
    }
}

impl std::str::FromStr for VehicleKind {
    type Err = UnknownVehicle;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "free" => Ok(Self::Free),
            "multirotor" => Ok(Self::Multirotor),
            "ground" => Ok(Self::Ground),
            other => Err(UnknownVehicle(other.to_owned())),
        }
    }
}

/// A vehicle name that is none of `free`, `multirotor`, `ground`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown vehicle '{0}': expected free, multirotor or ground")]
pub struct UnknownVehicle(pub String);

/// The vehicle model the mechanisation integrates with.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Mechanisation {
    /// Every accelerometer axis integrated ([`VehicleKind::Free`]).
    #[default]
    Free,
    /// Body x/y specific force replaced by linear drag `-drag_per_s * v_b`
    /// ([`VehicleKind::Multirotor`]).
    ThrustDrag {
        /// Linear drag coefficient, 1/s.
        drag_per_s: f64,
    },
}

/// The body specific force a multirotor model integrates: the measured
/// (bias-compensated) body z, and linear drag `-drag_per_s * v_b` in body x
/// and y, with `v_b = C^T v` the body-frame velocity.
#[must_use]
pub fn thrust_drag_force(
    f_meas_b: &Vector3<f64>,
    att: &UnitQuaternion<f64>,
    vel_nav: &Vector3<f64>,
    drag_per_s: f64,
) -> Vector3<f64> {
    let v_b = att.inverse() * vel_nav;
    Vector3::new(-drag_per_s * v_b.x, -drag_per_s * v_b.y, f_meas_b.z)
}

/// The ENU kinematic acceleration (gravity removed) a vehicle model
/// integrates at one INS state, from the measured kinematic acceleration
/// `accel_nav_meas` (the accelerometer's, rotated to ENU, gravity removed),
/// the attitude `quat` (`[w, x, y, z]`, body to ENU) and the velocity: what
/// a filter linearises the mechanisation about. [`Mechanisation::Free`]
/// returns the measured acceleration.
#[must_use]
pub fn model_accel_nav(
    mech: Mechanisation,
    quat: [f64; 4],
    vel_nav: [f64; 3],
    accel_nav_meas: [f64; 3],
    gravity_mps2: f64,
) -> [f64; 3] {
    let Mechanisation::ThrustDrag { drag_per_s } = mech else {
        return accel_nav_meas;
    };
    let att = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
        quat[0], quat[1], quat[2], quat[3],
    ));
    let g = Vector3::new(0.0, 0.0, gravity_mps2);
    let f_meas_b = att.inverse() * (Vector3::from(accel_nav_meas) + g);
    let f = thrust_drag_force(&f_meas_b, &att, &Vector3::from(vel_nav), drag_per_s);
    (att * f - g).into()
}

/// Length of the slow blocks of [`HorizontalSignal`], ns.
const SIGNAL_SLOW_BLOCK_NS: u64 = 200_000_000;
/// Length of the fast blocks whose residual is the vibration, ns.
const SIGNAL_FAST_BLOCK_NS: u64 = 50_000_000;

/// Sums over one block of samples (both horizontal axes).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Block {
    start_ns: u64,
    n: f64,
    sum: [f64; 2],
    sum_sq: [f64; 2],
}

/// Whether a multirotor's accelerometer measures its horizontal
/// acceleration after all: the RMS variation of the horizontal channels'
/// 0.2 s means, over the RMS of their residual about their 50 ms means
/// (vibration), over a window of samples.
///
/// On a vehicle whose horizontal channels hold only drag and vibration
/// the slow part is small against the vibration; where the IMU sits quiet
/// and its horizontal channels follow the motion, it is a multiple of the
/// vibration, and every axis is better integrated ([`VehicleKind::Free`]).
/// Over the first 3 s of integration: 0.16-0.94 on the 21 UTIL Crazyflie
/// 2.x flights, 1.93 and 2.43 on the two Crazyflie Bolt flights
/// (docs/REAL_FLIGHTS.md). Pure and deterministic: the INS and a replay of
/// it decide at the same sample.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct HorizontalSignal {
    first_ns: Option<u64>,
    last_ns: u64,
    slow: Block,
    fast: Block,
    /// The slow blocks' means (Welford per axis: count, mean, M2).
    blocks: f64,
    mean: [f64; 2],
    m2: [f64; 2],
    /// The squared residuals about the fast blocks' means (both axes) and
    /// the samples they hold.
    vib_sq: f64,
    vib_n: f64,
}

impl HorizontalSignal {
    /// Folds in one accelerometer sample (body, m/s^2) at `t_ns`; samples
    /// not after the previous one, or not finite, are ignored.
    pub fn push(&mut self, t_ns: u64, accel_b: [f64; 3]) {
        if !accel_b.iter().all(|v| v.is_finite()) {
            return;
        }
        match self.first_ns {
            None => {
                self.first_ns = Some(t_ns);
                self.slow.start_ns = t_ns;
                self.fast.start_ns = t_ns;
            }
            Some(_) if t_ns <= self.last_ns => return,
            Some(_) => {}
        }
        self.last_ns = t_ns;
        if t_ns - self.slow.start_ns >= SIGNAL_SLOW_BLOCK_NS {
            if self.slow.n > 0.0 {
                self.blocks += 1.0;
                for i in 0..2 {
                    let m = self.slow.sum[i] / self.slow.n;
                    let d = m - self.mean[i];
                    self.mean[i] += d / self.blocks;
                    self.m2[i] += d * (m - self.mean[i]);
                }
            }
            self.slow = Block {
                start_ns: t_ns,
                ..Block::default()
            };
        }
        if t_ns - self.fast.start_ns >= SIGNAL_FAST_BLOCK_NS {
            let b = self.fast;
            if b.n > 1.0 {
                for i in 0..2 {
                    self.vib_sq += (b.sum_sq[i] - b.sum[i] * b.sum[i] / b.n).max(0.0);
                }
                self.vib_n += b.n;
            }
            self.fast = Block {
                start_ns: t_ns,
                ..Block::default()
            };
        }
        for b in [&mut self.slow, &mut self.fast] {
            b.n += 1.0;
            for (i, a) in accel_b.iter().take(2).enumerate() {
                b.sum[i] += a;
                b.sum_sq[i] += a * a;
            }
        }
    }

    /// Seconds from the first sample to the last.
    #[must_use]
    pub fn span_s(&self) -> f64 {
        self.first_ns
            .map_or(0.0, |f| (self.last_ns - f) as f64 * 1e-9)
    }

    /// The mean of the horizontal channels (body x, y) over the slow
    /// blocks, m/s^2; `None` before the first block.
    #[must_use]
    pub fn mean_xy(&self) -> Option<[f64; 2]> {
        (self.blocks >= 1.0).then_some(self.mean)
    }

    /// The ratio (slow variation over vibration, RMS over both axes);
    /// `None` before two slow blocks or without vibration.
    #[must_use]
    pub fn ratio(&self) -> Option<f64> {
        if self.blocks < 2.0 || self.vib_sq <= 0.0 || self.vib_n <= 0.0 {
            return None;
        }
        let var = (self.m2[0] + self.m2[1]) / (2.0 * self.blocks);
        let vib = self.vib_sq / (2.0 * self.vib_n);
        Some((var / vib).sqrt())
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn names_round_trip() {
        for k in [
            VehicleKind::Free,
            VehicleKind::Multirotor,
            VehicleKind::Ground,
        ] {
            assert_eq!(k.name().parse::<VehicleKind>().unwrap(), k);
        }
        let e = "boat".parse::<VehicleKind>().unwrap_err();
        assert!(e.to_string().contains("boat"), "{e}");
    }

    /// Level, flying east at 2 m/s, drag 0.5/s: the model's acceleration is
    /// 1 m/s^2 westwards whatever the accelerometer's x and y say; the
    /// vertical comes from the measured z.
    #[test]
    fn thrust_drag_replaces_horizontal_channels() {
        let g = 9.81;
        let meas = [3.0, -2.0, 0.2]; // vibration and a climb
        let a = model_accel_nav(
            Mechanisation::ThrustDrag { drag_per_s: 0.5 },
            [1.0, 0.0, 0.0, 0.0],
            [2.0, 0.0, 0.0],
            meas,
            g,
        );
        assert!((a[0] + 1.0).abs() < 1e-12, "{a:?}");
        assert!(a[1].abs() < 1e-12);
        assert!((a[2] - 0.2).abs() < 1e-12);
        // Free: the measurement itself.
        assert_eq!(
            model_accel_nav(
                Mechanisation::Free,
                [1.0, 0.0, 0.0, 0.0],
                [2.0, 0.0, 0.0],
                meas,
                g
            ),
            meas
        );
    }

    /// Tilted 0.1 rad about body x (right wing down... roll), hovering:
    /// the thrust's tilt gives the horizontal acceleration `g tan(roll)`.
    #[test]
    fn tilted_thrust_accelerates_sideways() {
        let g = 9.81;
        let roll: f64 = 0.1;
        let att = UnitQuaternion::from_euler_angles(roll, 0.0, 0.0);
        let q = att.quaternion();
        // Thrust that holds the height: f_z = g / cos(roll); measured in
        // body z; the accelerometer x/y read noise.
        let f_b = Vector3::new(0.7, -0.4, g / roll.cos());
        let meas: [f64; 3] = (att * f_b - Vector3::new(0.0, 0.0, g)).into();
        let a = model_accel_nav(
            Mechanisation::ThrustDrag { drag_per_s: 0.3 },
            [q.w, q.i, q.j, q.k],
            [0.0; 3],
            meas,
            g,
        );
        // Positive roll tilts body z towards -y (north): a_n = -g tan(roll).
        assert!((a[1] + g * roll.tan()).abs() < 1e-9, "{a:?}");
        assert!(a[0].abs() < 1e-9 && a[2].abs() < 1e-9, "{a:?}");
    }

    /// Quiet channels that follow a slow motion read several times their
    /// vibration; channels of vibration and a little drag read below one.
    #[test]
    fn the_horizontal_signal_tells_motion_from_vibration() {
        let step = 1_000_000u64; // 1 kHz
        let (mut moving, mut shaking) = (HorizontalSignal::default(), HorizontalSignal::default());
        let mut x: u64 = 12345;
        let mut noise = || {
            // A small deterministic generator: uniform in [-1, 1).
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (x >> 11) as f64 / (1u64 << 52) as f64 - 1.0
        };
        for k in 0..10_000u64 {
            let t = k as f64 * 1e-3;
            let motion = (t * 2.0).sin(); // 1 m/s^2 at 0.3 Hz
            moving.push(
                k * step,
                [
                    motion + 0.2 * noise(),
                    0.8 * (t * 1.3).cos() + 0.2 * noise(),
                    9.8,
                ],
            );
            shaking.push(
                k * step,
                [0.05 * motion + 1.5 * noise(), 1.5 * noise(), 9.8],
            );
        }
        assert!((moving.span_s() - 9.999).abs() < 1e-9);
        let (m, s) = (moving.ratio().unwrap(), shaking.ratio().unwrap());
        assert!(m > 3.0, "{m}");
        assert!(s < 0.5, "{s}");
        assert_eq!(HorizontalSignal::default().ratio(), None);
    }
}
