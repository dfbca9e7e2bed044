//! The optical-flow deck's measurement model: pixel flow, the range
//! finder's distance and the body rates give the body-frame velocity
//! ([`BodyVelocity`], source flow), which carries that distance
//! (`range_mm`); each range finder reading in the deck's range is also a
//! height ([`Height`], [`range_heights`]) for a filter.
//!
//! The model is the Crazyflie firmware's (bitcraze/crazyflie-firmware,
//! `src/modules/src/kalman_core/mm_flow.c` and
//! `src/deck/drivers/src/flowdeck_v1v2.c`): the PMW3901 sensor looks down
//! through an aperture of `aperture_rad` (0.71674 rad) spread over
//! `pixels` (35); its motion counts are [`FlowDeck::counts_per_pixel`] (10)
//! per pixel; a camera at distance `d` along the body z axis from the floor
//! that moves at `v` in the body frame while turning at `ω` sees
//!
//! ```text
//! n_x = dt · (pixels / aperture) · (v_x / d - ω_y)
//! n_y = dt · (pixels / aperture) · (v_y / d + ω_x)
//! ```
//!
//! pixels in `dt` (the firmware writes `d` as `z / R22`, the height over the
//! tilt; the range finder measures `d` itself). The deck is mounted turned,
//! so the body's `n_x` is the sensor's `-deltaY` and `n_y` its `-deltaX`
//! (the firmware's "flip motion information to comply with sensor
//! mounting"). Solved for the velocity:
//!
//! ```text
//! v_x = d · (n_x · aperture / (pixels · dt) + ω_y)
//! v_y = d · (n_y · aperture / (pixels · dt) - ω_x)
//! ```
//!
//! with `ω` the mean gyro rate over the flow interval. The standard
//! deviation is the firmware's fixed flow noise (`flowStdFixed`, 2 counts)
//! carried through the same scale: `σ_v = d · σ_counts / counts_per_pixel ·
//! aperture / (pixels · dt)`, about 0.4 m/s per metre of range at 100 Hz.
//! Checked on the 16 UTIL flights that carry flow against the motion
//! capture's body velocity (`python3 tools/util_flow_check.py
//! ../shared/data/util`): the per-read error has a robust SD of 0.41-0.57
//! m/s at 1-2 m, the stated SD is honest or conservative (median NEES
//! 0.5-1.1 per flight), the velocity is not late, and its scale is 0.77-1.06
//! of the truth's, a factor of each flight.
//!
//! The deck reads the sensor every 10 ms and reports only frames with
//! motion: an interval between two records longer than
//! [`FlowDeck::max_interval_s`] is a frame's own period
//! ([`FlowDeck::period_s`]), not the gap. A flow record is refused, and
//! counted by reason in [`FlowStats`], when no range was measured within
//! [`FlowDeck::max_range_age_s`] before it, when the range is outside
//! [`FlowDeck::min_range_m`]..[`FlowDeck::max_range_m`] (on the floor the
//! sensor is out of focus; beyond the range finder's reach the distance is
//! not known), or when no IMU sample covers it.

use insuwb_msg::{BodyVelocity, Header, Height, ImuSample};
use serde::{Deserialize, Serialize};

/// One flow-deck record: motion counts since the previous read, in the
/// sensor's own axes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FlowRecord {
    /// When the deck read the sensor, ns.
    pub t_ns: u64,
    /// The sensor's `deltaX` counts.
    pub delta_x: f64,
    /// The sensor's `deltaY` counts.
    pub delta_y: f64,
}

/// One range-finder record: distance to the floor along the body z axis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RangeRecord {
    /// When it was measured, ns.
    pub t_ns: u64,
    /// The distance, m.
    pub range_m: f64,
}

/// The flow deck's constants and the limits of its use (module doc).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FlowDeck {
    /// Pixels across the aperture (firmware `Npix`, 35).
    pub pixels: f64,
    /// Aperture the pixels span, rad (firmware `thetapix`, 0.71674).
    pub aperture_rad: f64,
    /// Motion counts per pixel (firmware `1 / FLOW_RESOLUTION`, 10).
    pub counts_per_pixel: f64,
    /// Standard deviation of one read's counts (firmware `flowStdFixed`, 2).
    pub sigma_counts: f64,
    /// The deck's read period, s (10 ms).
    pub period_s: f64,
    /// Longest interval between two records taken as the flow's own, s;
    /// longer: frames without motion were not reported, the record covers
    /// one period.
    pub max_interval_s: f64,
    /// Shortest usable range, m.
    pub min_range_m: f64,
    /// Longest usable range, m (the VL53L1x reaches about 4 m).
    pub max_range_m: f64,
    /// Oldest range measurement used for a flow record, s.
    pub max_range_age_s: f64,
}

impl Default for FlowDeck {
    fn default() -> Self {
        Self {
            pixels: 35.0,
            aperture_rad: 0.71674,
            counts_per_pixel: 10.0,
            sigma_counts: 2.0,
            period_s: 0.01,
            max_interval_s: 0.015,
            min_range_m: 0.1,
            max_range_m: 4.0,
            max_range_age_s: 0.2,
        }
    }
}

/// A [`FlowDeck`] value out of range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FlowDeckError {
    /// A value is not finite and positive (or the range limits are not ordered).
    #[error("flow.{key} must be finite and positive (and min_range_m < max_range_m), got {value}")]
    Value {
        /// The key.
        key: &'static str,
        /// Its value.
        value: f64,
    },
}

impl FlowDeck {
    /// Checks every value, naming the first offending key.
    ///
    /// # Errors
    /// [`FlowDeckError::Value`].
    pub fn validate(&self) -> Result<(), FlowDeckError> {
        for (key, value) in [
            ("pixels", self.pixels),
            ("aperture_rad", self.aperture_rad),
            ("counts_per_pixel", self.counts_per_pixel),
            ("sigma_counts", self.sigma_counts),
            ("period_s", self.period_s),
            ("max_interval_s", self.max_interval_s),
            ("min_range_m", self.min_range_m),
            ("max_range_m", self.max_range_m),
            ("max_range_age_s", self.max_range_age_s),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(FlowDeckError::Value { key, value });
            }
        }
        if self.min_range_m >= self.max_range_m {
            return Err(FlowDeckError::Value {
                key: "min_range_m",
                value: self.min_range_m,
            });
        }
        Ok(())
    }

    /// Body velocity (x, y) and its standard deviation from one read:
    /// `counts` the sensor's `(deltaX, deltaY)`, `dt_s` the interval it
    /// covers, `range_m` the distance along body z, `gyro_rps` the mean body
    /// rates over the interval (module doc).
    #[must_use]
    pub fn velocity(
        &self,
        counts: (f64, f64),
        dt_s: f64,
        range_m: f64,
        gyro_rps: [f64; 3],
    ) -> ([f64; 2], f64) {
        let rad_per_count = self.aperture_rad / (self.pixels * self.counts_per_pixel);
        let n_x = -counts.1;
        let n_y = -counts.0;
        let vx = range_m * (n_x * rad_per_count / dt_s + gyro_rps[1]);
        let vy = range_m * (n_y * rad_per_count / dt_s - gyro_rps[0]);
        let sigma = range_m * self.sigma_counts * rad_per_count / dt_s;
        ([vx, vy], sigma)
    }
}

/// Flow records turned into velocities, and those refused by reason.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct FlowStats {
    /// Flow records read.
    pub records: u64,
    /// Velocities produced.
    pub velocities: u64,
    /// No range measured within `max_range_age_s` before the record.
    pub no_range: u64,
    /// The range below `min_range_m` (on or near the floor).
    pub range_low: u64,
    /// The range above `max_range_m` (out of the range finder's reach).
    pub range_high: u64,
    /// No IMU sample within the record's interval (no body rates).
    pub no_gyro: u64,
    /// A record at or before the previous one's time.
    pub time_backwards: u64,
}

/// Range-finder records turned into heights, and those refused by reason.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct HeightStats {
    /// Range records read.
    pub records: u64,
    /// Heights produced.
    pub heights: u64,
    /// The range not finite, or below `min_range_m` (on or near the
    /// floor, where the sensor reads 0 or too short).
    pub range_low: u64,
    /// The range above `max_range_m` (out of the range finder's reach).
    pub range_high: u64,
    /// A record at or before the previous one's time.
    pub time_backwards: u64,
}

/// The heights of one flight's range records (sorted by time): each reading
/// within the deck's [`FlowDeck::min_range_m`]..[`FlowDeck::max_range_m`],
/// as the flow velocities use them, at its own time (`header.seq` counting
/// from 0); the others refused and counted by reason.
#[must_use]
pub fn range_heights(ranges: &[RangeRecord], deck: &FlowDeck) -> (Vec<Height>, HeightStats) {
    let mut stats = HeightStats::default();
    let mut out = Vec::with_capacity(ranges.len());
    let mut prev_t: Option<u64> = None;
    for r in ranges {
        stats.records += 1;
        if prev_t.is_some_and(|p| r.t_ns <= p) {
            stats.time_backwards += 1;
            continue;
        }
        prev_t = Some(r.t_ns);
        if r.range_m.is_nan() || r.range_m < deck.min_range_m {
            stats.range_low += 1;
            continue;
        }
        if r.range_m > deck.max_range_m {
            stats.range_high += 1;
            continue;
        }
        out.push(Height {
            header: Header::new(out.len() as u64, r.t_ns),
            range_m: r.range_m,
            source: Height::SOURCE_RANGE_FINDER,
        });
        stats.heights += 1;
    }
    (out, stats)
}

/// Body velocities from the flow and range records of one flight and its
/// IMU samples (all sorted by time), with the deck model `deck`; stamped
/// at the middle of each flow interval, `header.seq` counting from 0.
#[must_use]
pub fn flow_velocities(
    flow: &[FlowRecord],
    ranges: &[RangeRecord],
    imu: &[ImuSample],
    deck: &FlowDeck,
) -> (Vec<BodyVelocity>, FlowStats) {
    let mut stats = FlowStats::default();
    let mut out = Vec::with_capacity(flow.len());
    let mut prev_t: Option<u64> = None;
    let s_to_ns = |s: f64| (s * 1e9) as u64;
    for f in flow {
        stats.records += 1;
        if prev_t.is_some_and(|p| f.t_ns <= p) {
            stats.time_backwards += 1;
            continue;
        }
        let gap_ns = prev_t.map(|p| f.t_ns - p);
        prev_t = Some(f.t_ns);
        let dt_ns = match gap_ns {
            Some(g) if g <= s_to_ns(deck.max_interval_s) => g,
            _ => s_to_ns(deck.period_s),
        };
        // The newest range at or before the record.
        let j = ranges.partition_point(|r| r.t_ns <= f.t_ns);
        let Some(r) = j.checked_sub(1).and_then(|i| ranges.get(i)) else {
            stats.no_range += 1;
            continue;
        };
        if f.t_ns - r.t_ns > s_to_ns(deck.max_range_age_s) {
            stats.no_range += 1;
            continue;
        }
        if r.range_m < deck.min_range_m {
            stats.range_low += 1;
            continue;
        }
        if r.range_m > deck.max_range_m {
            stats.range_high += 1;
            continue;
        }
        let start = f.t_ns.saturating_sub(dt_ns);
        let a = imu.partition_point(|s| s.header.meas_time_ns < start);
        let b = imu.partition_point(|s| s.header.meas_time_ns <= f.t_ns);
        let Some(window) = imu.get(a..b).filter(|w| !w.is_empty()) else {
            stats.no_gyro += 1;
            continue;
        };
        let mut gyro = [0.0; 3];
        for s in window {
            for (g, v) in gyro.iter_mut().zip(s.gyro_rps) {
                *g += v;
            }
        }
        let n = window.len() as f64;
        let gyro = gyro.map(|g| g / n);
        let dt_s = dt_ns as f64 * 1e-9;
        let ([vx, vy], sigma) = deck.velocity((f.delta_x, f.delta_y), dt_s, r.range_m, gyro);
        out.push(BodyVelocity {
            header: Header::new(out.len() as u64, f.t_ns - dt_ns / 2),
            vel_mps: [vx, vy, 0.0],
            sigma_mps: [sigma, sigma, 0.0],
            source: BodyVelocity::SOURCE_FLOW,
            // Whole mm, as the sensor reports it (`estTOF`'s `zrange`).
            range_mm: BodyVelocity::range_mm_from_m(r.range_m),
        });
        stats.velocities += 1;
    }
    (out, stats)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A camera at known height and velocity, turning: the counts the
    /// firmware's model predicts give back the velocity.
    #[test]
    fn counts_of_a_known_motion_give_its_velocity() {
        let deck = FlowDeck::default();
        let (d, dt) = (1.5, 0.01);
        let (v, w) = ([0.8, -0.3], [0.2, -0.4, 0.1]);
        let k = deck.pixels / deck.aperture_rad * dt * deck.counts_per_pixel;
        let n_x = k * (v[0] / d - w[1]);
        let n_y = k * (v[1] / d + w[0]);
        // The sensor's axes: n_x = -deltaY, n_y = -deltaX.
        let (got, sigma) = deck.velocity((-n_y, -n_x), dt, d, w);
        assert!(
            (got[0] - v[0]).abs() < 1e-12 && (got[1] - v[1]).abs() < 1e-12,
            "{got:?}"
        );
        // 2 counts at 1.5 m over 10 ms: 1.5 * 2 * 0.71674 / 350 / 0.01.
        assert!((sigma - 0.614_349).abs() < 1e-5, "{sigma}");
    }

    fn imu_at(t_ns: u64, gyro: [f64; 3]) -> ImuSample {
        ImuSample {
            header: Header::new(0, t_ns),
            accel_mps2: [0.0, 0.0, 9.81],
            gyro_rps: gyro,
        }
    }

    #[test]
    fn records_without_a_usable_range_or_rates_are_refused_and_counted() {
        let ms = 1_000_000u64;
        let imu: Vec<ImuSample> = (0..400).map(|i| imu_at(i * ms, [0.0; 3])).collect();
        let ranges = [
            RangeRecord {
                t_ns: 30 * ms,
                range_m: 1.0,
            },
            RangeRecord {
                t_ns: 100 * ms,
                range_m: 0.05,
            },
            RangeRecord {
                t_ns: 150 * ms,
                range_m: 5.0,
            },
            RangeRecord {
                t_ns: 200 * ms,
                range_m: 1.234,
            },
        ];
        let rec = |t: u64| FlowRecord {
            t_ns: t * ms,
            delta_x: -3.0,
            delta_y: 6.0,
        };
        let flow = [
            rec(20),  // before any range
            rec(40),  // 1.0 m: kept (interval 20 ms > 15 ms: one period)
            rec(50),  // kept, 10 ms
            rec(50),  // repeated time
            rec(105), // 0.05 m: too low
            rec(155), // 5 m: too high
            rec(210), // kept
            rec(405), // range 205 ms old
        ];
        let (v, s) = flow_velocities(&flow, &ranges, &imu, &FlowDeck::default());
        assert_eq!(
            (
                s.records,
                s.velocities,
                s.no_range,
                s.range_low,
                s.range_high,
                s.time_backwards
            ),
            (8, 3, 2, 1, 1, 1)
        );
        // -deltaY = -6 counts in 10 ms at 1 m: -6 * 0.71674 / 350 / 0.01.
        let want = -6.0 * 0.71674 / 350.0 / 0.01;
        assert!((v[0].vel_mps[0] - want).abs() < 1e-12, "{:?}", v[0]);
        assert!((v[0].vel_mps[1] - 3.0 * 0.71674 / 350.0 / 0.01).abs() < 1e-12);
        assert_eq!(v[0].header.meas_time_ns, 35 * ms);
        assert_eq!(v[1].header.meas_time_ns, 45 * ms);
        // Each carries the range that scaled it, in mm.
        assert_eq!(
            v.iter().map(|b| b.range_mm).collect::<Vec<_>>(),
            [1000, 1000, 1234]
        );
        assert!(v
            .iter()
            .all(|b| insuwb_msg::check::velocity_values(b).is_ok()));
        // Past the IMU's end: no rates.
        let late = [RangeRecord {
            t_ns: 500 * ms,
            range_m: 1.0,
        }];
        let (_, s) = flow_velocities(&[rec(510)], &late, &imu, &FlowDeck::default());
        assert_eq!(s.no_gyro, 1);
    }

    #[test]
    fn readings_in_the_decks_range_are_heights_the_others_are_counted() {
        let ms = 1_000_000u64;
        let r = |t: u64, range_m: f64| RangeRecord {
            t_ns: t * ms,
            range_m,
        };
        let ranges = [
            r(10, 0.05),
            r(20, 1.234),
            r(20, 1.3),
            r(15, 1.3),
            r(30, f64::NAN),
            r(40, 5.0),
            r(50, 1.25),
        ];
        let (h, stats) = range_heights(&ranges, &FlowDeck::default());
        assert_eq!(
            h.iter()
                .map(|h| (h.header.seq, h.header.meas_time_ns / ms, h.range_m))
                .collect::<Vec<_>>(),
            [(0, 20, 1.234), (1, 50, 1.25)]
        );
        assert!(h.iter().all(|h| h.source == Height::SOURCE_RANGE_FINDER));
        assert_eq!(
            stats,
            HeightStats {
                records: 7,
                heights: 2,
                range_low: 2,
                range_high: 1,
                time_backwards: 2,
            }
        );
    }

    #[test]
    fn a_bad_setting_names_its_key() {
        let deck = FlowDeck {
            aperture_rad: f64::NAN,
            ..FlowDeck::default()
        };
        assert!(deck
            .validate()
            .unwrap_err()
            .to_string()
            .contains("flow.aperture_rad"));
        let deck = FlowDeck {
            min_range_m: 5.0,
            ..FlowDeck::default()
        };
        assert!(deck
            .validate()
            .unwrap_err()
            .to_string()
            .contains("min_range_m"));
        assert!(FlowDeck::default().validate().is_ok());
    }
}
