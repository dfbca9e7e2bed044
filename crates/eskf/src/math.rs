//! Small rotation helpers (skew matrix, quaternion to rotation matrix) and
//! input checks shared by the filter's operations.

use nalgebra::{Matrix3, Vector3};

/// Tolerance on `| |q| - 1 |` for an input quaternion (it is then normalised).
pub(crate) const QUAT_NORM_TOL: f64 = 1e-2;

/// `[v x]`, the cross-product matrix: `skew(a) * b = a x b`.
#[must_use]
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Rotation matrix (body to ENU) of a unit quaternion `[w, x, y, z]`.
///
/// The quaternion is used as given (not normalised).
#[must_use]
pub fn quat_to_rot(q: [f64; 4]) -> Matrix3<f64> {
    let [w, x, y, z] = q;
    Matrix3::new(
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y - w * z),
        2.0 * (x * z + w * y),
        2.0 * (x * y + w * z),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z - w * x),
        2.0 * (x * z - w * y),
        2.0 * (y * z + w * x),
        1.0 - 2.0 * (x * x + y * y),
    )
}

/// A check that failed on an input: either a non-finite value (named) or a
/// quaternion whose norm is off by more than [`QUAT_NORM_TOL`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum InputFault {
    NonFinite { input: &'static str, value: f64 },
    QuatNorm { norm: f64 },
}

/// Fails on the first non-finite entry of `v`.
pub(crate) fn finite<const N: usize>(input: &'static str, v: &[f64; N]) -> Result<(), InputFault> {
    match v.iter().find(|x| !x.is_finite()) {
        Some(&value) => Err(InputFault::NonFinite { input, value }),
        None => Ok(()),
    }
}

/// Checks a quaternion input and returns its rotation matrix (normalised).
pub(crate) fn checked_rotation(q: [f64; 4]) -> Result<Matrix3<f64>, InputFault> {
    finite("quat", &q)?;
    let norm = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    if (norm - 1.0).abs() > QUAT_NORM_TOL {
        return Err(InputFault::QuatNorm { norm });
    }
    Ok(quat_to_rot([
        q[0] / norm,
        q[1] / norm,
        q[2] / norm,
        q[3] / norm,
    ]))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn skew_is_cross_product() {
        let a = Vector3::new(0.3, -1.2, 2.0);
        let b = Vector3::new(-0.7, 0.4, 1.1);
        assert!((skew(&a) * b - a.cross(&b)).norm() < 1e-15);
    }

    #[test]
    fn quaternion_rotates_body_into_enu() {
        // 90 deg yaw (counter-clockwise about up): body x (forward) points north.
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let r = quat_to_rot([h, 0.0, 0.0, h]);
        let v = r * Vector3::new(1.0, 0.0, 0.0);
        assert!((v - Vector3::new(0.0, 1.0, 0.0)).norm() < 1e-15);
        // 90 deg roll about body x: body y (left) points up.
        let r = quat_to_rot([h, h, 0.0, 0.0]);
        let v = r * Vector3::new(0.0, 1.0, 0.0);
        assert!((v - Vector3::new(0.0, 0.0, 1.0)).norm() < 1e-15);
    }

    #[test]
    fn checked_rotation_rejects_bad_quaternions() {
        assert_eq!(
            checked_rotation([2.0, 0.0, 0.0, 0.0]),
            Err(InputFault::QuatNorm { norm: 2.0 })
        );
        assert!(matches!(
            checked_rotation([f64::NAN, 0.0, 0.0, 0.0]),
            Err(InputFault::NonFinite { input: "quat", .. })
        ));
        let r = checked_rotation([1.005, 0.0, 0.0, 0.0]).unwrap();
        assert!((r - Matrix3::identity()).norm() < 1e-15);
    }
}
