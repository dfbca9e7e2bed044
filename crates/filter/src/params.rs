//! Tuning of the adaptive filters ([`FilterParams`]) and the prior shared by
//! all four filters ([`FilterSetup`]: `P_0`, `R_0`), with their validation.

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::model::{Mat14, Mat4, N_MEAS, N_STATES};

/// How the IAKF tests a measurement component for an outlier (eqs. 23-25, erratum 10).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OutlierForm {
    /// No outlier weighting (all `lambda_i = 1`).
    Off,
    /// Innovation form (erratum 10, default): `G_i = v_i^2` against
    /// `D_i = S_ii = (H P- H^T + R)_ii`.
    #[default]
    Innovation,
    /// The paper's literal form: `G_i = Z_i^2` against
    /// `D_i = S_ii + (H X-)_i^2` (much worse in open loop).
    ZForm,
}

/// How an outlier's weight `lambda < 1` is applied (erratum 13): the one
/// outlier-weighting vocabulary of both filter families, the IAKF's
/// `filter.limit_mode` and the tight ESKF's `eskf.limit_mode`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LimitMode {
    /// Scale the innovation: `v_i <- lambda_i v_i` (default; with the
    /// default `eps_i` of the IAKF, and the ESKF's `lambda = kappa / r`,
    /// this clips `v_i` at `kappa sqrt(S_ii)`: Huber). `huber` is read as
    /// this.
    #[default]
    #[serde(alias = "huber")]
    ScaleInnovation,
    /// Keep `v` and inflate `R` for this update: `R <- L^-1 R L^-1`,
    /// `L = diag(lambda)` (i.e. `R_ii / lambda_i^2`), which keeps `P` consistent.
    InflateR,
}

/// Tuning of the SHAF, STF and IAKF (the KF uses none of it).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FilterParams {
    /// Sage-Husa forgetting factor `b` (eq. 22; the paper: 0.95 to 0.99). Default 0.97.
    pub b: f64,
    /// Updates during which `R` stays at `R_0` before the Sage-Husa estimator
    /// adapts it (erratum 7); they still count in `d_k` (erratum 8, `k` from 1).
    /// Default 10 (1 s at the paper's 10 Hz UWB rate).
    pub warmup_updates: u32,
    /// Lower clamp of each adapted `R_ii`, as a factor of `R_0,ii` (erratum 7). Default 0.1.
    pub r_min_factor: f64,
    /// Upper clamp of each adapted `R_ii`, as a factor of `R_0,ii` (erratum 7). Default 100.
    pub r_max_factor: f64,
    /// Keep the full 4 x 4 estimate of eq. 22 (`true`, the paper) or only its
    /// diagonal (`false`, default: `R_0` is diagonal and the clamp is then
    /// guaranteed to keep `R` positive definite). A full estimate that is not
    /// positive definite after clamping falls back to its diagonal.
    pub adapt_full_r: bool,
    /// IAKF outlier test (erratum 10). Default `innovation`.
    pub outlier_form: OutlierForm,
    /// IAKF outlier threshold in sigmas: `eps_i = (kappa^2 - 1) S_ii`
    /// (erratum 12). Default 3.
    pub kappa: f64,
    /// IAKF outlier limiting (erratum 13). Default `scale_innovation`.
    pub limit_mode: LimitMode,
    /// IAKF divergence test and fading (eqs. 27-31). Default `true`.
    pub divergence_fading: bool,
    /// IAKF divergence threshold: diverging when `v^T v > gamma tr(S)` (eq. 27,
    /// erratum 14; the paper gives no value). Default 4 (for four equal
    /// Gaussian components a false alarm rate of about 0.3 %).
    pub gamma: f64,
    /// Upper bound of the fading factor of the STF and the IAKF (erratum 15). Default 10.
    pub fading_cap: f64,
    /// STF forgetting factor `rho` of the innovation covariance estimate
    /// `V_k = (rho V_{k-1} + v v^T) / (1 + rho)` (Zhou). Default 0.95.
    pub stf_rho: f64,
    /// STF softening factor `beta >= 1` in `N = V - beta R - H Q H^T` (Zhou). Default 1.
    pub stf_beta: f64,
}

impl Default for FilterParams {
    fn default() -> Self {
        Self {
            b: 0.97,
            warmup_updates: 10,
            r_min_factor: 0.1,
            r_max_factor: 100.0,
            adapt_full_r: false,
            outlier_form: OutlierForm::Innovation,
            kappa: 3.0,
            limit_mode: LimitMode::ScaleInnovation,
            divergence_fading: true,
            gamma: 4.0,
            fading_cap: 10.0,
            stf_rho: 0.95,
            stf_beta: 1.0,
        }
    }
}

/// Why a [`FilterParams`] was refused.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum FilterParamsError {
    /// A value outside its allowed range.
    #[error("filter.{key} must be {allowed}, got {value}")]
    OutOfRange {
        /// Offending key.
        key: &'static str,
        /// What is allowed.
        allowed: &'static str,
        /// Its value.
        value: f64,
    },
}

fn check(
    key: &'static str,
    allowed: &'static str,
    value: f64,
    ok: bool,
) -> Result<(), FilterParamsError> {
    if value.is_finite() && ok {
        Ok(())
    } else {
        Err(FilterParamsError::OutOfRange {
            key,
            allowed,
            value,
        })
    }
}

impl FilterParams {
    /// Checks every key; the error names the first offending one.
    ///
    /// # Errors
    /// [`FilterParamsError`] naming the key, the allowed range and the value.
    pub fn validate(&self) -> Result<(), FilterParamsError> {
        check("b", "in (0, 1)", self.b, self.b > 0.0 && self.b < 1.0)?;
        check(
            "r_min_factor",
            "> 0",
            self.r_min_factor,
            self.r_min_factor > 0.0,
        )?;
        check(
            "r_max_factor",
            ">= filter.r_min_factor",
            self.r_max_factor,
            self.r_max_factor >= self.r_min_factor,
        )?;
        check("kappa", ">= 1", self.kappa, self.kappa >= 1.0)?;
        check("gamma", "> 1", self.gamma, self.gamma > 1.0)?;
        check(
            "fading_cap",
            ">= 1",
            self.fading_cap,
            self.fading_cap >= 1.0,
        )?;
        check(
            "stf_rho",
            "in (0, 1]",
            self.stf_rho,
            self.stf_rho > 0.0 && self.stf_rho <= 1.0,
        )?;
        check("stf_beta", ">= 1", self.stf_beta, self.stf_beta >= 1.0)?;
        Ok(())
    }
}

/// The prior shared by the KF, SHAF, STF and IAKF: they share `Q` (the
/// model), `R_0` and `P_0`; only their adaptive parts differ.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FilterSetup {
    /// Diagonal of `P_0` in state order (m^2, (m/s)^2, rad^2, (m/s^2)^2,
    /// (rad/s)^2). Default: 1 m and 1 m/s (the paper's initial errors read as
    /// `P_0`, erratum 18), 0.1 rad heading, AR states at their driving
    /// variances of the default model (1e-4 and 2.115e-8).
    pub p0_diag: [f64; N_STATES],
    /// Diagonal of `R_0` (`dPe, dPn` in m^2, `dVe, dVn` in (m/s)^2). Default:
    /// 0.07 m UWB position noise (Table 1's UWB RMSE) and 1 m/s velocity noise
    /// (velocity from successive 10 Hz fixes: sqrt(2) 0.07 m / 0.1 s, erratum 17).
    pub r0_diag: [f64; N_MEAS],
}

impl Default for FilterSetup {
    fn default() -> Self {
        let (a, g) = (1e-4, 2.115e-8);
        Self {
            p0_diag: [1.0, 1.0, 1.0, 1.0, 0.01, a, a, a, a, a, a, g, g, g],
            r0_diag: [0.0049, 0.0049, 1.0, 1.0],
        }
    }
}

/// Why a [`FilterSetup`] was refused.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum FilterSetupError {
    /// A `P_0` entry is negative or not finite.
    #[error("setup.p0_diag[{index}] must be finite and >= 0, got {value}")]
    P0 {
        /// Offending index.
        index: usize,
        /// Its value.
        value: f64,
    },
    /// An `R_0` entry is not positive or not finite.
    #[error("setup.r0_diag[{index}] must be finite and > 0, got {value}")]
    R0 {
        /// Offending index.
        index: usize,
        /// Its value.
        value: f64,
    },
}

impl FilterSetup {
    /// Checks every entry; the error names the first offending one.
    ///
    /// # Errors
    /// [`FilterSetupError`] naming the key, index and value.
    pub fn validate(&self) -> Result<(), FilterSetupError> {
        for (index, &value) in self.p0_diag.iter().enumerate() {
            if !(value.is_finite() && value >= 0.0) {
                return Err(FilterSetupError::P0 { index, value });
            }
        }
        for (index, &value) in self.r0_diag.iter().enumerate() {
            if !(value.is_finite() && value > 0.0) {
                return Err(FilterSetupError::R0 { index, value });
            }
        }
        Ok(())
    }

    /// `P_0` as a matrix.
    #[must_use]
    pub fn p0(&self) -> Mat14 {
        Mat14::from_diagonal(&self.p0_diag.into())
    }

    /// `R_0` as a matrix.
    #[must_use]
    pub fn r0(&self) -> Mat4 {
        Mat4::from_diagonal(&self.r0_diag.into())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_validate_and_round_trip() {
        FilterParams::default().validate().unwrap();
        FilterSetup::default().validate().unwrap();
        let p: FilterParams =
            serde_json::from_str(&serde_json::to_string(&FilterParams::default()).unwrap())
                .unwrap();
        assert_eq!(p, FilterParams::default());
        let p: FilterParams =
            serde_json::from_str(r#"{"outlier_form":"z_form","limit_mode":"inflate_r"}"#).unwrap();
        assert_eq!(p.outlier_form, OutlierForm::ZForm);
        assert_eq!(p.limit_mode, LimitMode::InflateR);
        let p: FilterParams = serde_json::from_str(r#"{"limit_mode":"huber"}"#).unwrap();
        assert_eq!(p.limit_mode, LimitMode::ScaleInnovation);
        assert!(serde_json::from_str::<FilterParams>(r#"{"gama":3}"#).is_err());
        assert!(serde_json::from_str::<FilterSetup>(r#"{"p0":[]}"#).is_err());
    }

    #[test]
    fn validate_names_the_key() {
        let p = FilterParams {
            gamma: 0.5,
            ..FilterParams::default()
        };
        assert_eq!(
            p.validate().unwrap_err().to_string(),
            "filter.gamma must be > 1, got 0.5"
        );
        let p = FilterParams {
            b: 1.0,
            ..FilterParams::default()
        };
        assert!(p
            .validate()
            .unwrap_err()
            .to_string()
            .starts_with("filter.b "));
        let p = FilterParams {
            r_max_factor: 0.01,
            ..FilterParams::default()
        };
        assert!(p
            .validate()
            .unwrap_err()
            .to_string()
            .starts_with("filter.r_max_factor"));
        let p = FilterParams {
            kappa: f64::NAN,
            ..FilterParams::default()
        };
        assert!(p.validate().is_err());
        let mut s = FilterSetup::default();
        s.r0_diag[3] = 0.0;
        assert_eq!(
            s.validate().unwrap_err().to_string(),
            "setup.r0_diag[3] must be finite and > 0, got 0"
        );
        let mut s = FilterSetup::default();
        s.p0_diag[7] = -1.0;
        assert!(s
            .validate()
            .unwrap_err()
            .to_string()
            .starts_with("setup.p0_diag[7]"));
    }
}
