//! What the launcher measures while a group runs, in bounded memory: a group
//! runs for days, so nothing here grows with the run's length. Accuracy is a
//! running sum over a short window of ground truth, latency a fixed-size
//! histogram, rates and gaps running counters.

use std::collections::{BTreeMap, VecDeque};

use insuwb_eval::metrics::TruthTrack;
use insuwb_msg::{FusedState, GroundTruth, Health, UwbFix};

/// Longest gap across which ground truth is interpolated, ns.
const TRUTH_MAX_GAP_NS: u64 = 100_000_000;
/// Ground truth kept behind the oldest state still waiting for it, ns (the
/// interpolation needs one sample either side, the velocity window 50 ms).
const TRUTH_KEEP_NS: u64 = 1_000_000_000;
/// A state still without ground truth after the newest state is this far
/// ahead is given up (the truth topic is late or absent), ns.
const PENDING_GIVE_UP_NS: u64 = 10_000_000_000;
/// Gap between valid updates counted as a deadlock, ns.
const DEADLOCK_NS: u64 = 5_000_000_000;
/// Fix publish times kept, to tell a coasting state in a UWB outage from
/// one although fixes came (6.4 s of fixes at 10 Hz).
const FIX_PUBS_KEPT: usize = 64;

/// First time, last time and count of a stream.
#[derive(Debug, Default, Clone, Copy)]
pub struct Times {
    first: u64,
    last: u64,
    n: u64,
}

impl Times {
    /// Counts one sample measured at `at`.
    pub fn count(&mut self, at: u64) {
        if self.n == 0 {
            self.first = at;
        }
        self.last = at;
        self.n += 1;
    }

    /// Samples counted.
    pub fn n(&self) -> u64 {
        self.n
    }

    /// Mean rate between the first and the last sample, Hz.
    pub fn rate(&self) -> f64 {
        if self.n < 2 || self.last <= self.first {
            return 0.0;
        }
        (self.n - 1) as f64 / ((self.last - self.first) as f64 * 1e-9)
    }
}

/// Horizontal squared error summed over fused states as ground truth for
/// them arrives.
#[derive(Debug, Default)]
struct Accuracy {
    /// Ground truth known beforehand (sorted), used instead of the window.
    known: Vec<GroundTruth>,
    /// Ground truth received, sorted, trimmed from the front.
    window: Vec<GroundTruth>,
    /// Valid updates not yet compared: measurement time, horizontal position.
    pending: VecDeque<(u64, [f64; 2])>,
    se: f64,
    n: usize,
    /// States given up for want of ground truth.
    unmatched: u64,
}

impl Accuracy {
    fn truth(&mut self, t: GroundTruth) {
        let at = t.header.meas_time_ns;
        match self.window.last() {
            Some(last) if last.header.meas_time_ns > at => {
                let i = self.window.partition_point(|g| g.header.meas_time_ns < at);
                self.window.insert(i, t);
            }
            _ => self.window.push(t),
        }
    }

    fn state(&mut self, at: u64, pos: [f64; 2]) {
        self.pending.push_back((at, pos));
    }

    /// Compares the states whose ground truth has arrived; with `all`, every
    /// state still waiting (the end of the run).
    fn settle(&mut self, all: bool) {
        let known = !self.known.is_empty();
        let truth: &[GroundTruth] = if known { &self.known } else { &self.window };
        let track = TruthTrack::new(truth, TRUTH_MAX_GAP_NS);
        let newest_truth = truth.last().map_or(0, |g| g.header.meas_time_ns);
        let newest_state = self.pending.back().map_or(0, |p| p.0);
        while let Some(&(at, pos)) = self.pending.front() {
            let ready = all || known || at <= newest_truth;
            if !ready {
                if newest_state.saturating_sub(at) > PENDING_GIVE_UP_NS {
                    self.pending.pop_front();
                    self.unmatched += 1;
                    continue;
                }
                break;
            }
            self.pending.pop_front();
            match track.at(at) {
                Some((p, _)) => {
                    self.se += (pos[0] - p[0]).powi(2) + (pos[1] - p[1]).powi(2);
                    self.n += 1;
                }
                None => self.unmatched += 1,
            }
        }
        if !known {
            // Keep what the states still waiting (or the next ones) need.
            let keep_from = self
                .pending
                .front()
                .map_or(newest_truth, |p| p.0.min(newest_truth))
                .saturating_sub(TRUTH_KEEP_NS);
            let cut = self
                .window
                .partition_point(|g| g.header.meas_time_ns < keep_from);
            if cut > 0 && cut * 2 >= self.window.len() {
                self.window.drain(..cut);
            }
        }
    }

    fn rmse(&self) -> Option<f64> {
        (self.n > 0).then(|| (self.se / self.n as f64).sqrt())
    }
}

/// The launcher's running figures of one group.
#[derive(Debug)]
pub struct Monitor {
    accuracy: Accuracy,
    latency: Option<hdrhistogram::Histogram<u64>>,
    /// Fused states from UWB updates (not degraded).
    updates: Times,
    /// Fused states published while coasting.
    degraded: u64,
    /// Publish time of the last valid update, and the largest gap so far.
    last_valid_pub: Option<u64>,
    max_gap_ns: u64,
    /// When the largest gap ended (the publish time of the pose after it).
    max_gap_end_ns: u64,
    deadlocks: u32,
    /// For the live line: states that carry a UWB update or are not degraded.
    live_updates: u64,
    last_pos: [f64; 3],
    /// IMU samples.
    pub imu: Times,
    /// UWB fixes.
    pub fixes: Times,
    /// Publish times of the latest fixes (at most [`FIX_PUBS_KEPT`]).
    fix_pubs: VecDeque<u64>,
    /// Each stage's last heartbeat, by name.
    pub health: BTreeMap<String, Health>,
}

impl Monitor {
    /// A monitor; `known_truth` is ground truth known beforehand
    /// (CLOCK_MONOTONIC times), used instead of the truth topic when given.
    pub fn new(mut known_truth: Vec<GroundTruth>) -> Self {
        known_truth.sort_by_key(|t| t.header.meas_time_ns);
        Self {
            accuracy: Accuracy {
                known: known_truth,
                ..Accuracy::default()
            },
            latency: hdrhistogram::Histogram::<u64>::new_with_bounds(1, 60_000_000, 3).ok(),
            updates: Times::default(),
            degraded: 0,
            last_valid_pub: None,
            max_gap_ns: 0,
            max_gap_end_ns: 0,
            deadlocks: 0,
            live_updates: 0,
            last_pos: [f64::NAN; 3],
            imu: Times::default(),
            fixes: Times::default(),
            fix_pubs: VecDeque::with_capacity(FIX_PUBS_KEPT),
            health: BTreeMap::new(),
        }
    }

    /// Takes one fused state.
    pub fn fused(&mut self, f: &FusedState) {
        self.last_pos = f.pos_m;
        let degraded = f.header.flags & FusedState::FLAG_DEGRADED != 0;
        if f.uwb_seq != 0 || !degraded {
            self.live_updates += 1;
        }
        if degraded {
            self.degraded += 1;
            // Coasting while no fix exists (a UWB outage): the INS's pose
            // is the answer, and closes the gap; coasting although fixes
            // came is not.
            if f.header.flags & FusedState::FLAG_VALID != 0
                && !self.fix_since_valid(f.header.pub_time_ns)
            {
                self.note_valid(f.header.pub_time_ns);
            }
            return;
        }
        if f.header.flags & FusedState::FLAG_UWB_ONLY != 0 {
            // A pose while the INS cannot serve: it closes a gap, but it is
            // the UWB fix, not the filter: not in the rate, the latency or
            // the accuracy of the fused states.
            if f.header.flags & FusedState::FLAG_VALID != 0 {
                self.note_valid(f.header.pub_time_ns);
            }
            return;
        }
        self.updates.count(f.header.meas_time_ns);
        if f.uwb_pub_time_ns > 0 && f.header.pub_time_ns > f.uwb_pub_time_ns {
            if let Some(h) = self.latency.as_mut() {
                let _ = h.record(((f.header.pub_time_ns - f.uwb_pub_time_ns) / 1000).max(1));
            }
        }
        if f.header.flags & FusedState::FLAG_VALID == 0 {
            return;
        }
        self.accuracy
            .state(f.header.meas_time_ns, [f.pos_m[0], f.pos_m[1]]);
        self.note_valid(f.header.pub_time_ns);
    }

    /// Takes one UWB fix.
    pub fn fix(&mut self, f: &UwbFix) {
        self.fixes.count(f.header.meas_time_ns);
        if self.fix_pubs.len() == FIX_PUBS_KEPT {
            self.fix_pubs.pop_front();
        }
        self.fix_pubs.push_back(f.header.pub_time_ns);
    }

    /// Whether a fix was published after the last valid pose and at or
    /// before `at`.
    fn fix_since_valid(&self, at: u64) -> bool {
        let from = self.last_valid_pub.unwrap_or(0);
        self.fix_pubs.iter().any(|&t| t > from && t <= at)
    }

    /// A valid pose published at `at`: the gap since the previous one.
    fn note_valid(&mut self, at: u64) {
        if let Some(prev) = self.last_valid_pub {
            let gap = at.saturating_sub(prev);
            if gap > self.max_gap_ns {
                self.max_gap_ns = gap;
                self.max_gap_end_ns = at;
            }
            if gap > DEADLOCK_NS {
                self.deadlocks += 1;
            }
        }
        self.last_valid_pub = Some(self.last_valid_pub.map_or(at, |p| p.max(at)));
    }

    /// Takes one ground-truth sample.
    pub fn truth(&mut self, t: GroundTruth) {
        if self.accuracy.known.is_empty() {
            self.accuracy.truth(t);
        }
    }

    /// Compares the states whose ground truth has arrived (call after each
    /// drain; memory stays bounded by the truth window).
    pub fn settle(&mut self) {
        self.accuracy.settle(false);
    }

    /// States counted for the live line, and the last position.
    pub fn live(&self) -> (u64, [f64; 3]) {
        (self.live_updates, self.last_pos)
    }

    /// The running accuracy so far: the horizontal squared errors summed
    /// and the states compared (the difference of two readings is the RMS
    /// of the states compared between them).
    pub fn accuracy_sums(&self) -> (f64, usize) {
        (self.accuracy.se, self.accuracy.n)
    }

    /// The final figures: every state still waiting is compared.
    pub fn finish(&mut self) -> Figures {
        self.accuracy.settle(true);
        let (p50, p99) = self
            .latency
            .as_ref()
            .filter(|h| !h.is_empty())
            .map_or((0.0, 0.0), |h| {
                (
                    h.value_at_quantile(0.5) as f64,
                    h.value_at_quantile(0.99) as f64,
                )
            });
        Figures {
            rmse_horizontal: self.accuracy.rmse(),
            compared: self.accuracy.n as u64,
            fused_rate_hz: self.updates.rate(),
            latency_p50_us: p50,
            latency_p99_us: p99,
            degraded: self.degraded,
            max_gap_ms: self.max_gap_ns as f64 * 1e-6,
            max_gap_start_ns: self.max_gap_end_ns.saturating_sub(self.max_gap_ns),
            deadlocks: self.deadlocks,
        }
    }

    #[cfg(test)]
    /// Bytes held by the growing parts (ground-truth window and states
    /// waiting for it): bounded whatever the run's length.
    pub fn held_bytes(&self) -> usize {
        self.accuracy.window.capacity() * std::mem::size_of::<GroundTruth>()
            + self.accuracy.pending.capacity() * std::mem::size_of::<(u64, [f64; 2])>()
    }
}

/// The figures [`Monitor::finish`] gives.
#[derive(Debug, Clone, Copy)]
pub struct Figures {
    /// Horizontal RMS error of the valid updates against ground truth, m.
    pub rmse_horizontal: Option<f64>,
    /// Valid updates compared with ground truth.
    pub compared: u64,
    /// Rate of fused states from UWB updates, Hz.
    pub fused_rate_hz: f64,
    /// UWB fix publish to fused publish, p50, us.
    pub latency_p50_us: f64,
    /// p99, us.
    pub latency_p99_us: f64,
    /// States published while coasting.
    pub degraded: u64,
    /// Largest gap between valid poses (updates, or UWB-only poses while
    /// the INS cannot serve), ms.
    pub max_gap_ms: f64,
    /// When it started (the publish time of the pose before it, CLOCK_MONOTONIC ns).
    pub max_gap_start_ns: u64,
    /// Gaps of more than 5 s between valid updates.
    pub deadlocks: u32,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn truth(t: u64, x: f64) -> GroundTruth {
        let mut g = GroundTruth::default();
        g.header.meas_time_ns = t;
        g.pos_m = [x, 0.0, 0.0];
        g
    }

    fn state(t: u64, x: f64) -> FusedState {
        let mut f = FusedState::default();
        f.header.meas_time_ns = t;
        f.header.pub_time_ns = t + 1000;
        f.header.flags = FusedState::FLAG_VALID;
        f.uwb_seq = 1;
        f.pos_m = [x, 0.0, 0.0];
        f
    }

    /// A long run: the same RMSE as the whole-run computation, and the held
    /// memory does not grow with the run.
    #[test]
    fn long_run_is_bounded_and_exact() {
        let mut m = Monitor::new(Vec::new());
        let mut held = Vec::new();
        let ms = 1_000_000u64;
        // Truth at 100 Hz, states at 10 Hz 0.1 m east of it, for 2000 s;
        // truth is delivered in bursts that lag the states by 200 ms.
        for k in 0..20_000u64 {
            let t = 1_000 * ms + k * 100 * ms;
            m.fused(&state(t, t as f64 * 1e-9 + 0.1));
            if k >= 2 {
                for j in 0..10 {
                    let tt = t - 200 * ms + j * 10 * ms;
                    m.truth(truth(tt, tt as f64 * 1e-9));
                }
            }
            m.settle();
            if k % 1000 == 999 {
                held.push(m.held_bytes());
            }
        }
        let f = m.finish();
        let rmse = f.rmse_horizontal.unwrap_or(f64::NAN);
        assert!((rmse - 0.1).abs() < 1e-6, "rmse {rmse}");
        assert!(f.compared >= 19_990, "{} compared", f.compared);
        let (first, last) = (held[1], held[held.len() - 1]);
        assert!(last <= first * 2, "held {first} -> {last} bytes");
        assert!((f.fused_rate_hz - 10.0).abs() < 1e-6);
    }

    /// Without ground truth the waiting states are given up, not kept.
    #[test]
    fn no_truth_keeps_nothing() {
        let mut m = Monitor::new(Vec::new());
        for k in 0..10_000u64 {
            m.fused(&state(k * 100_000_000, 0.0));
            m.settle();
        }
        assert!(
            m.accuracy.pending.len() <= 101,
            "{}",
            m.accuracy.pending.len()
        );
        assert_eq!(m.finish().rmse_horizontal, None);
    }

    /// Ground truth known beforehand is used as it is.
    #[test]
    fn known_truth() {
        let known: Vec<_> = (0..100u64).map(|k| truth(k * 10_000_000, 1.0)).collect();
        let mut m = Monitor::new(known);
        m.fused(&state(500_000_000, 1.5));
        m.truth(truth(500_000_000, 9.0));
        m.settle();
        let r = m.finish().rmse_horizontal.unwrap_or(f64::NAN);
        assert!((r - 0.5).abs() < 1e-9, "{r}");
    }

    /// The running sums give the RMS of the states compared between two
    /// readings.
    #[test]
    fn accuracy_sums_difference_is_the_rms_between_readings() {
        let known: Vec<_> = (0..100u64).map(|k| truth(k * 10_000_000, 1.0)).collect();
        let mut m = Monitor::new(known);
        m.fused(&state(100_000_000, 1.5));
        m.settle();
        let (se0, n0) = m.accuracy_sums();
        assert_eq!(n0, 1);
        m.fused(&state(200_000_000, 3.0));
        m.fused(&state(300_000_000, 3.0));
        m.settle();
        let (se, n) = m.accuracy_sums();
        let rms = ((se - se0) / (n - n0) as f64).sqrt();
        assert!((rms - 2.0).abs() < 1e-9, "{rms}");
    }

    /// A gap is closed by an update, or by a coasting state while no fix
    /// was published since the last valid pose (a UWB outage); coasting
    /// although fixes came leaves it open.
    #[test]
    fn coasting_closes_a_gap_only_in_a_uwb_outage() {
        let ms = 1_000_000u64;
        let coast = |t: u64| {
            let mut f = state(t, 0.0);
            f.uwb_seq = 0;
            f.header.flags |= FusedState::FLAG_DEGRADED;
            f
        };
        let fix = |t: u64| {
            let mut f = UwbFix::default();
            f.header.meas_time_ns = t;
            f.header.pub_time_ns = t + 500;
            f
        };
        // An outage: updates to 1 s, coasting every 100 ms to 3 s, updates again.
        let mut m = Monitor::new(Vec::new());
        for k in 0..=10u64 {
            m.fix(&fix(k * 100 * ms));
            m.fused(&state(k * 100 * ms, 0.0));
        }
        for k in 11..30u64 {
            m.fused(&coast(k * 100 * ms));
        }
        m.fix(&fix(3000 * ms));
        m.fused(&state(3000 * ms, 0.0));
        let gap = m.finish().max_gap_ms;
        assert!((gap - 100.0).abs() < 1.0, "{gap}");
        // The same coasting while fixes keep coming: a 2 s gap.
        let mut m = Monitor::new(Vec::new());
        m.fused(&state(1000 * ms, 0.0));
        for k in 11..30u64 {
            m.fix(&fix(k * 100 * ms));
            m.fused(&coast(k * 100 * ms));
        }
        m.fused(&state(3000 * ms, 0.0));
        let gap = m.finish().max_gap_ms;
        assert!((gap - 2000.0).abs() < 1.0, "{gap}");
    }
}
