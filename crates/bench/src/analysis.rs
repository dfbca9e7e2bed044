//! Latency of one run from its recording: the headers of the samples (their
//! publish times and the sequence numbers and times a fused state carries)
//! and the logger's receive times.
//!
//! Definitions (every figure a difference of CLOCK_MONOTONIC stamps taken
//! by two processes):
//! - `uwb_fusion` (also the end-to-end figure): publish of the UWB fix ->
//!   publish of the fused state it triggered (`FusedState::uwb_pub_time_ns`
//!   to the fused header's `pub_time_ns`); it includes waiting for the INS
//!   state covering the fix epoch;
//! - `ins_fusion`: publish of the INS state used -> fused publish;
//! - `imu_ins`: publish of an IMU sample -> first publish of the INS state
//!   that integrated it (`NavState::imu_seq`; re-propagated states are later
//!   publications of the same sample and are not counted);
//! - `fusion_logger`: fused publish -> the logger's receive;
//! - period jitter: `|t_pub(k+1) - t_pub(k) - period|` for fused states of
//!   consecutive fixes;
//! - a missed cycle: a fix of the steady state with no fused state naming it.
//!
//! The steady state starts at the first fused state from a UWB update plus
//! [`AnalysisConfig::warmup_s`] (missed cycles are counted from the first
//! fused state itself) and ends [`AnalysisConfig::tail_s`] before the last
//! IMU sample or fix (shutdown stops the sources first). Sequence numbers
//! are matched within one run without restarts (a restarted publisher counts
//! from 0 again).

use std::collections::HashMap;

use hdrhistogram::Histogram;
use insuwb_log::Record;
use insuwb_msg::{FusedState, NavState};
use serde::{Deserialize, Serialize};

use crate::trace::RecvStamp;

/// Settings of [`analyse`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AnalysisConfig {
    /// Samples measured less than this after the first fused state are left
    /// out of the latency and jitter figures (process start-up: first page
    /// faults and wake-ups), s. Default 1.0 (chosen).
    pub warmup_s: f64,
    /// Samples measured less than this before the end of the IMU or UWB
    /// stream are left out (the shutdown stops the sources first), s.
    /// Default 0.5 (chosen: several fix periods).
    pub tail_s: f64,
    /// Nominal period of the fused output, ns: one per UWB fix. Default
    /// 100 000 000 (10 Hz UWB, the paper's rate).
    pub period_ns: u64,
}

impl Default for AnalysisConfig {
    fn default() -> Self {
        Self {
            warmup_s: 1.0,
            tail_s: 0.5,
            period_ns: 100_000_000,
        }
    }
}

/// An [`AnalysisConfig`] value that is not acceptable.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AnalysisConfigError {
    /// `warmup_s` negative or not finite.
    #[error("analysis.warmup_s must be finite and >= 0, got {0}")]
    Warmup(f64),
    /// `tail_s` negative or not finite.
    #[error("analysis.tail_s must be finite and >= 0, got {0}")]
    Tail(f64),
    /// `period_ns` zero.
    #[error("analysis.period_ns must be > 0, got {0}")]
    Period(u64),
}

impl AnalysisConfig {
    /// Checks every value.
    pub fn validate(&self) -> Result<(), AnalysisConfigError> {
        if !(self.warmup_s.is_finite() && self.warmup_s >= 0.0) {
            return Err(AnalysisConfigError::Warmup(self.warmup_s));
        }
        if !(self.tail_s.is_finite() && self.tail_s >= 0.0) {
            return Err(AnalysisConfigError::Tail(self.tail_s));
        }
        if self.period_ns == 0 {
            return Err(AnalysisConfigError::Period(self.period_ns));
        }
        Ok(())
    }
}

/// Why [`analyse`] could not measure a run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AnalysisError {
    /// The settings are invalid.
    #[error(transparent)]
    Config(#[from] AnalysisConfigError),
    /// The recording holds no IMU sample or no UWB fix.
    #[error("the recording holds {imu} IMU samples and {fixes} UWB fixes: nothing to measure")]
    NoInput {
        /// IMU samples recorded.
        imu: usize,
        /// Fixes recorded.
        fixes: usize,
    },
    /// No fused state from a UWB update was recorded.
    #[error("no fused state from a UWB update among {fixes} UWB fixes recorded")]
    NoFused {
        /// Fixes recorded.
        fixes: usize,
    },
}

/// Percentiles of one latency, microseconds.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct Percentiles {
    /// Median, us.
    pub p50_us: f64,
    /// 99th percentile, us.
    pub p99_us: f64,
    /// 99.9th percentile, us.
    pub p999_us: f64,
    /// Largest, us.
    pub max_us: f64,
    /// Values measured (0: every figure is 0).
    #[serde(skip)]
    pub count: u64,
}

/// Largest value a histogram tracks, ns (one hour); larger ones are clamped.
const HIST_MAX_NS: u64 = 3_600_000_000_000;

impl Percentiles {
    /// Percentiles of `values_ns` (nanoseconds) with HdrHistogram at 3
    /// significant digits (each figure within 0.1 % of the exact order
    /// statistic); values above one hour are clamped to it.
    #[must_use]
    pub fn of(values_ns: impl IntoIterator<Item = u64>) -> Self {
        let Ok(mut h) = Histogram::<u64>::new_with_bounds(1, HIST_MAX_NS, 3) else {
            return Self::default();
        };
        for v in values_ns {
            h.saturating_record(v.min(HIST_MAX_NS));
        }
        if h.is_empty() {
            return Self::default();
        }
        let us = |ns: u64| ns as f64 * 1e-3;
        Self {
            p50_us: us(h.value_at_quantile(0.5)),
            p99_us: us(h.value_at_quantile(0.99)),
            p999_us: us(h.value_at_quantile(0.999)),
            max_us: us(h.max()),
            count: h.len(),
        }
    }
}

/// Latency of each hop (see the module documentation for the definitions).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct Hops {
    /// IMU publish -> INS publish.
    pub imu_ins: Percentiles,
    /// INS publish -> fused publish.
    pub ins_fusion: Percentiles,
    /// UWB fix publish -> fused publish.
    pub uwb_fusion: Percentiles,
    /// Fused publish -> logger receive.
    pub fusion_logger: Percentiles,
}

/// What [`analyse`] measured.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct RunLatency {
    /// UWB fix publish -> fused publish (the end-to-end figure).
    pub e2e_uwb_fused: Percentiles,
    /// IMU publish -> INS publish (end to end on the inertial side).
    pub e2e_imu_ins: Percentiles,
    /// Per hop.
    pub hops: Hops,
    /// Deviation of the fused output period from [`AnalysisConfig::period_ns`].
    pub jitter: Percentiles,
    /// Fixes of the steady state (from the first fused state on).
    pub fixes: u64,
    /// Of those, fixes with no fused state naming them.
    pub missed_cycles: u64,
    /// Fused states from UWB updates recorded.
    pub fused: u64,
}

fn is_update(f: &FusedState) -> bool {
    f.header.flags & FusedState::FLAG_DEGRADED == 0
}

/// One steady-state cycle: the CLOCK_MONOTONIC stamps along the path of
/// one fix, for looking at single cycles (`insuwb bench latency --samples`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Cycle {
    /// Sequence number of the fix.
    pub uwb_seq: u64,
    /// Measurement time of the fix (ns).
    pub uwb_meas_ns: u64,
    /// Publish time of the fix (ns).
    pub uwb_pub_ns: u64,
    /// Publish time of the IMU sample the INS state used was built from
    /// (ns; 0 when the recording lacks it).
    pub imu_pub_ns: u64,
    /// Publish time of the INS state the fused state used (ns).
    pub ins_pub_ns: u64,
    /// Publish time of the fused state (ns).
    pub fused_pub_ns: u64,
    /// The logger's receive time of the fused state (ns; 0 when not traced).
    pub logger_recv_ns: u64,
}

impl Cycle {
    /// Header of [`Cycle::csv_row`].
    pub const CSV_HEADER: &'static str =
        "uwb_seq,uwb_meas_ns,uwb_pub_ns,imu_pub_ns,ins_pub_ns,fused_pub_ns,logger_recv_ns";

    /// The cycle as one CSV row (no line end).
    #[must_use]
    pub fn csv_row(&self) -> String {
        format!(
            "{},{},{},{},{},{},{}",
            self.uwb_seq,
            self.uwb_meas_ns,
            self.uwb_pub_ns,
            self.imu_pub_ns,
            self.ins_pub_ns,
            self.fused_pub_ns,
            self.logger_recv_ns
        )
    }
}

/// The raw values of one or more runs, in nanoseconds, before percentiles:
/// runs measured apart (rounds of `insuwb bench latency`) are pooled with
/// [`LatencySamples::extend`] and summarised once ([`LatencySamples::summary`]).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct LatencySamples {
    /// UWB fix publish -> fused publish, per steady-state fused state.
    pub uwb_fusion_ns: Vec<u64>,
    /// INS publish -> fused publish, per steady-state fused state.
    pub ins_fusion_ns: Vec<u64>,
    /// IMU publish -> first INS publish, per steady-state IMU sample.
    pub imu_ins_ns: Vec<u64>,
    /// Fused publish -> logger receive, per steady-state fused state.
    pub fusion_logger_ns: Vec<u64>,
    /// Deviation of the fused output period from the nominal one.
    pub jitter_ns: Vec<u64>,
    /// Fixes from the first fused state on.
    pub fixes: u64,
    /// Of those, fixes with no fused state naming them.
    pub missed_cycles: u64,
    /// Fused states from UWB updates recorded.
    pub fused: u64,
    /// The steady-state cycles, by fix sequence number.
    pub cycles: Vec<Cycle>,
}

impl LatencySamples {
    /// Adds the values of another run.
    pub fn extend(&mut self, other: &Self) {
        self.uwb_fusion_ns.extend_from_slice(&other.uwb_fusion_ns);
        self.ins_fusion_ns.extend_from_slice(&other.ins_fusion_ns);
        self.imu_ins_ns.extend_from_slice(&other.imu_ins_ns);
        self.fusion_logger_ns
            .extend_from_slice(&other.fusion_logger_ns);
        self.jitter_ns.extend_from_slice(&other.jitter_ns);
        self.fixes += other.fixes;
        self.missed_cycles += other.missed_cycles;
        self.fused += other.fused;
        self.cycles.extend_from_slice(&other.cycles);
    }

    /// Percentiles of every figure.
    #[must_use]
    pub fn summary(&self) -> RunLatency {
        let uwb_fusion = Percentiles::of(self.uwb_fusion_ns.iter().copied());
        let imu_ins = Percentiles::of(self.imu_ins_ns.iter().copied());
        RunLatency {
            e2e_uwb_fused: uwb_fusion,
            e2e_imu_ins: imu_ins,
            hops: Hops {
                imu_ins,
                ins_fusion: Percentiles::of(self.ins_fusion_ns.iter().copied()),
                uwb_fusion,
                fusion_logger: Percentiles::of(self.fusion_logger_ns.iter().copied()),
            },
            jitter: Percentiles::of(self.jitter_ns.iter().copied()),
            fixes: self.fixes,
            missed_cycles: self.missed_cycles,
            fused: self.fused,
        }
    }
}

/// Measures a run from its `records` (any order; duplicates, e.g. a
/// restarted logger's history, are ignored) and the logger's `recv` stamps.
pub fn analyse(
    records: &[Record],
    recv: &[RecvStamp],
    cfg: &AnalysisConfig,
) -> Result<RunLatency, AnalysisError> {
    samples(records, recv, cfg).map(|s| s.summary())
}

/// The raw values of one run (see [`analyse`]).
pub fn samples(
    records: &[Record],
    recv: &[RecvStamp],
    cfg: &AnalysisConfig,
) -> Result<LatencySamples, AnalysisError> {
    cfg.validate()?;
    // seq -> (meas, pub) of fixes and IMU samples; first INS publication per
    // IMU seq; first fused state per fix seq and per fused seq.
    let mut fixes: HashMap<u64, (u64, u64)> = HashMap::new();
    let mut imu: HashMap<u64, (u64, u64)> = HashMap::new();
    let mut nav_first: HashMap<u64, u64> = HashMap::new();
    let mut nav_imu: HashMap<u64, u64> = HashMap::new();
    let mut fused_by_fix: HashMap<u64, FusedState> = HashMap::new();
    for r in records {
        match r {
            Record::Fix(f) => {
                fixes
                    .entry(f.header.seq)
                    .or_insert((f.header.meas_time_ns, f.header.pub_time_ns));
            }
            Record::Imu(s) => {
                imu.entry(s.header.seq)
                    .or_insert((s.header.meas_time_ns, s.header.pub_time_ns));
            }
            Record::Nav(n) => {
                note_nav(&mut nav_first, n);
                nav_imu.entry(n.header.seq).or_insert(n.imu_seq);
            }
            Record::Fused(f) if is_update(f) => {
                fused_by_fix
                    .entry(f.uwb_seq)
                    .and_modify(|e| {
                        if f.header.pub_time_ns < e.header.pub_time_ns {
                            *e = *f;
                        }
                    })
                    .or_insert(*f);
            }
            _ => {}
        }
    }
    if imu.is_empty() || fixes.is_empty() {
        return Err(AnalysisError::NoInput {
            imu: imu.len(),
            fixes: fixes.len(),
        });
    }
    let Some(first_fused_ns) = fused_by_fix.values().map(|f| f.uwb_meas_time_ns).min() else {
        return Err(AnalysisError::NoFused { fixes: fixes.len() });
    };
    let imu_end = imu.values().map(|v| v.0).max().unwrap_or(0);
    let fix_end = fixes.values().map(|v| v.0).max().unwrap_or(0);
    let s_to_ns = |s: f64| (s * 1e9) as u64;
    let end_ns = imu_end.min(fix_end).saturating_sub(s_to_ns(cfg.tail_s));
    let steady_ns = first_fused_ns.saturating_add(s_to_ns(cfg.warmup_s));
    let in_cycles = |t: u64| (first_fused_ns..=end_ns).contains(&t);
    let in_steady = |t: u64| (steady_ns..=end_ns).contains(&t);

    let mut n_fixes = 0u64;
    let mut missed = 0u64;
    for (seq, &(meas, _)) in &fixes {
        if in_cycles(meas) {
            n_fixes += 1;
            if !fused_by_fix.contains_key(seq) {
                missed += 1;
            }
        }
    }

    let mut steady: Vec<&FusedState> = fused_by_fix
        .values()
        .filter(|f| in_steady(f.uwb_meas_time_ns))
        .collect();
    steady.sort_by_key(|f| f.uwb_seq);
    let uwb_fusion_ns: Vec<u64> = steady
        .iter()
        .map(|f| f.header.pub_time_ns.saturating_sub(f.uwb_pub_time_ns))
        .collect();
    let ins_fusion_ns: Vec<u64> = steady
        .iter()
        .map(|f| f.header.pub_time_ns.saturating_sub(f.ins_pub_time_ns))
        .collect();
    let jitter_ns: Vec<u64> = steady
        .windows(2)
        .filter_map(|w| {
            let (a, b) = (w.first()?, w.get(1)?);
            (b.uwb_seq == a.uwb_seq + 1).then(|| {
                b.header
                    .pub_time_ns
                    .saturating_sub(a.header.pub_time_ns)
                    .abs_diff(cfg.period_ns)
            })
        })
        .collect();
    let imu_ins_ns: Vec<u64> = nav_first
        .iter()
        .filter_map(|(seq, &nav_pub)| {
            let &(meas, imu_pub) = imu.get(seq)?;
            in_steady(meas).then(|| nav_pub.saturating_sub(imu_pub))
        })
        .collect();
    let steady_by_seq: HashMap<u64, u64> = steady
        .iter()
        .map(|f| (f.header.seq, f.header.pub_time_ns))
        .collect();
    let fusion_logger_ns: Vec<u64> = recv
        .iter()
        .filter_map(|r| {
            let &p = steady_by_seq.get(&r.seq)?;
            (p == r.pub_time_ns).then(|| r.receive_ns.saturating_sub(p))
        })
        .collect();
    let recv_of: HashMap<(u64, u64), u64> = recv
        .iter()
        .map(|r| ((r.seq, r.pub_time_ns), r.receive_ns))
        .collect();
    let cycles = steady
        .iter()
        .map(|f| Cycle {
            uwb_seq: f.uwb_seq,
            uwb_meas_ns: f.uwb_meas_time_ns,
            uwb_pub_ns: f.uwb_pub_time_ns,
            imu_pub_ns: nav_imu
                .get(&f.ins_seq)
                .and_then(|k| imu.get(k))
                .map_or(0, |v| v.1),
            ins_pub_ns: f.ins_pub_time_ns,
            fused_pub_ns: f.header.pub_time_ns,
            logger_recv_ns: recv_of
                .get(&(f.header.seq, f.header.pub_time_ns))
                .copied()
                .unwrap_or(0),
        })
        .collect();
    Ok(LatencySamples {
        uwb_fusion_ns,
        ins_fusion_ns,
        imu_ins_ns,
        fusion_logger_ns,
        jitter_ns,
        fixes: n_fixes,
        missed_cycles: missed,
        fused: fused_by_fix.len() as u64,
        cycles,
    })
}

fn note_nav(first: &mut HashMap<u64, u64>, n: &NavState) {
    first
        .entry(n.imu_seq)
        .and_modify(|p| *p = (*p).min(n.header.pub_time_ns))
        .or_insert(n.header.pub_time_ns);
}

#[cfg(test)]
mod tests {
    use super::*;
    use insuwb_msg::{Header, ImuSample, UwbFix};

    const MS: u64 = 1_000_000;
    const US: u64 = 1_000;

    fn h(seq: u64, meas: u64, pub_ns: u64) -> Header {
        Header {
            pub_time_ns: pub_ns,
            ..Header::new(seq, meas)
        }
    }

    /// 10 s at 100 Hz IMU / 10 Hz UWB from t0 = 1 s. IMU sample k published
    /// 20 us after its time, INS 50 us later; fix j published 30 us after its
    /// epoch; fused published `fused_after(j)` after the fix; the logger
    /// receives 40 us after that. Fixes in `skip` get no fused state.
    fn run(fused_after: impl Fn(u64) -> u64, skip: &[u64]) -> (Vec<Record>, Vec<RecvStamp>) {
        let t0 = 1_000 * MS;
        let mut recs = Vec::new();
        let mut recv = Vec::new();
        for k in 0..1000u64 {
            let t = t0 + k * 10 * MS;
            recs.push(Record::Imu(ImuSample {
                header: h(k, t, t + 20 * US),
                ..ImuSample::default()
            }));
            recs.push(Record::Nav(NavState {
                header: h(k, t, t + 70 * US),
                imu_seq: k,
                ..NavState::default()
            }));
            // A re-propagated copy, published later: not counted.
            recs.push(Record::Nav(NavState {
                header: h(5000 + k, t, t + 9 * MS),
                imu_seq: k,
                ..NavState::default()
            }));
        }
        let mut fused_seq = 0;
        for j in 0..100u64 {
            let t = t0 + j * 100 * MS;
            let fix_pub = t + 30 * US;
            recs.push(Record::Fix(UwbFix {
                header: h(j, t, fix_pub),
                ..UwbFix::default()
            }));
            if skip.contains(&j) {
                continue;
            }
            let p = fix_pub + fused_after(j);
            recs.push(Record::Fused(FusedState {
                header: h(fused_seq, t, p),
                uwb_seq: j,
                uwb_meas_time_ns: t,
                uwb_pub_time_ns: fix_pub,
                ins_seq: 10 * j,
                ins_pub_time_ns: t + 70 * US,
                ..FusedState::default()
            }));
            recv.push(RecvStamp {
                seq: fused_seq,
                pub_time_ns: p,
                receive_ns: p + 40 * US,
            });
            fused_seq += 1;
        }
        (recs, recv)
    }

    fn close(got: f64, want: f64) -> bool {
        (got - want).abs() <= want.abs() * 1e-3 + 1e-9
    }

    #[test]
    fn constant_delays_give_each_hop_its_value() {
        // Fused 100 us after the fix: 60 us after the INS state (published
        // 70 us after the epoch, the fix 30 us).
        let (recs, recv) = run(|_| 100 * US, &[]);
        let r = analyse(&recs, &recv, &AnalysisConfig::default()).unwrap();
        assert_eq!(r.missed_cycles, 0);
        assert_eq!(r.fused, 100);
        // The end is min(last IMU 9.99 s, last fix 9.9 s) - 0.5 s = 9.4 s after
        // t0: fixes 0..=94.
        assert_eq!(r.fixes, 95);
        for (p, want) in [
            (r.e2e_uwb_fused, 100.0),
            (r.hops.uwb_fusion, 100.0),
            (r.hops.ins_fusion, 60.0),
            (r.hops.imu_ins, 50.0),
            (r.e2e_imu_ins, 50.0),
            (r.hops.fusion_logger, 40.0),
        ] {
            for v in [p.p50_us, p.p99_us, p.p999_us, p.max_us] {
                assert!(close(v, want), "{p:?} want {want}");
            }
        }
        // Steady fixes 10..=94 (1 s warm-up): 85 fused, 84 periods, all exact.
        assert_eq!(r.e2e_uwb_fused.count, 85);
        assert_eq!(r.jitter.count, 84);
        assert_eq!(r.jitter.max_us, 0.0);
        // IMU samples 100..=940 (1 s to 9.4 s) are steady.
        assert_eq!(r.hops.imu_ins.count, 841);
        // The same cycles, stamp by stamp.
        let s = samples(&recs, &recv, &AnalysisConfig::default()).unwrap();
        assert_eq!(s.cycles.len(), 85);
        let t = 1_000 * MS + 10 * 100 * MS;
        assert_eq!(
            s.cycles.first().copied(),
            Some(Cycle {
                uwb_seq: 10,
                uwb_meas_ns: t,
                uwb_pub_ns: t + 30 * US,
                imu_pub_ns: t + 20 * US,
                ins_pub_ns: t + 70 * US,
                fused_pub_ns: t + 130 * US,
                logger_recv_ns: t + 170 * US,
            })
        );
        assert_eq!(s.cycles.last().map(|c| c.uwb_seq), Some(94));
        let row = s.cycles.first().map(Cycle::csv_row).unwrap_or_default();
        assert_eq!(row.split(',').count(), Cycle::CSV_HEADER.split(',').count());
    }

    #[test]
    fn percentiles_and_jitter_follow_a_known_distribution() {
        // Fix j's fused state is published 100 us + j us after it: steady
        // fixes 10..=94 give 110..=194 us; periods differ by 1 us each.
        let (recs, recv) = run(|j| (100 + j) * US, &[]);
        let r = analyse(&recs, &recv, &AnalysisConfig::default()).unwrap();
        let e = r.e2e_uwb_fused;
        assert_eq!(e.count, 85);
        // Order statistics of 110..=194 (85 values): median 152, p99 and
        // p99.9 the largest, 194.
        assert!(close(e.p50_us, 152.0), "{e:?}");
        assert!(close(e.p99_us, 194.0), "{e:?}");
        assert!(close(e.max_us, 194.0), "{e:?}");
        assert!(close(r.jitter.p50_us, 1.0), "{:?}", r.jitter);
    }

    #[test]
    fn runs_pool_into_the_percentiles_of_all_their_values() {
        // Run a: every fused state 100 us after its fix; run b: 300 us, one
        // fix missed. Pooled, half the values are each: p50 at 100 us, p99
        // at 300 us; counts add up.
        let (ra, va) = run(|_| 100 * US, &[]);
        let (rb, vb) = run(|_| 300 * US, &[50]);
        let cfg = AnalysisConfig::default();
        let a = samples(&ra, &va, &cfg).unwrap();
        let b = samples(&rb, &vb, &cfg).unwrap();
        let mut pooled = a.clone();
        pooled.extend(&b);
        let s = pooled.summary();
        assert_eq!(
            s.e2e_uwb_fused.count,
            a.uwb_fusion_ns.len() as u64 + b.uwb_fusion_ns.len() as u64
        );
        assert!(close(s.e2e_uwb_fused.p50_us, 100.0), "{s:?}");
        assert!(close(s.e2e_uwb_fused.p99_us, 300.0), "{s:?}");
        assert_eq!(s.missed_cycles, 1);
        assert_eq!(s.fixes, a.fixes + b.fixes);
        assert_eq!(s.fused, a.fused + b.fused);
        // One run alone summarises as `analyse` does.
        assert_eq!(a.summary(), analyse(&ra, &va, &cfg).unwrap());
    }

    #[test]
    fn a_fix_without_fused_state_is_a_missed_cycle_and_a_long_period() {
        let (recs, recv) = run(|_| 100 * US, &[20, 21, 99]);
        let r = analyse(&recs, &recv, &AnalysisConfig::default()).unwrap();
        // 99 lies in the tail: only 20 and 21 count.
        assert_eq!(r.missed_cycles, 2);
        // The period across the gap is not a period of consecutive fixes:
        // jitter stays exact, and the pairs (19, 22) are left out.
        assert_eq!(r.jitter.max_us, 0.0);
        assert_eq!(r.jitter.count, 81);
    }

    #[test]
    fn degraded_outputs_are_not_updates() {
        let (mut recs, recv) = run(|_| 100 * US, &[30]);
        // A coasting output naming fix 30 does not fill the cycle.
        recs.push(Record::Fused(FusedState {
            header: Header {
                flags: FusedState::FLAG_DEGRADED,
                ..h(999, 4_000 * MS, 4_000 * MS)
            },
            uwb_seq: 30,
            ..FusedState::default()
        }));
        let r = analyse(&recs, &recv, &AnalysisConfig::default()).unwrap();
        assert_eq!(r.missed_cycles, 1);
    }

    #[test]
    fn empty_recordings_are_refused() {
        let e = analyse(&[], &[], &AnalysisConfig::default()).unwrap_err();
        assert!(
            matches!(e, AnalysisError::NoInput { imu: 0, fixes: 0 }),
            "{e}"
        );
        let (recs, _) = run(|_| 0, &(0..100).collect::<Vec<_>>());
        let e = analyse(&recs, &[], &AnalysisConfig::default()).unwrap_err();
        assert_eq!(e, AnalysisError::NoFused { fixes: 100 });
    }

    #[test]
    fn bad_settings_name_the_key() {
        for (c, key) in [
            (
                AnalysisConfig {
                    warmup_s: -1.0,
                    ..AnalysisConfig::default()
                },
                "warmup_s",
            ),
            (
                AnalysisConfig {
                    tail_s: f64::NAN,
                    ..AnalysisConfig::default()
                },
                "tail_s",
            ),
            (
                AnalysisConfig {
                    period_ns: 0,
                    ..AnalysisConfig::default()
                },
                "period_ns",
            ),
        ] {
            assert!(c.validate().unwrap_err().to_string().contains(key));
        }
        let c: AnalysisConfig = toml::from_str("warmup_s = 2.0").unwrap();
        assert_eq!(c.warmup_s, 2.0);
        assert!(toml::from_str::<AnalysisConfig>("warmup = 2.0").is_err());
    }

    #[test]
    fn percentiles_of_1_to_1000_us() {
        let p = Percentiles::of((1..=1000u64).map(|v| v * US));
        assert!(close(p.p50_us, 500.0), "{p:?}");
        assert!(close(p.p99_us, 990.0), "{p:?}");
        assert!(close(p.p999_us, 999.0), "{p:?}");
        assert!(close(p.max_us, 1000.0), "{p:?}");
        assert_eq!(p.count, 1000);
        assert_eq!(Percentiles::of([]), Percentiles::default());
        // Zero is a value (a period exactly on time).
        assert_eq!(Percentiles::of([0, 0]).count, 2);
    }
}
