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
//! prior). It is observed on baselines (`close_baseline`): the distance
//! the source's raw samples integrate to between two UWB fixes at least
//! `loose.scale_baseline_m` apart, against the distance between the fixes
//! along it (with their covariances). The fixes are the UWB alone, which
//! the velocity source does not drive; the filter's own velocity is no
//! such reference, since the source itself pulls it: observed against it,
//! the factor and the velocity confirm each other and run away together
//! (the tight filter on `ground-outage` with odometry: metres of error).
//! Loose and tight filters observe the factor the same way. Each velocity
//! update then uses `m / s` and a variance grown by what `s` is not known
//! to (`p² var(s)` at the filter's predicted body velocity `p`:
//! `scale_corrected`). The factor is observable only while the vehicle
//! moves; at rest it keeps its prior or its last estimate.

use insuwb_msg::{BodyVelocity, Height};
use nalgebra::{UnitQuaternion, Vector3};
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
    /// The range finder's height (`insuwb_msg::Height` samples).
    pub height: HeightConfig,
}

/// The height a range finder gives (`[fusion.aiding.height]`, from
/// [`insuwb_msg::Height`] samples: the flow deck's VL53L1x, a downward
/// lidar): `(range + range_offset_m) · R33` above the floor at ENU z = 0,
/// with `R33` the filter's `cos` of its tilt, as one update per reading
/// of the tight filter. With the first one the tight filter also turns on
/// a state for the height at which the UWB places the tag above the
/// vehicle's (`insuwb_eskf::Eskf::enable_radio_height`): the radio's
/// height error is then not the vehicle's, and the radio's horizontal is
/// weighted as it would be alone. The loose filters' vertical loop steers
/// to the last such height instead of the fix's while it is at most 0.5 s
/// old.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HeightConfig {
    /// Standard deviation of one height, m; 0 (default): no height
    /// updates.
    pub sigma_m: f64,
    /// Added to the range before it is turned into a height, m: the range
    /// finder's distance below the IMU along body z, and its reading's
    /// offset. Default 0.
    pub range_offset_m: f64,
    /// Stationary sigma of the radio's height state, m. Default 0.3.
    pub radio_sigma_m: f64,
    /// Its correlation time, s. Default 30.
    pub radio_corr_time_s: f64,
}

/// Test settings: the range finder's height on, sigma 0.03 m, the range
/// 0.05 m longer.
#[cfg(test)]
pub(crate) fn height_aiding() -> AidingConfig {
    AidingConfig {
        height: HeightConfig {
            sigma_m: 0.03,
            range_offset_m: 0.05,
            ..HeightConfig::default()
        },
        ..AidingConfig::default()
    }
}

impl HeightConfig {
    /// The height (ENU z of the IMU) that `m`'s range gives at attitude
    /// `att`: `(range + range_offset_m) R33`; `None` while height updates
    /// are off.
    #[must_use]
    pub fn height_m(&self, m: &Height, att: &UnitQuaternion<f64>) -> Option<f64> {
        (self.sigma_m > 0.0).then(|| (m.range_m + self.range_offset_m) * (att * Vector3::z()).z)
    }
}

impl Default for HeightConfig {
    fn default() -> Self {
        Self {
            sigma_m: 0.0,
            range_offset_m: 0.0,
            radio_sigma_m: 0.3,
            radio_corr_time_s: 30.0,
        }
    }
}

impl Default for AidingConfig {
    fn default() -> Self {
        Self {
            wait_s: 0.25,
            flow: ScaleConfig::default(),
            odometry: ScaleConfig::default(),
            height: HeightConfig::default(),
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
        /// `flow`, `odometry` or `height`.
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
        let check = |source_name, key, value: f64, ok: bool, range| {
            if value.is_finite() && ok {
                Ok(())
            } else {
                Err(AidingConfigError::Value {
                    source_name,
                    key,
                    range,
                    value,
                })
            }
        };
        let h = &self.height;
        for (key, value, ok, range) in [
            (
                "sigma_m",
                h.sigma_m,
                (0.0..=10.0).contains(&h.sigma_m),
                "within [0, 10]",
            ),
            (
                "range_offset_m",
                h.range_offset_m,
                (-1.0..=1.0).contains(&h.range_offset_m),
                "within [-1, 1]",
            ),
            (
                "radio_sigma_m",
                h.radio_sigma_m,
                h.radio_sigma_m > 0.0 && h.radio_sigma_m <= 10.0,
                "within (0, 10]",
            ),
            (
                "radio_corr_time_s",
                h.radio_corr_time_s,
                h.radio_corr_time_s > 0.0 && h.radio_corr_time_s <= 3600.0,
                "within (0, 3600]",
            ),
        ] {
            check("height", key, value, ok, range)?;
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
                check(source_name, key, value, ok, range)?;
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
    /// The baselines each is observed on.
    flow_baseline: Baseline,
    odometry_baseline: Baseline,
}

impl VelocityScales {
    /// Each at its prior in `aiding`.
    #[must_use]
    pub fn new(aiding: &AidingConfig) -> Self {
        Self {
            flow: ScaleEstimator::new(aiding.flow.clone()),
            odometry: ScaleEstimator::new(aiding.odometry.clone()),
            flow_baseline: Baseline::default(),
            odometry_baseline: Baseline::default(),
        }
    }

    /// A body velocity of the INS attitude `att` (body to ENU): its
    /// source's factor is advanced to its time and its raw horizontal
    /// velocity added to the source's baseline. Returns the source's
    /// factor, `None` for a source with none.
    pub fn on_sample(
        &mut self,
        m: &BodyVelocity,
        att: &UnitQuaternion<f64>,
    ) -> Option<&mut ScaleEstimator> {
        let (scale, baseline) = match m.source {
            BodyVelocity::SOURCE_ODOMETRY => (&mut self.odometry, &mut self.odometry_baseline),
            BodyVelocity::SOURCE_FLOW => (&mut self.flow, &mut self.flow_baseline),
            _ => return None,
        };
        let t_ns = m.header.meas_time_ns;
        scale.advance(t_ns);
        let mut body = Vector3::zeros();
        let mut sigma_max: f64 = 0.0;
        for (i, (&value, &sigma)) in m.vel_mps.iter().zip(&m.sigma_mps).enumerate() {
            if sigma > 0.0 {
                body[i] = value;
                sigma_max = sigma_max.max(sigma);
            }
        }
        let nav = att * body;
        baseline.push(t_ns, [nav.x, nav.y], sigma_max);
        Some(scale)
    }

    /// At a UWB fix at `t_ns` (the body's horizontal position `body_pos`,
    /// ENU, with covariance `cov`): each source's baseline at least
    /// `min_m` long is an observation of its factor, and the next one
    /// opens.
    pub fn on_fix(&mut self, t_ns: u64, body_pos: [f64; 2], cov: [[f64; 2]; 2], min_m: f64) {
        for (base, scale) in [
            (&mut self.odometry_baseline, &mut self.odometry),
            (&mut self.flow_baseline, &mut self.flow),
        ] {
            close_baseline(base, scale, t_ns, body_pos, cov, min_m);
        }
    }

    /// Breaks both baselines (after a reset of the filter).
    pub fn break_baselines(&mut self) {
        self.flow_baseline = Baseline::default();
        self.odometry_baseline = Baseline::default();
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

    /// One observation `measured = s · reference + noise`: `measured`
    /// (standard deviation `sigma`, before `sigma_factor`) against
    /// `reference` (variance `reference_var`), e.g. the distance a
    /// source's samples integrate to against the distance between two
    /// fixes (`close_baseline`). Returns the measurement corrected for
    /// the factor and its standard deviation.
    pub fn observe(
        &mut self,
        measured: f64,
        sigma: f64,
        reference: f64,
        reference_var: f64,
    ) -> (f64, f64) {
        let sigma = sigma * self.cfg.sigma_factor;
        if self.cfg.prior_sigma > 0.0 {
            let r = sigma * sigma + self.scale * self.scale * reference_var.max(0.0);
            let s = reference * reference * self.var + r;
            let y = measured - self.scale * reference;
            if s > 0.0 && y * y <= self.cfg.gate_sigma * self.cfg.gate_sigma * s {
                let k = self.var * reference / s;
                self.scale += k * y;
                self.var = (self.var - k * reference * self.var).max(0.0);
                // The factor stays physical whatever the data.
                self.scale = self.scale.clamp(0.2, 5.0);
                self.used += 1;
            } else {
                self.gated += 1;
            }
        }
        let corrected = measured / self.scale;
        let var = (sigma * sigma + reference * reference * self.var) / (self.scale * self.scale);
        (corrected, var.sqrt())
    }
}

/// Longest interval between two samples of a velocity source (and from
/// the last one to a fix) that a baseline integrates across, ns.
const BASELINE_MAX_GAP_NS: u64 = 500_000_000;

/// The displacement a velocity source's samples integrate to since the UWB
/// fix that opened the baseline (`loose.scale_baseline_m`), for
/// the source's scale factor.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Baseline {
    /// The fix that opened it: horizontal position of the body (the
    /// antenna less its lever arm), m, and its covariance, m^2.
    start: Option<([f64; 2], [[f64; 2]; 2])>,
    /// Displacement from the raw measurements, ENU, m.
    disp_m: [f64; 2],
    /// Its variance from the samples' noise, m^2.
    var_m2: f64,
    /// Time up to which it is integrated (ns), the last sample's
    /// horizontal velocity (ENU, m/s) and its largest standard deviation.
    last: Option<(u64, [f64; 2], f64)>,
}

impl Baseline {
    /// Integrates a sample at `t_ns` (trapezoid from the previous one); a
    /// gap longer than [`BASELINE_MAX_GAP_NS`] breaks the baseline.
    fn push(&mut self, t_ns: u64, vel_en: [f64; 2], sigma: f64) {
        match self.last {
            Some((t0, v0, s0)) if t_ns >= t0 && t_ns - t0 <= BASELINE_MAX_GAP_NS => {
                let dt = (t_ns - t0) as f64 * 1e-9;
                for (d, (a, b)) in self.disp_m.iter_mut().zip(v0.iter().zip(&vel_en)) {
                    *d += 0.5 * (a + b) * dt;
                }
                let s = 0.5 * (s0 + sigma);
                self.var_m2 += s * s * dt * dt;
            }
            Some((t0, ..)) if t_ns < t0 => return,
            _ => self.start = None,
        }
        self.last = Some((t_ns, vel_en, sigma));
    }

    /// At a fix at `t_ns`: the baseline's displacement and variance up to
    /// it, the last sample held (None when the source has not been heard
    /// from within [`BASELINE_MAX_GAP_NS`]: the baseline is broken).
    fn extend_to(&mut self, t_ns: u64) -> Option<([f64; 2], f64)> {
        let Some((t0, v, sigma)) = self.last else {
            self.start = None;
            return None;
        };
        if t_ns < t0 || t_ns - t0 > BASELINE_MAX_GAP_NS {
            self.start = None;
            return None;
        }
        let dt = (t_ns - t0) as f64 * 1e-9;
        for (d, a) in self.disp_m.iter_mut().zip(&v) {
            *d += a * dt;
        }
        self.var_m2 += sigma * sigma * dt * dt;
        self.last = Some((t_ns, v, sigma));
        Some((self.disp_m, self.var_m2))
    }

    /// Opens a baseline at a fix.
    fn open(&mut self, body_pos: [f64; 2], cov: [[f64; 2]; 2]) {
        self.start = Some((body_pos, cov));
        self.disp_m = [0.0; 2];
        self.var_m2 = 0.0;
    }
}

/// At a UWB fix (`body_pos`, horizontal, with covariance `cov`) at `t_ns`:
/// closes the source's baseline when it is `min_m` long, as an observation
/// of its scale factor (the distance its samples integrate to against the
/// distance between the fixes along it), and opens the next one.
fn close_baseline(
    base: &mut Baseline,
    scale: &mut ScaleEstimator,
    t_ns: u64,
    body_pos: [f64; 2],
    cov: [[f64; 2]; 2],
    min_m: f64,
) {
    let Some((disp, var)) = base.extend_to(t_ns) else {
        return;
    };
    let Some((p0, c0)) = base.start else {
        base.open(body_pos, cov);
        return;
    };
    let dist = disp[0].hypot(disp[1]);
    if dist < min_m {
        return;
    }
    let u = [disp[0] / dist, disp[1] / dist];
    let fixes = u[0] * (body_pos[0] - p0[0]) + u[1] * (body_pos[1] - p0[1]);
    let mut fixes_var = 0.0;
    for r in 0..2 {
        for c in 0..2 {
            fixes_var += u[r] * u[c] * (c0[r][c] + cov[r][c]);
        }
    }
    scale.advance(t_ns);
    let _ = scale.observe(dist, var.sqrt(), fixes, fixes_var);
    base.open(body_pos, cov);
}

/// The measurement `measured` (standard deviation `sigma`) corrected for
/// the factor of `scale`, and its standard deviation grown by what the
/// factor is not known to at the predicted value `predicted`: what
/// [`ScaleEstimator::observe`] returns, without observing.
pub(crate) fn scale_corrected(
    scale: &ScaleEstimator,
    measured: f64,
    sigma: f64,
    predicted: f64,
) -> (f64, f64) {
    let (s, sd) = scale.scale();
    let sigma = sigma * scale.config().sigma_factor;
    let var = sigma * sigma + predicted * predicted * sd * sd;
    (measured / s, var.sqrt() / s)
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
        for (key, set) in [
            (
                "sigma_m",
                (|h: &mut HeightConfig| h.sigma_m = -0.01) as fn(&mut HeightConfig),
            ),
            ("range_offset_m", |h| h.range_offset_m = f64::NAN),
            ("radio_sigma_m", |h| h.radio_sigma_m = 0.0),
            ("radio_corr_time_s", |h| h.radio_corr_time_s = f64::INFINITY),
        ] {
            let mut c = AidingConfig::default();
            set(&mut c.height);
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains(&format!("aiding.height.{key}")), "{e}");
        }
    }
}
