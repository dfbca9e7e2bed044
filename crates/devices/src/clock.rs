//! Maps a device's clock onto the host's CLOCK_MONOTONIC: the
//! [`ClockFilter`].
//!
//! Input: pairs of (device ticks, host time the frame was sent), the host
//! time being the monotonic time the bytes were read minus their time on
//! the wire ([`crate::frame::wire_time_ns`]). That host time is late by a
//! positive, random delay (USB polling, scheduling, buffering), never early.
//! So the host-minus-device offsets `y = h - d` of all samples lie above the
//! true offset line `y(d) = offset + slope * d`, and the samples that came
//! through fastest touch it from above. The filter keeps the lower envelope:
//!
//! 1. The counter is unwrapped (modulus in ticks, nearest step wins) and
//!    turned into nanoseconds `d`.
//! 2. A sliding window (default 30 s) of [`BINS`] equal bins keeps, per
//!    bin, the sample with the smallest offset: a fixed-size ring, no
//!    allocation per sample.
//! 3. The lower convex hull of those minima is built; the fitted line is
//!    the hull edge above the window's mean device time (the line below all
//!    samples that minimises their summed distance to it). Its slope is the
//!    drift, clamped to `max_drift_ppm`.
//! 4. [`ClockFilter::to_host`] maps ticks through that line, plus half a
//!    tick (a counter that reads `k` was sent, on average, half a tick
//!    after `k` began).
//!
//! The filter resets itself (keeping nothing of the old line) when the
//! device clock went backwards further than the tolerance (a reboot), when a
//! sample lies further below the line than `jump_threshold_ns` (the device
//! clock jumped ahead), or when samples stay more than `jump_threshold_ns`
//! above it for `stall_reset_ns` of device time (the device clock slipped
//! back or stalled).
//!
//! ```
//! use insuwb_devices::clock::{ClockConfig, ClockFilter};
//!
//! // A 1 kHz counter (ms), never wrapping, 5 s ahead of the host.
//! let mut clock = ClockFilter::new(1_000_000, None, ClockConfig::default())?;
//! for k in 0..100u64 {
//!     let host_ns = k * 10_000_000 + 200_000; // sent at k*10 ms, read 0.2 ms late
//!     clock.update(5_000 + k * 10, host_ns)?;
//! }
//! let mapped = clock.to_host(5_990).unwrap();
//! assert!(mapped.abs_diff(990_000_000) < 1_000_000);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! Pure and deterministic: integers for the hull, one `f64` for the slope.

/// Bins of the sliding window.
pub const BINS: usize = 256;

/// The largest device time (ns) the filter handles: about 4e13 years, and
/// small enough that no difference of times or offsets overflows.
const MAX_DEVICE_NS: i128 = 1 << 100;

/// How the filter behaves.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClockConfig {
    /// Length of the sliding window the line is fitted on (ns of device
    /// time).
    pub window_ns: u64,
    /// A sample this far below the line is a jump ahead; this far above it
    /// for `stall_reset_ns`, a stall (ns).
    pub jump_threshold_ns: u64,
    /// How long samples may stay above the line by `jump_threshold_ns`
    /// before the filter resets (ns of device time).
    pub stall_reset_ns: u64,
    /// A counter going back by at most this much is a reordered or repeated
    /// sample (ignored); further back, a reboot (reset) (ns).
    pub backward_tolerance_ns: u64,
    /// The largest drift the fit may report (ppm).
    pub max_drift_ppm: f64,
}

impl Default for ClockConfig {
    fn default() -> Self {
        ClockConfig {
            window_ns: 30_000_000_000,
            jump_threshold_ns: 50_000_000,
            stall_reset_ns: 2_000_000_000,
            backward_tolerance_ns: 10_000_000,
            max_drift_ppm: 1_000.0,
        }
    }
}

/// What [`ClockFilter::new`] rejects.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ClockNewError {
    /// A tick must last at least 1 ns.
    #[error("ClockNewError::ZeroTick: the device tick must be at least 1 ns")]
    ZeroTick,
    /// A wrapping counter needs a modulus of at least 2 ticks.
    #[error("ClockNewError::WrapTooSmall: a counter wrap must be at least 2 ticks")]
    WrapTooSmall,
    /// The window must hold at least one nanosecond per bin.
    #[error("ClockNewError::WindowTooShort: the window must be at least {BINS} ns")]
    WindowTooShort,
}

/// What [`ClockFilter::update`] rejects.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ClockUpdateError {
    /// The counter value is not below the wrap modulus.
    #[error("ClockUpdateError::TicksBeyondWrap: {ticks} is not below the wrap {wrap}")]
    TicksBeyondWrap {
        /// The value received.
        ticks: u64,
        /// The counter's modulus.
        wrap: u64,
    },
    /// The unwrapped device time does not fit the filter's arithmetic.
    #[error("ClockUpdateError::Overflow: the device time is out of range")]
    Overflow,
}

/// Why the filter reset itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ResetCause {
    /// The counter went back further than the tolerance (device reboot).
    Backwards,
    /// A sample lay far below the line (device clock jumped ahead).
    JumpedAhead,
    /// Samples stayed far above the line (device clock stalled or slipped).
    Stalled,
}

/// What one [`ClockFilter::update`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ClockEvent {
    /// The sample was added to the window.
    Accepted,
    /// The counter stepped back within the tolerance: sample ignored.
    Ignored,
    /// The filter reset, then started again from this sample.
    Reset(ResetCause),
}

/// The minimum-offset sample of one bin.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Bin {
    id: i128,
    d: i128,
    y: i128,
}

/// The fitted line `y(d) = y0 + slope * (d - d0)`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Fit {
    d0: i128,
    y0: i128,
    slope: f64,
}

impl Fit {
    fn y_at(&self, d: i128) -> i128 {
        // `as` saturates; so does the sum: absurd device times cannot panic.
        self.y0
            .saturating_add(((d - self.d0) as f64 * self.slope).round() as i128)
    }
}

/// Device clock to host CLOCK_MONOTONIC, by the lower envelope of the
/// offsets over a sliding window.
#[derive(Debug, Clone)]
pub struct ClockFilter {
    cfg: ClockConfig,
    tick_ns: u64,
    wrap: Option<u64>,
    /// Raw and unwrapped ticks of the last accepted sample.
    last: Option<(u64, i128)>,
    last_d: i128,
    bins: Box<[Option<Bin>; BINS]>,
    head_bin: i128,
    bin_width: i128,
    fit: Option<Fit>,
    above_since: Option<i128>,
    resets: u64,
    accepted: u64,
}

impl ClockFilter {
    /// A filter for a counter of `tick_ns` nanoseconds per tick that wraps
    /// at `wrap` ticks (`None`: never).
    pub fn new(tick_ns: u64, wrap: Option<u64>, cfg: ClockConfig) -> Result<Self, ClockNewError> {
        if tick_ns == 0 {
            return Err(ClockNewError::ZeroTick);
        }
        if wrap.is_some_and(|w| w < 2) {
            return Err(ClockNewError::WrapTooSmall);
        }
        if cfg.window_ns < BINS as u64 {
            return Err(ClockNewError::WindowTooShort);
        }
        Ok(ClockFilter {
            cfg,
            tick_ns,
            wrap,
            last: None,
            last_d: 0,
            bins: Box::new([None; BINS]),
            head_bin: 0,
            bin_width: i128::from(cfg.window_ns) / BINS as i128,
            fit: None,
            above_since: None,
            resets: 0,
            accepted: 0,
        })
    }

    /// Forgets the line and the window (the device rebooted).
    pub fn reset(&mut self) {
        self.last = None;
        self.bins.fill(None);
        self.fit = None;
        self.above_since = None;
        self.resets = self.resets.saturating_add(1);
    }

    /// How many times the filter was reset (by itself or by [`reset`]).
    ///
    /// [`reset`]: ClockFilter::reset
    pub fn resets(&self) -> u64 {
        self.resets
    }

    /// Samples accepted since the filter was made.
    pub fn accepted(&self) -> u64 {
        self.accepted
    }

    /// Adds a sample: the device counter `ticks` and the host monotonic time
    /// (ns) it was sent at, as best known (receive time minus wire time).
    pub fn update(&mut self, ticks: u64, host_ns: u64) -> Result<ClockEvent, ClockUpdateError> {
        if let Some(wrap) = self.wrap {
            if ticks >= wrap {
                return Err(ClockUpdateError::TicksBeyondWrap { ticks, wrap });
            }
        }
        let mut reset = None;
        let unwrapped = match self.unwrap(ticks) {
            Some(u) if self.last.is_some_and(|(_, last)| u < last) => {
                let back_ticks = self.last.map_or(0, |(_, last)| last - u);
                let back_ns = back_ticks.saturating_mul(i128::from(self.tick_ns));
                if back_ns <= i128::from(self.cfg.backward_tolerance_ns) {
                    return Ok(ClockEvent::Ignored);
                }
                reset = Some(ResetCause::Backwards);
                i128::from(ticks)
            }
            Some(u) => u,
            None => i128::from(ticks),
        };
        let d = unwrapped
            .checked_mul(i128::from(self.tick_ns))
            .filter(|d| d.abs() <= MAX_DEVICE_NS)
            .ok_or(ClockUpdateError::Overflow)?;
        let y = i128::from(host_ns) - d;
        if reset.is_none() {
            reset = self.check_residual(d, y);
        }
        let (d, y, unwrapped) = match reset {
            Some(_) => {
                self.reset();
                // Restart the unwrapped count at the raw value.
                let d = i128::from(ticks)
                    .checked_mul(i128::from(self.tick_ns))
                    .filter(|d| d.abs() <= MAX_DEVICE_NS)
                    .ok_or(ClockUpdateError::Overflow)?;
                (d, i128::from(host_ns) - d, i128::from(ticks))
            }
            None => (d, y, unwrapped),
        };
        self.last = Some((ticks, unwrapped));
        self.last_d = d;
        self.insert(d, y);
        self.refit();
        self.accepted = self.accepted.saturating_add(1);
        Ok(reset.map_or(ClockEvent::Accepted, ClockEvent::Reset))
    }

    /// The unwrapped tick count of `ticks`: the value congruent to it
    /// (modulo the wrap) nearest the last sample's.
    fn unwrap(&self, ticks: u64) -> Option<i128> {
        let (last_raw, last_unwrapped) = self.last?;
        let Some(wrap) = self.wrap else {
            return Some(i128::from(ticks));
        };
        let wrap = i128::from(wrap);
        let forward = (i128::from(ticks) - i128::from(last_raw)).rem_euclid(wrap);
        let step = if forward <= wrap / 2 {
            forward
        } else {
            forward - wrap
        };
        Some(last_unwrapped + step)
    }

    /// Whether the sample `(d, y)` says the device clock jumped.
    fn check_residual(&mut self, d: i128, y: i128) -> Option<ResetCause> {
        let fit = self.fit?;
        let residual = y - fit.y_at(d);
        let threshold = i128::from(self.cfg.jump_threshold_ns);
        if residual < -threshold {
            return Some(ResetCause::JumpedAhead);
        }
        if residual <= threshold {
            self.above_since = None;
            return None;
        }
        let since = *self.above_since.get_or_insert(d);
        (d - since >= i128::from(self.cfg.stall_reset_ns)).then_some(ResetCause::Stalled)
    }

    fn slot(&self, id: i128) -> usize {
        // rem_euclid of a positive modulus is in 0..BINS.
        id.rem_euclid(BINS as i128) as usize
    }

    /// Keeps `(d, y)` if it is its bin's smallest offset; slides the window.
    fn insert(&mut self, d: i128, y: i128) {
        let id = d.div_euclid(self.bin_width);
        let fresh = self.fit.is_none() && self.bins.iter().all(Option::is_none);
        if fresh || id - self.head_bin >= BINS as i128 {
            self.bins.fill(None);
        } else {
            for old in self.head_bin + 1..=id {
                let slot = self.slot(old);
                if let Some(b) = self.bins.get_mut(slot) {
                    *b = None;
                }
            }
        }
        if fresh || id > self.head_bin {
            self.head_bin = id;
        }
        let slot = self.slot(id);
        if let Some(b) = self.bins.get_mut(slot) {
            match b {
                Some(old) if old.id == id && old.y <= y => {}
                _ => *b = Some(Bin { id, d, y }),
            }
        }
    }

    /// Fits the line on the lower hull of the window's bin minima.
    fn refit(&mut self) {
        let mut hull = [(0i128, 0i128); BINS];
        let mut n = 0usize;
        // Sum of device times after the first point, for the mean.
        let (mut first_d, mut sum_after, mut count) = (None, 0i128, 0i128);
        let oldest = self.head_bin - (BINS as i128 - 1);
        for id in oldest..=self.head_bin {
            let Some(Some(bin)) = self.bins.get(self.slot(id)).copied() else {
                continue;
            };
            if bin.id != id {
                continue;
            }
            let first = *first_d.get_or_insert(bin.d);
            sum_after = sum_after.saturating_add(bin.d - first);
            count += 1;
            let p = (bin.d, bin.y);
            while n >= 2 {
                let (Some(o), Some(a)) = (hull.get(n - 2), hull.get(n - 1)) else {
                    break;
                };
                let cross = (a.0 - o.0)
                    .saturating_mul(p.1 - o.1)
                    .saturating_sub((a.1 - o.1).saturating_mul(p.0 - o.0));
                if cross > 0 {
                    break;
                }
                n -= 1;
            }
            if let Some(h) = hull.get_mut(n) {
                *h = p;
                n += 1;
            }
        }
        let hull = hull.get(..n).unwrap_or(&[]);
        let Some(&(d_first, y_first)) = hull.first() else {
            self.fit = None;
            return;
        };
        let max_slope = self.cfg.max_drift_ppm.abs() * 1e-6;
        let mean_d = d_first + if count > 0 { sum_after / count } else { 0 };
        let edge = hull
            .windows(2)
            .find(|w| matches!(w, [_, b] if b.0 >= mean_d))
            .or_else(|| hull.windows(2).last());
        self.fit = Some(match edge {
            Some(&[a, b]) => Fit {
                d0: a.0,
                y0: a.1,
                slope: ((b.1 - a.1) as f64 / (b.0 - a.0) as f64).clamp(-max_slope, max_slope),
            },
            // One point: keep the drift we had.
            _ => Fit {
                d0: d_first,
                y0: y_first,
                slope: self.fit.map_or(0.0, |f| f.slope),
            },
        });
    }

    /// The host monotonic time (ns) at which the device counter read
    /// `ticks` (mid-tick); `None` before the first sample or out of range.
    /// `ticks` is unwrapped relative to the last sample.
    pub fn to_host(&self, ticks: u64) -> Option<u64> {
        let fit = self.fit?;
        if self.wrap.is_some_and(|w| ticks >= w) {
            return None;
        }
        let u = self.unwrap(ticks)?;
        let tick = i128::from(self.tick_ns);
        let d = u.checked_mul(tick).filter(|d| d.abs() <= MAX_DEVICE_NS)?;
        let host = d.saturating_add(fit.y_at(d)).saturating_add(tick / 2);
        u64::try_from(host).ok()
    }

    /// Host minus device time (ns) at the last sample, per the fitted line.
    pub fn offset_ns(&self) -> Option<i64> {
        let fit = self.fit?;
        i64::try_from(fit.y_at(self.last_d)).ok()
    }

    /// How fast the device clock runs against the host's (ppm; positive:
    /// the device counts more than the host).
    pub fn drift_ppm(&self) -> Option<f64> {
        // host = d + y(d): dh/dd = 1 + slope; device per host = 1/(1+slope).
        let fit = self.fit?;
        Some((1.0 / (1.0 + fit.slope) - 1.0) * 1e6)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt as _, SeedableRng as _};
    use rand_distr::Exp1;
    use rand_xoshiro::Xoshiro256StarStar;

    /// Seeded delays (xoshiro256** of `rand_xoshiro`, `rand_distr`'s
    /// exponential law).
    struct Rng(Xoshiro256StarStar);

    impl Rng {
        /// Exponential delay, mean 0.5 ms, plus a 5 ms spike one time in 20.
        fn delay_ns(&mut self) -> u64 {
            let exp = 500_000.0 * self.0.sample::<f64, _>(Exp1);
            let spike = if self.0.random_bool(0.05) {
                5_000_000.0
            } else {
                0.0
            };
            (exp + spike) as u64
        }
    }

    /// Runs 10 s of 100 Hz samples from a device clock 100 ppm fast that
    /// reads `start` ticks of `tick_ns` at host time 5 s; returns the
    /// largest mapping error (ns) over the last second, the drift estimate
    /// and the ticks of the first and last samples.
    fn ten_seconds(tick_ns: u64, wrap: Option<u64>, start: u64, seed: u64) -> (u64, f64, u64, u64) {
        let mut clock = ClockFilter::new(tick_ns, wrap, ClockConfig::default()).unwrap();
        let mut rng = Rng(Xoshiro256StarStar::seed_from_u64(seed));
        let t0: u64 = 5_000_000_000;
        let (mut worst, mut first, mut last) = (0u64, None, 0u64);
        for i in 0..1000u64 {
            let sent = t0 + i * 10_000_000;
            let device_ns = ((sent - t0) as f64 * (1.0 + 100e-6)) as u64;
            let mut ticks = start + device_ns / tick_ns;
            if let Some(w) = wrap {
                ticks %= w;
            }
            first.get_or_insert(ticks);
            last = ticks;
            let event = clock.update(ticks, sent + rng.delay_ns()).unwrap();
            assert_eq!(event, ClockEvent::Accepted, "sample {i}");
            if i >= 900 {
                worst = worst.max(clock.to_host(ticks).unwrap().abs_diff(sent));
            }
        }
        (worst, clock.drift_ppm().unwrap(), first.unwrap_or(0), last)
    }

    #[test]
    fn drift_of_100_ppm_and_random_delays_map_within_1_ms_after_10_s() {
        for seed in [1, 2, 3, 0xDEAD_BEEF] {
            let (worst, drift, _, _) = ten_seconds(1_000, None, 123_456_789, seed);
            println!("us counter, seed {seed}: worst {worst} ns, drift {drift:.1} ppm");
            assert!(worst < 1_000_000, "worst error {worst} ns");
            assert!((drift - 100.0).abs() < 20.0, "drift {drift} ppm");
        }
    }

    #[test]
    fn a_u32_ms_counter_wrapping_mid_run_maps_within_1_ms() {
        for seed in [1, 2, 3, 0xDEAD_BEEF] {
            let start = (1u64 << 32) - 3_000; // wraps 3 s into the run
            let (worst, drift, first, last) = ten_seconds(1_000_000, Some(1 << 32), start, seed);
            println!("ms counter, seed {seed}: worst {worst} ns, drift {drift:.1} ppm");
            assert!(
                first > last,
                "the counter must have wrapped: {first} -> {last}"
            );
            assert!(worst < 1_000_000, "worst error {worst} ns");
        }
    }

    #[test]
    fn bad_settings_are_refused() {
        let cfg = ClockConfig::default();
        assert_eq!(
            ClockFilter::new(0, None, cfg).err(),
            Some(ClockNewError::ZeroTick)
        );
        assert_eq!(
            ClockFilter::new(1, Some(1), cfg).err(),
            Some(ClockNewError::WrapTooSmall)
        );
        let short = ClockConfig {
            window_ns: 10,
            ..cfg
        };
        assert_eq!(
            ClockFilter::new(1, None, short).err(),
            Some(ClockNewError::WindowTooShort)
        );
    }

    #[test]
    fn ticks_beyond_the_wrap_are_an_error() {
        let mut c = ClockFilter::new(1_000_000, Some(1000), ClockConfig::default()).unwrap();
        assert_eq!(
            c.update(1000, 0),
            Err(ClockUpdateError::TicksBeyondWrap {
                ticks: 1000,
                wrap: 1000
            })
        );
        assert_eq!(c.to_host(5), None);
    }

    #[test]
    fn a_reboot_resets_and_a_small_step_back_is_ignored() {
        let mut c = ClockFilter::new(1_000_000, Some(1 << 32), ClockConfig::default()).unwrap();
        for k in 0..50u64 {
            assert_eq!(
                c.update(100_000 + k * 10, k * 10_000_000).unwrap(),
                ClockEvent::Accepted
            );
        }
        assert_eq!(c.update(100_485, 0).unwrap(), ClockEvent::Ignored);
        assert_eq!(
            c.update(3, 500_000_000).unwrap(),
            ClockEvent::Reset(ResetCause::Backwards)
        );
        assert_eq!(c.resets(), 1);
        let mapped = c.to_host(3).unwrap();
        assert!(mapped.abs_diff(500_000_000) <= 1_000_000, "{mapped}");
    }

    #[test]
    fn a_jump_ahead_resets() {
        let mut c = ClockFilter::new(1_000, None, ClockConfig::default()).unwrap();
        for k in 0..50u64 {
            c.update(k * 10_000, k * 10_000_000).unwrap();
        }
        // The device claims 1 s passed while the host saw 10 ms.
        let event = c.update(49 * 10_000 + 1_000_000, 500_000_000).unwrap();
        assert_eq!(event, ClockEvent::Reset(ResetCause::JumpedAhead));
    }

    #[test]
    fn a_stall_resets_after_the_stall_time() {
        let mut c = ClockFilter::new(1_000, None, ClockConfig::default()).unwrap();
        for k in 0..100u64 {
            c.update(k * 10_000, k * 10_000_000).unwrap();
        }
        // From now the device clock runs at half speed.
        let mut events = Vec::new();
        for k in 100..1000u64 {
            let ticks = 99 * 10_000 + (k - 99) * 5_000;
            events.push(c.update(ticks, k * 10_000_000).unwrap());
        }
        assert!(events.contains(&ClockEvent::Reset(ResetCause::Stalled)));
    }
}
