//! The lockstep runner: the whole chain in one process on recorded samples,
//! wired exactly as the stage processes are: the fix builder of the UWB
//! driver, the INS engine of the INS stage and the fusion engine of the
//! fusion stage, each correction handed to the INS at once and the states it
//! re-propagates handed back to fusion. `insuwb eval` runs it ([`run_with`]),
//! so eval and a replay through the pipeline give the same result. Every
//! input first passes the gate of its stream that the drivers hold
//! ([`insuwb_msg::check`]): a sample a driver would refuse is refused here,
//! counted by reason ([`RunOutput::refusals`]) and goes no further.
//!
//! [`Runner`] takes one input at a time ([`Input`], in the order [`merged`]
//! gives); [`run`] and [`run_with`] feed it the recording in time order,
//! [`run_fixes`] and [`run_ins_only`] give the UWB-only and INS-only
//! solutions. With [`FusionConfig::output`] set, the runner applies the
//! fusion stage's coasting and stale-input policy ([`crate::output`]) on the
//! recording's clock, ticking on every input; unset, it publishes the
//! updates' fused states only.

use insuwb_msg::check::{HeightGate, ImuGate, RangeGate, Refusals, TdoaGate, VelocityGate};
use insuwb_msg::{
    BodyVelocity, FilterDiag, FilterKind, FusedState, HasHeader, Height, ImuSample, InsCorrection,
    NavState, UwbFix, UwbRange, UwbTdoa,
};
use insuwb_uwb::fix::{FixBuilder, FixStats, PushError};

use crate::config::{build_estimator, ConfigError, FusionConfig};
use crate::engine::{FusionCounters, FusionEngine, Measurement, Outputs};
use crate::estimator::Estimator;
use crate::ins_engine::{InsCounters, InsEngine};
use crate::output::{OutputPolicy, OutputPolicyConfig};

/// What a run produced.
#[derive(Debug, Clone, Default)]
pub struct RunOutput {
    /// Fused states, one per update (and per reset), and the coasting
    /// states when an output policy is configured.
    pub fused: Vec<FusedState>,
    /// Diagnostics, one per update.
    pub diag: Vec<FilterDiag>,
    /// Corrections sent to the INS.
    pub corrections: Vec<InsCorrection>,
    /// UWB fixes built.
    pub fixes: Vec<UwbFix>,
    /// INS counters.
    pub ins: InsCounters,
    /// Fusion counters.
    pub fusion: FusionCounters,
    /// Inputs refused by the drivers' gates, by reason: what the drivers'
    /// heartbeats count in `dropped_invalid` and `dropped_time`.
    pub refusals: Refusals,
    /// The fix builder's counters, the measurements it refused after the
    /// gate among them (by reason; those still reach a tight filter, as the
    /// UWB driver still publishes them).
    pub fix_stats: FixStats,
}

/// One input sample.
#[derive(Debug, Clone, Copy)]
pub enum Input<'a> {
    /// An IMU sample (to the INS engine).
    Imu(&'a ImuSample),
    /// A TDOA measurement (to the fix builder, and to fusion when the
    /// filter is tightly coupled; corrected by [`FusionConfig::calibration`]
    /// if set).
    Tdoa(&'a UwbTdoa),
    /// A two-way range (to the fix builder, and to fusion when the filter
    /// is tightly coupled).
    Range(&'a UwbRange),
    /// A body-frame velocity (odometry, flow): to fusion, for the filters
    /// that take one.
    Velocity(&'a BodyVelocity),
    /// A height (a range finder's): to fusion, for the filters that take one.
    Height(&'a Height),
}

/// A UWB measurement type the runner takes: a TDOA difference or a
/// two-way range. The recorded streams are slices of one of them.
pub trait UwbInput {
    /// This measurement as a runner input.
    fn input(&self) -> Input<'_>;
    /// Its measurement time, ns.
    fn time_ns(&self) -> u64;
}

impl UwbInput for UwbTdoa {
    fn input(&self) -> Input<'_> {
        Input::Tdoa(self)
    }
    fn time_ns(&self) -> u64 {
        self.header.meas_time_ns
    }
}

impl UwbInput for UwbRange {
    fn input(&self) -> Input<'_> {
        Input::Range(self)
    }
    fn time_ns(&self) -> u64 {
        self.header.meas_time_ns
    }
}

impl Input<'_> {
    /// Its measurement time, ns.
    #[must_use]
    pub fn time(&self) -> u64 {
        match self {
            Self::Imu(s) => s.header.meas_time_ns,
            Self::Tdoa(m) => m.header.meas_time_ns,
            Self::Range(m) => m.header.meas_time_ns,
            Self::Velocity(v) => v.header.meas_time_ns,
            Self::Height(h) => h.header.meas_time_ns,
        }
    }
}

/// Which input goes first when an IMU sample and a TDOA measurement have
/// the same time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Ties {
    /// The IMU sample (the recording's order; [`run_with`]).
    #[default]
    ImuFirst,
    /// The TDOA measurement: the order samples reach the fusion stage in
    /// real time, a fix one hop from its driver, the INS state of the same
    /// epoch two.
    UwbFirst,
}

/// Merges two time-sorted streams into one, ties broken as `ties` says.
pub fn merged<'a, U: UwbInput>(
    imu: &'a [ImuSample],
    tdoa: &'a [U],
    ties: Ties,
) -> impl Iterator<Item = Input<'a>> {
    let (mut i, mut j) = (0usize, 0usize);
    std::iter::from_fn(move || {
        let imu_first = match (imu.get(i), tdoa.get(j)) {
            (Some(a), Some(b)) => match ties {
                Ties::ImuFirst => a.header.meas_time_ns <= b.time_ns(),
                Ties::UwbFirst => a.header.meas_time_ns < b.time_ns(),
            },
            (Some(_), None) => true,
            (None, Some(_)) => false,
            (None, None) => return None,
        };
        if imu_first {
            i += 1;
            imu.get(i - 1).map(Input::Imu)
        } else {
            j += 1;
            tdoa.get(j - 1).map(UwbInput::input)
        }
    })
}

/// [`merged`] with the aiding streams, body velocities and heights, each
/// sample after the IMU samples and TDOA measurements of its time (a
/// velocity before a height of the same time).
pub fn merged_aided<'a, U: UwbInput>(
    imu: &'a [ImuSample],
    tdoa: &'a [U],
    velocity: &'a [BodyVelocity],
    height: &'a [Height],
    ties: Ties,
) -> impl Iterator<Item = Input<'a>> {
    let with_velocity = after_their_time(merged(imu, tdoa, ties), velocity, Input::Velocity);
    after_their_time(with_velocity, height, Input::Height)
}

/// `base` with the time-sorted `extra` merged in, each after the inputs of
/// its time.
fn after_their_time<'a, T: HasHeader>(
    base: impl Iterator<Item = Input<'a>>,
    extra: &'a [T],
    wrap: fn(&'a T) -> Input<'a>,
) -> impl Iterator<Item = Input<'a>> {
    let mut base = base.peekable();
    let mut k = 0usize;
    std::iter::from_fn(move || {
        let extra_first = match (base.peek(), extra.get(k)) {
            (Some(b), Some(e)) => e.header().meas_time_ns < b.time(),
            (None, Some(_)) => true,
            (_, None) => false,
        };
        if extra_first {
            k += 1;
            extra.get(k - 1).map(wrap)
        } else {
            base.next()
        }
    })
}

/// The chain in lockstep, fed one input at a time.
#[derive(Debug)]
pub struct Runner {
    imu_gate: ImuGate,
    tdoa_gate: TdoaGate,
    range_gate: RangeGate,
    vel_gate: VelocityGate,
    height_gate: HeightGate,
    ins: InsEngine,
    fixb: FixBuilder,
    fusion: FusionEngine,
    tight: bool,
    /// The output policy's settings until the first input starts it.
    policy_cfg: Option<OutputPolicyConfig>,
    policy: Option<OutputPolicy>,
    /// Time of the newest INS state, ns.
    newest_nav_ns: Option<u64>,
    /// Time of the input being handled, ns.
    now_ns: u64,
    o: Outputs,
    renav: Vec<NavState>,
    out: RunOutput,
}

impl Runner {
    /// The chain of `cfg` around `est`.
    ///
    /// # Errors
    /// An INS, fix builder, engine or output policy configuration that does
    /// not validate.
    pub fn new(cfg: &FusionConfig, est: Box<dyn Estimator>) -> Result<Self, ConfigError> {
        cfg.engine.validate()?;
        if let Some(p) = &cfg.output {
            p.validate()?;
        }
        Ok(Self {
            imu_gate: ImuGate::new(),
            tdoa_gate: TdoaGate::new(),
            range_gate: RangeGate::new(),
            vel_gate: VelocityGate::new(),
            height_gate: HeightGate::new(),
            ins: InsEngine::new(cfg.ins_engine_config())?,
            fixb: FixBuilder::new(cfg.fix.clone())?.with_calibration(cfg.calibration.clone()),
            tight: est.is_tight(),
            fusion: FusionEngine::new(cfg.engine.clone(), est)
                .with_velocity_wait(cfg.aiding.wait_s),
            policy_cfg: cfg.output.clone(),
            policy: None,
            newest_nav_ns: None,
            now_ns: 0,
            o: Outputs::default(),
            renav: Vec::new(),
            out: RunOutput::default(),
        })
    }

    /// The fusion engine (for a caller that warms it up between inputs, as
    /// the fusion stage does).
    pub fn engine_mut(&mut self) -> &mut FusionEngine {
        &mut self.fusion
    }

    /// Handles one input: through its stream's gate (a refused input is
    /// counted and goes no further: the driver would not publish it, so no
    /// stage sees it, nor the output policy's clock), then the INS, or the
    /// fix builder (the UWB driver publishes the fixes a measurement
    /// completes before the measurement itself), then fusion, until no
    /// correction is in flight; then the output policy's tick, if one is
    /// configured.
    pub fn push(&mut self, input: Input<'_>) {
        let passed = match input {
            Input::Imu(s) => self.imu_gate.check(s).is_ok(),
            Input::Tdoa(m) => self.tdoa_gate.check(m).is_ok(),
            Input::Range(m) => self.range_gate.check(m).is_ok(),
            Input::Velocity(v) => self.vel_gate.check(v).is_ok(),
            Input::Height(h) => self.height_gate.check(h).is_ok(),
        };
        if !passed {
            return;
        }
        self.now_ns = input.time();
        if let Some(cfg) = self.policy_cfg.take() {
            // Validated in `new`: cannot fail here.
            self.policy = OutputPolicy::new(&cfg, 0, self.now_ns).ok();
        }
        match input {
            Input::Imu(s) => {
                if let Some(n) = self.ins.on_imu(s) {
                    self.newest_nav_ns = Some(n.header.meas_time_ns);
                    self.fusion.on_nav(&n, &mut self.o);
                }
            }
            Input::Tdoa(m) => {
                // Corrected by the site calibration, if any, as the UWB
                // driver publishes it: the fix builder and the tight filter
                // use the same difference.
                let m = self.fixb.calibrate(m);
                // A refusal is counted by reason in the builder's stats
                // (`RunOutput::fix_stats`); the tight filter still gets the
                // measurement, as the driver still publishes it.
                if let Ok(Some(f)) = self.fixb.push(&m) {
                    self.on_fix(f);
                }
                if self.tight {
                    self.fusion
                        .on_measurement(Measurement::Tdoa(m), &mut self.o);
                }
            }
            Input::Range(m) => {
                // Less the tag's range offset estimated so far, as the UWB
                // driver publishes it: the fix builder and the tight filter
                // use the same range.
                let m = self.fixb.correct_range(m);
                if let Ok(Some(f)) = self.fixb.push_range(&m) {
                    self.on_fix(f);
                }
                if self.tight {
                    self.fusion
                        .on_measurement(Measurement::Range(m), &mut self.o);
                }
            }
            Input::Velocity(v) => {
                self.fusion
                    .on_measurement(Measurement::Velocity(*v), &mut self.o);
            }
            Input::Height(h) => {
                self.fusion
                    .on_measurement(Measurement::Height(*h), &mut self.o);
            }
        }
        self.settle();
        if let Some(p) = self.policy.as_mut() {
            let age = self.newest_nav_ns.map(|t| self.now_ns.saturating_sub(t));
            let fusion = &mut self.fusion;
            if let Some(s) = p.on_tick(self.now_ns, age, || fusion.coasting_state()) {
                self.out.fused.push(s);
            }
        }
    }

    /// Ends the run: the fix the builder still holds goes to fusion; what
    /// the run produced.
    #[must_use]
    pub fn finish(mut self) -> RunOutput {
        if let Some(f) = self.fixb.flush() {
            self.on_fix(f);
        }
        self.out.ins = self.ins.counters();
        self.out.fusion = self.fusion.counters();
        self.out.refusals = Refusals {
            imu: *self.imu_gate.refusals(),
            tdoa: *self.tdoa_gate.refusals(),
            velocity: *self.vel_gate.refusals(),
            range: *self.range_gate.refusals(),
            height: *self.height_gate.refusals(),
        };
        self.out.fix_stats = *self.fixb.stats();
        self.out
    }

    fn on_fix(&mut self, f: UwbFix) {
        self.out.fixes.push(f);
        self.fusion.on_measurement(Measurement::Fix(f), &mut self.o);
        self.settle();
        if let Some(p) = self.policy.as_mut() {
            let fusion = &mut self.fusion;
            if let Some(s) = p.on_fix(|| fusion.uwb_only_state(&f)) {
                self.out.fused.push(s);
            }
        }
    }

    /// Delivers corrections to the INS and the re-propagated states back to
    /// fusion until nothing is left in flight.
    fn settle(&mut self) {
        loop {
            for s in &self.o.fused {
                let s = match self.policy.as_mut() {
                    Some(p) => p.on_update(*s, self.now_ns),
                    None => *s,
                };
                self.out.fused.push(s);
            }
            self.out.diag.extend_from_slice(&self.o.diag);
            let corrections: Vec<InsCorrection> = std::mem::take(&mut self.o.corrections);
            self.o.clear();
            if corrections.is_empty() {
                return;
            }
            for c in &corrections {
                self.out.corrections.push(*c);
                self.ins.on_correction(c, &mut self.renav);
                for n in &self.renav {
                    self.fusion.on_nav(n, &mut self.o);
                }
            }
        }
    }
}

/// Runs the closed loop with the filter `kind` over time-sorted IMU and TDOA samples.
///
/// # Errors
/// A configuration that does not validate.
pub fn run<U: UwbInput>(
    imu: &[ImuSample],
    tdoa: &[U],
    cfg: &FusionConfig,
    kind: FilterKind,
) -> Result<RunOutput, ConfigError> {
    let est = build_estimator(kind, cfg)?;
    run_with(imu, tdoa, cfg, est)
}

/// Runs the closed loop with a given estimator over time-sorted IMU and
/// TDOA samples, in the recording's order ([`Ties::ImuFirst`]).
///
/// # Errors
/// A configuration that does not validate.
pub fn run_with<U: UwbInput>(
    imu: &[ImuSample],
    tdoa: &[U],
    cfg: &FusionConfig,
    est: Box<dyn Estimator>,
) -> Result<RunOutput, ConfigError> {
    run_aided(imu, tdoa, &[], &[], cfg, est)
}

/// [`run_with`] with body velocities (odometry, flow) and heights (a range
/// finder) as aiding updates.
///
/// # Errors
/// A configuration that does not validate.
pub fn run_aided<U: UwbInput>(
    imu: &[ImuSample],
    tdoa: &[U],
    velocity: &[BodyVelocity],
    height: &[Height],
    cfg: &FusionConfig,
    est: Box<dyn Estimator>,
) -> Result<RunOutput, ConfigError> {
    let mut r = Runner::new(cfg, est)?;
    for input in merged_aided(imu, tdoa, velocity, height, Ties::ImuFirst) {
        r.push(input);
    }
    Ok(r.finish())
}

/// INS-only: integrates the IMU samples the IMU driver's gate passes from
/// the configured initial state with no correction.
///
/// # Errors
/// An INS configuration that does not validate.
pub fn run_ins_only(imu: &[ImuSample], cfg: &FusionConfig) -> Result<Vec<NavState>, ConfigError> {
    let mut ins = InsEngine::new(cfg.ins_engine_config())?;
    let mut gate = ImuGate::new();
    Ok(imu
        .iter()
        .filter(|s| gate.check(s).is_ok())
        .filter_map(|s| ins.on_imu(s))
        .collect())
}

/// The UWB fixes alone (UWB-only solution): the fixes the UWB driver
/// publishes, from the measurements (TDOA differences or ranges) its gate
/// passes.
///
/// # Errors
/// A fix-builder configuration that does not validate.
pub fn run_fixes<U: UwbInput>(uwb: &[U], cfg: &FusionConfig) -> Result<Vec<UwbFix>, ConfigError> {
    let mut fixb = FixBuilder::new(cfg.fix.clone())?.with_calibration(cfg.calibration.clone());
    let mut tdoa_gate = TdoaGate::new();
    let mut range_gate = RangeGate::new();
    let mut out = Vec::new();
    for m in uwb {
        // A refusal is counted in the builder's stats, as in `Runner::push`.
        let pushed: Result<Option<UwbFix>, PushError> = match m.input() {
            Input::Tdoa(t) if tdoa_gate.check(t).is_ok() => fixb.push(t),
            Input::Range(r) if range_gate.check(r).is_ok() => fixb.push_range(r),
            _ => continue,
        };
        if let Ok(Some(f)) = pushed {
            out.push(f);
        }
    }
    out.extend(fixb.flush());
    Ok(out)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use insuwb_msg::{Header, LAYOUT_VERSION};

    use super::*;

    /// A chain printed with `{:#}` (anyhow, the binaries) names each cause
    /// once: a variant that shows its inner error does not also expose it
    /// as its source.
    #[test]
    fn an_error_shows_its_cause_once() {
        let mut cfg = FusionConfig::default();
        cfg.fix.period_s = -1.0;
        let e = run::<UwbTdoa>(&[], &[], &cfg, FilterKind::Kf).unwrap_err();
        let text = e.to_string();
        assert!(text.starts_with("fix: period_s"), "{text}");
        assert!(std::error::Error::source(&e).is_none(), "{text}");
    }

    #[test]
    fn an_output_policy_that_does_not_validate_is_named() {
        let cfg = FusionConfig {
            output: Some(OutputPolicyConfig {
                coast_rate_hz: -1.0,
                ..OutputPolicyConfig::default()
            }),
            ..FusionConfig::default()
        };
        let e = run::<UwbTdoa>(&[], &[], &cfg, FilterKind::Kf).unwrap_err();
        assert_eq!(e.to_string(), "output.coast_rate_hz: must be > 0, got -1");
    }

    fn imu(k: u64) -> ImuSample {
        ImuSample {
            header: Header::new(k, k * 10_000_000),
            accel_mps2: [0.0, 0.0, 9.80665],
            ..ImuSample::default()
        }
    }

    /// A measurement the gate passes (one pair: it completes no fix).
    fn tdoa(k: u64) -> UwbTdoa {
        UwbTdoa {
            header: Header::new(k, k * 10_000_000),
            anchor_b: 1,
            anchor_b_pos_m: [10.0, 0.0, 0.0],
            ..UwbTdoa::default()
        }
    }

    /// What the drivers' gates refuse goes nowhere (not even to the output
    /// policy's clock) and is counted by reason.
    #[test]
    fn the_runner_refuses_and_counts_what_the_drivers_refuse() {
        use insuwb_msg::check::{ImuRefusals, TdoaRefusals};
        let clean_imu: Vec<ImuSample> = (0..100).map(imu).collect();
        let clean_tdoa: Vec<UwbTdoa> = (0..100).step_by(2).map(tdoa).collect();
        let later = |mut s: ImuSample, edit: fn(&mut ImuSample)| {
            s.header.meas_time_ns += 1_000_000;
            edit(&mut s);
            s
        };
        let mut seeded_imu = Vec::new();
        for (k, s) in clean_imu.iter().enumerate() {
            seeded_imu.push(*s);
            match k {
                50 => seeded_imu.push(later(*s, |s| s.gyro_rps[0] = f64::NAN)),
                60 => seeded_imu.push(*s),
                70 => seeded_imu.push(imu(65)),
                80 => seeded_imu.push(later(*s, |s| s.accel_mps2[1] = 500.0)),
                _ => {}
            }
        }
        let mut seeded_tdoa = Vec::new();
        for (k, m) in clean_tdoa.iter().enumerate() {
            seeded_tdoa.push(*m);
            let mut bad = *m;
            match k {
                10 => bad.anchor_b = 0,
                12 => bad.diff_m = 10.5,
                14 => {}
                16 => bad = tdoa(20),
                18 => bad.anchor_a_pos_m[0] = f64::NAN,
                _ => continue,
            }
            seeded_tdoa.push(bad);
        }
        let cfg = FusionConfig {
            output: Some(OutputPolicyConfig::default()),
            ..FusionConfig::default()
        };
        let clean = run(&clean_imu, &clean_tdoa, &cfg, FilterKind::Kf).unwrap();
        let out = run(&seeded_imu, &seeded_tdoa, &cfg, FilterKind::Kf).unwrap();
        assert_eq!(clean.refusals, Refusals::default());
        assert_eq!(
            out.refusals,
            Refusals {
                imu: ImuRefusals {
                    non_finite: 1,
                    out_of_range: 1,
                    time_backwards: 1,
                    time_repeated: 1,
                },
                tdoa: TdoaRefusals {
                    non_finite: 1,
                    same_anchor: 1,
                    impossible: 1,
                    time_backwards: 1,
                    pair_repeated: 1,
                },
                ..Refusals::default()
            }
        );
        assert_eq!(out.ins, clean.ins);
        assert_eq!(out.fix_stats, clean.fix_stats);
        assert!(!out.fused.is_empty());
        assert_eq!(out.fused, clean.fused);
    }

    fn vel(t: u64, vx: f64) -> BodyVelocity {
        BodyVelocity {
            header: Header::new(t, t * 10_000_000),
            vel_mps: [vx, 0.0, 0.0],
            sigma_mps: [0.1, 0.1, 0.0],
            source: BodyVelocity::SOURCE_FLOW,
            range_mm: 0,
        }
    }

    fn height(t: u64, range_m: f64) -> Height {
        Height {
            header: Header::new(t, t * 10_000_000),
            range_m,
            source: Height::SOURCE_RANGE_FINDER,
        }
    }

    fn letter(x: Input<'_>) -> (char, u64) {
        let c = match x {
            Input::Imu(_) => 'i',
            Input::Tdoa(_) => 't',
            Input::Range(_) => 'r',
            Input::Velocity(_) => 'v',
            Input::Height(_) => 'h',
        };
        (c, x.time() / 10_000_000)
    }

    #[test]
    fn aiding_merges_after_its_time_and_bad_samples_are_refused_and_counted() {
        let i = [imu(0), imu(1), imu(2)];
        let t = [tdoa(1), tdoa(3)];
        let v = [vel(1, 0.5), vel(2, f64::NAN), vel(4, 0.5)];
        let h = [height(1, 1.0), height(3, -0.5), height(4, 1.1)];
        let order: Vec<(char, u64)> = merged_aided(&i, &t, &v, &h, Ties::ImuFirst)
            .map(letter)
            .collect();
        assert_eq!(
            order,
            [
                ('i', 0),
                ('i', 1),
                ('t', 1),
                ('v', 1),
                ('h', 1),
                ('i', 2),
                ('v', 2),
                ('t', 3),
                ('h', 3),
                ('v', 4),
                ('h', 4)
            ]
        );
        let cfg = FusionConfig::default();
        let est = build_estimator(FilterKind::IakfTdoa, &cfg).unwrap();
        let out = run_aided(&i, &t, &v, &h, &cfg, est).unwrap();
        assert_eq!(out.refusals.velocity.non_finite, 1);
        assert_eq!(out.refusals.velocity.total(), 1);
        assert_eq!(out.refusals.height.out_of_range, 1);
        assert_eq!(out.refusals.height.total(), 1);
    }

    #[test]
    fn merged_breaks_ties_as_asked() {
        let i = [imu(0), imu(1), imu(2)];
        let t = [tdoa(1), tdoa(3)];
        let order = |ties| merged(&i, &t, ties).map(letter).collect::<Vec<_>>();
        assert_eq!(
            order(Ties::ImuFirst),
            [('i', 0), ('i', 1), ('t', 1), ('i', 2), ('t', 3)]
        );
        assert_eq!(
            order(Ties::UwbFirst),
            [('i', 0), ('t', 1), ('i', 1), ('i', 2), ('t', 3)]
        );
    }

    /// IMU alone (no UWB): with no output policy nothing is published; with
    /// one the INS-only state coasts at the configured rate after the
    /// timeout, flagged degraded, on the recording's clock.
    #[test]
    fn the_runner_coasts_only_with_an_output_policy() {
        let samples: Vec<ImuSample> = (0..200).map(imu).collect();
        assert!(samples
            .iter()
            .all(|s| s.header.layout_version == LAYOUT_VERSION));
        let mut cfg = FusionConfig::default();
        let out = run::<UwbTdoa>(&samples, &[], &cfg, FilterKind::Kf).unwrap();
        assert!(out.fused.is_empty());
        cfg.output = Some(OutputPolicyConfig::default());
        let out = run::<UwbTdoa>(&samples, &[], &cfg, FilterKind::Kf).unwrap();
        let times: Vec<u64> = out
            .fused
            .iter()
            .map(|s| s.header.meas_time_ns / 10_000_000)
            .collect();
        // 100 Hz IMU: first coasting output 160 ms after the first sample,
        // then every 100 ms.
        assert_eq!(
            times,
            [
                16, 26, 36, 46, 56, 66, 76, 86, 96, 106, 116, 126, 136, 146, 156, 166, 176, 186,
                196
            ]
        );
        for s in &out.fused {
            assert_ne!(s.header.flags & FusedState::FLAG_DEGRADED, 0);
            assert_eq!(s.header.flags & FusedState::FLAG_STALE, 0);
        }
    }

    /// The IMU stops at 490 ms while TDOA measurements go on: the coasting
    /// states built on the last INS state are flagged stale and not valid
    /// once it is older than `stale_ins_timeout_s` (250 ms).
    #[test]
    fn coasting_states_on_old_ins_input_are_stale() {
        let samples: Vec<ImuSample> = (0..50).map(imu).collect();
        let meas: Vec<UwbTdoa> = (50..120).map(tdoa).collect();
        let cfg = FusionConfig {
            output: Some(OutputPolicyConfig::default()),
            ..FusionConfig::default()
        };
        let out = run(&samples, &meas, &cfg, FilterKind::Kf).unwrap();
        let at = |s: &FusedState| s.header.meas_time_ns;
        let pub_ms: Vec<(u64, bool)> = out
            .fused
            .iter()
            .map(|s| {
                assert_ne!(s.header.flags & FusedState::FLAG_DEGRADED, 0);
                let stale = s.header.flags & FusedState::FLAG_STALE != 0;
                assert_eq!(stale, s.header.flags & FusedState::FLAG_VALID == 0);
                (at(s) / 1_000_000, stale)
            })
            .collect();
        // Built on the newest INS state (490 ms) once the IMU stopped;
        // published at 560, 660 (fresh), 760, 860, ... (stale).
        let stale: Vec<bool> = pub_ms.iter().map(|p| p.1).collect();
        assert_eq!(
            stale,
            [false, false, false, false, false, false, true, true, true, true, true]
        );
        assert!(pub_ms.iter().skip(4).all(|p| p.0 == 490), "{pub_ms:?}");
    }
}
