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
}
