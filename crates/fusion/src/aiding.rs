//! Velocity aiding: the settings of body-velocity updates (odometry, flow)
//! and the online estimate of each source's scale factor.
//!
//! A velocity sensor reads its speed with a scale error: wheel odometry
//! through the wheel radius, tyre wear and slip; optical flow through the
//! lens model and the floor's texture (on the UTIL flights the Flow deck
//! reads 0.77-1.06 of the motion capture's body velocity, a different
//! factor on each flight: `tools/util_flow_check.py`). Fused as if exact, such a
//! sensor pulls the velocity, then the position, away from the UWB for as
//! long as the vehicle moves. [`ScaleEstimator`] estimates the factor `s`
//! of `measured = s · true` online, one per source, with a scalar Kalman
//! filter beside the navigation filter (a random walk from the configured
//! prior): each measured axis `m` against the filter's predicted body
//! velocity `p` is an observation `m = s p + noise`, with the noise of the
//! sensor and of `p` (its variance from the filter's covariance). The
//! velocity update then uses `m / s` and a variance grown by what `s` is not
//! known to (`p² var(s)`). The factor is observable only while the vehicle
//! moves; at rest it keeps its prior or its last estimate.

use serde::{Deserialize, Serialize};

/// Settings of the velocity updates, per source (`[fusion.aiding]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AidingConfig {
    /// Longest a body velocity waits for the UWB stream to reach its time,
    /// s: the engine applies it once a UWB measurement at or after its
    /// time has arrived (the order `insuwb eval` applies them in, whichever
    /// process delivers first), or, while UWB is silent, once the INS is
    /// this far past it. Default 0.25.
    pub wait_s: f64,
    /// Optical flow's scale factor estimate.
    pub flow: ScaleConfig,
    /// Wheel odometry's scale factor estimate.
    pub odometry: ScaleConfig,
}

impl Default for AidingConfig {
    fn default() -> Self {
        Self {
            wait_s: 0.25,
            flow: ScaleConfig::default(),
            odometry: ScaleConfig::default(),
        }
    }
}

/// The scale factor of one velocity source and the weight of its updates.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ScaleConfig {
    /// Prior of the factor `measured / true` (1: the sensor model's).
    pub prior: f64,
    /// Its standard deviation; 0 keeps the factor fixed at the prior.
    pub prior_sigma: f64,
    /// Random walk of the factor, 1/sqrt(s).
    pub random_walk_per_rts: f64,
    /// Multiplies the standard deviation each sample carries (1: as the
    /// source states it).
    pub sigma_factor: f64,
    /// Innovation gate of the factor's update, in standard deviations.
    pub gate_sigma: f64,
}

impl Default for ScaleConfig {
    fn default() -> Self {
        Self {
            prior: 1.0,
            prior_sigma: 0.1,
            random_walk_per_rts: 0.001,
            sigma_factor: 1.0,
            gate_sigma: 3.0,
        }
    }
}

/// An [`AidingConfig`] value out of range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AidingConfigError {
    /// The wait is negative, not finite or above 5 s.
    #[error("aiding.wait_s must be finite and within [0, 5] s, got {0}")]
    Wait(f64),
    /// A value is out of its range.
    #[error("aiding.{source_name}.{key} must be {range}, got {value}")]
    Value {
        /// `flow` or `odometry`.
        source_name: &'static str,
        /// The key.
        key: &'static str,
        /// The range it must be in.
        range: &'static str,
        /// Its value.
        value: f64,
    },
}

impl AidingConfig {
    /// Checks every value, naming the first offending key.
    ///
    /// # Errors
    /// [`AidingConfigError::Value`].
    pub fn validate(&self) -> Result<(), AidingConfigError> {
        if !(self.wait_s.is_finite() && (0.0..=5.0).contains(&self.wait_s)) {
            return Err(AidingConfigError::Wait(self.wait_s));
        }
        for (source_name, c) in [("flow", &self.flow), ("odometry", &self.odometry)] {
            for (key, value, ok, range) in [
                (
                    "prior",
                    c.prior,
                    (0.2..=5.0).contains(&c.prior),
                    "within [0.2, 5]",
                ),
                (
                    "prior_sigma",
                    c.prior_sigma,
                    (0.0..=1.0).contains(&c.prior_sigma),
                    "within [0, 1]",
                ),
                (
                    "random_walk_per_rts",
                    c.random_walk_per_rts,
                    (0.0..=1.0).contains(&c.random_walk_per_rts),
                    "within [0, 1]",
                ),
                (
                    "sigma_factor",
                    c.sigma_factor,
                    c.sigma_factor > 0.0 && c.sigma_factor <= 100.0,
                    "within (0, 100]",
                ),
                (
                    "gate_sigma",
                    c.gate_sigma,
                    c.gate_sigma > 0.0 && c.gate_sigma <= 100.0,
                    "within (0, 100]",
                ),
            ] {
                if !(value.is_finite() && ok) {
                    return Err(AidingConfigError::Value {
                        source_name,
                        key,
                        range,
                        value,
                    });
                }
            }
        }
        Ok(())
    }
}

/// The scale factors of both sources, as an estimator holds them.
#[derive(Debug, Clone, PartialEq)]
pub struct VelocityScales {
    /// Optical flow's.
    pub flow: ScaleEstimator,
    /// Wheel odometry's.
    pub odometry: ScaleEstimator,
}

impl VelocityScales {
    /// Each at its prior in `aiding`.
    #[must_use]
    pub fn new(aiding: &AidingConfig) -> Self {
        Self {
            flow: ScaleEstimator::new(aiding.flow.clone()),
            odometry: ScaleEstimator::new(aiding.odometry.clone()),
        }
    }

    /// The flow's and the odometry's factors (`measured / true`) and their
    /// standard deviations.
    #[must_use]
    pub fn scales(&self) -> [(f64, f64); 2] {
        [self.flow.scale(), self.odometry.scale()]
    }
}

impl Default for VelocityScales {
    fn default() -> Self {
        Self::new(&AidingConfig::default())
    }
}

/// The online scale factor of one source (module doc).
#[derive(Debug, Clone, PartialEq)]
pub struct ScaleEstimator {
    cfg: ScaleConfig,
    scale: f64,
    var: f64,
    last_ns: Option<u64>,
    used: u64,
    gated: u64,
}

impl ScaleEstimator {
    /// At the prior of `cfg`.
    #[must_use]
    pub fn new(cfg: ScaleConfig) -> Self {
        Self {
            scale: cfg.prior,
            var: cfg.prior_sigma * cfg.prior_sigma,
            cfg,
            last_ns: None,
            used: 0,
            gated: 0,
        }
    }

    /// The factor `measured / true` and its standard deviation.
    #[must_use]
    pub fn scale(&self) -> (f64, f64) {
        (self.scale, self.var.sqrt())
    }

    /// Observations used and gated out.
    #[must_use]
    pub fn counts(&self) -> (u64, u64) {
        (self.used, self.gated)
    }

    /// The settings.
    #[must_use]
    pub fn config(&self) -> &ScaleConfig {
        &self.cfg
    }

    /// Grows the variance by the random walk up to `t_ns`.
    pub fn advance(&mut self, t_ns: u64) {
        if let Some(last) = self.last_ns {
            let dt = t_ns.saturating_sub(last) as f64 * 1e-9;
            let q = self.cfg.random_walk_per_rts;
            self.var += q * q * dt;
        }
        self.last_ns = Some(self.last_ns.map_or(t_ns, |l| l.max(t_ns)));
    }

    /// One axis: `measured` (m/s, standard deviation `sigma`) against the
    /// filter's `predicted` body velocity (variance `predicted_var`).
    /// Returns the measurement corrected for the factor and its standard
    /// deviation, for the filter's update.
    pub fn observe(
        &mut self,
        measured: f64,
        sigma: f64,
        predicted: f64,
        predicted_var: f64,
    ) -> (f64, f64) {
        let sigma = sigma * self.cfg.sigma_factor;
        if self.cfg.prior_sigma > 0.0 {
            let r = sigma * sigma + self.scale * self.scale * predicted_var.max(0.0);
            let s = predicted * predicted * self.var + r;
            let y = measured - self.scale * predicted;
            if s > 0.0 && y * y <= self.cfg.gate_sigma * self.cfg.gate_sigma * s {
                let k = self.var * predicted / s;
                self.scale += k * y;
                self.var = (self.var - k * predicted * self.var).max(0.0);
                // The factor stays physical whatever the data.
                self.scale = self.scale.clamp(0.2, 5.0);
                self.used += 1;
            } else {
                self.gated += 1;
            }
        }
        let corrected = measured / self.scale;
        let var = (sigma * sigma + predicted * predicted * self.var) / (self.scale * self.scale);
        (corrected, var.sqrt())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt as _, SeedableRng as _};
    use rand_distr::StandardNormal;

    /// A sensor that reads 0.85 of the true velocity, with noise, against a
    /// filter that knows the velocity to 0.05 m/s: the factor is found.
    #[test]
    fn a_known_scale_factor_is_recovered() {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(7);
        let mut e = ScaleEstimator::new(ScaleConfig::default());
        for k in 0..3000u64 {
            e.advance(k * 10_000_000);
            let t = k as f64 * 0.01;
            let v = (t * 0.7).sin() * 1.2;
            let n: f64 = rng.sample(StandardNormal);
            let p: f64 = rng.sample(StandardNormal);
            let measured = 0.85 * v + 0.4 * n;
            let (c, s) = e.observe(measured, 0.4, v + 0.05 * p, 0.05 * 0.05);
            assert!(c.is_finite() && s > 0.0);
        }
        let (scale, sigma) = e.scale();
        assert!((scale - 0.85).abs() < 0.03, "{scale} +- {sigma}");
        assert!(sigma < 0.03, "{sigma}");
        assert!(e.counts().0 > 2900, "{:?}", e.counts());
    }

    #[test]
    fn at_rest_the_factor_keeps_its_prior_and_a_fixed_one_never_moves() {
        let mut e = ScaleEstimator::new(ScaleConfig::default());
        for k in 0..100u64 {
            e.advance(k * 10_000_000);
            let _ = e.observe(0.01, 0.3, 0.0, 0.01);
        }
        assert!((e.scale().0 - 1.0).abs() < 1e-9);
        let mut fixed = ScaleEstimator::new(ScaleConfig {
            prior: 0.9,
            prior_sigma: 0.0,
            ..ScaleConfig::default()
        });
        let (c, s) = fixed.observe(0.9, 0.1, 2.0, 0.0);
        assert_eq!(fixed.scale().0, 0.9);
        assert!((c - 1.0).abs() < 1e-12 && (s - 0.1 / 0.9).abs() < 1e-12);
    }

    #[test]
    fn a_bad_setting_names_its_key() {
        let mut c = AidingConfig::default();
        c.odometry.sigma_factor = 0.0;
        let e = c.validate().unwrap_err().to_string();
        assert!(e.contains("aiding.odometry.sigma_factor"), "{e}");
        assert!(AidingConfig::default().validate().is_ok());
    }
}
