//! A recorded track as a solution: the fused states a log holds (a fleet
//! station's recording of a robot, or a robot's own log), evaluated as
//! they were published, where the log has no IMU and UWB records to run
//! the filters on.
//!
//! The track is every state flagged valid (a state published without
//! `FLAG_VALID` is one its robot said not to trust; where none is flagged
//! valid, every state), the last one of each measurement time, in time
//! order. [`evaluate_recorded`] reports how many there are, their span and
//! rate, and, where the log also has ground truth, the metrics of the
//! track at its own epochs (NEES from the states' covariances).
//!
//! ```
//! use insuwb_eval::recorded::evaluate_recorded;
//! use insuwb_msg::{FusedState, Header};
//! let fused: Vec<FusedState> = (0..11u64)
//!     .map(|k| {
//!         let mut s = FusedState { header: Header::new(k, k * 100_000_000), ..FusedState::default() };
//!         s.header.flags = FusedState::FLAG_VALID;
//!         s
//!     })
//!     .collect();
//! let r = evaluate_recorded(&fused, &[], None).unwrap();
//! assert_eq!((r.states, r.span_s, r.rate_hz), (11, 1.0, 10.0));
//! assert!(r.metrics.is_none(), "no ground truth");
//! ```

use insuwb_msg::{FusedState, GroundTruth};
use serde::Serialize;

use crate::metrics::{compute, Estimate, Metrics, MetricsError, TruthTrack};
use crate::run::fused_estimate;

/// The key of the recorded track among the solutions.
pub const RECORDED: &str = "recorded";

/// Maximum truth gap bridged by interpolation (ns), as for the other
/// solutions.
const TRUTH_MAX_GAP_NS: u64 = 100_000_000;

/// The recorded track's figures.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RecordedReport {
    /// States in the track.
    pub states: usize,
    /// From its first to its last state, s.
    pub span_s: f64,
    /// States per second over the span (0 with fewer than two).
    pub rate_hz: f64,
    /// Its metrics against the ground truth, where the log has some.
    pub metrics: Option<Metrics>,
}

/// The track of `fused` (see the module documentation), time-sorted.
#[must_use]
pub fn recorded_track(fused: &[FusedState]) -> Vec<Estimate> {
    let any_valid = fused
        .iter()
        .any(|s| s.header.flags & FusedState::FLAG_VALID != 0);
    let mut kept: Vec<&FusedState> = fused
        .iter()
        .filter(|s| !any_valid || s.header.flags & FusedState::FLAG_VALID != 0)
        .collect();
    // Stable: of equal times, the last recorded stays last.
    kept.sort_by_key(|s| s.header.meas_time_ns);
    let mut out: Vec<Estimate> = Vec::with_capacity(kept.len());
    for s in kept {
        let e = fused_estimate(s);
        match out.last_mut() {
            Some(last) if last.t_ns == e.t_ns => *last = e,
            _ => out.push(e),
        }
    }
    out
}

/// The figures of the track of `fused`; its metrics against `truth`
/// (time-sorted) at its epochs inside `segment` where `truth` is not empty.
///
/// # Errors
/// [`MetricsError`] when the track and the truth do not overlap or a state
/// is not finite.
pub fn evaluate_recorded(
    fused: &[FusedState],
    truth: &[GroundTruth],
    segment: Option<(u64, u64)>,
) -> Result<RecordedReport, MetricsError> {
    let track = recorded_track(fused);
    let (span_s, rate_hz) = match (track.first(), track.last()) {
        (Some(a), Some(b)) if b.t_ns > a.t_ns => {
            let span = (b.t_ns - a.t_ns) as f64 * 1e-9;
            (span, (track.len() - 1) as f64 / span)
        }
        _ => (0.0, 0.0),
    };
    let metrics = if truth.is_empty() {
        None
    } else {
        Some(compute(
            &track,
            &TruthTrack::new(truth, TRUTH_MAX_GAP_NS),
            segment,
            &[],
        )?)
    };
    Ok(RecordedReport {
        states: track.len(),
        span_s,
        rate_hz,
        metrics,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use insuwb_msg::Header;

    fn state(t_ms: u64, x: f64, flags: u32) -> FusedState {
        let mut s = FusedState {
            header: Header::new(0, t_ms * 1_000_000),
            pos_m: [x, 0.0, 0.0],
            ..FusedState::default()
        };
        for i in 0..6 {
            s.cov[i][i] = 0.01;
        }
        s.header.flags = flags;
        s
    }

    fn truth_at(t_ms: u64) -> GroundTruth {
        GroundTruth {
            header: Header::new(0, t_ms * 1_000_000),
            ..GroundTruth::default()
        }
    }

    #[test]
    fn the_track_keeps_valid_states_once_per_time_in_order() {
        let v = FusedState::FLAG_VALID;
        let fused = [
            state(200, 2.0, v),
            state(100, 1.0, v),
            state(150, 9.0, 0),
            state(200, 3.0, v),
        ];
        let t = recorded_track(&fused);
        assert_eq!(
            t.iter()
                .map(|e| (e.t_ns, e.pos_en_m[0]))
                .collect::<Vec<_>>(),
            [(100_000_000, 1.0), (200_000_000, 3.0)]
        );
        // None valid: every state.
        assert_eq!(
            recorded_track(&[state(1, 0.0, 0), state(2, 0.0, 0)]).len(),
            2
        );
    }

    #[test]
    fn with_truth_the_track_has_metrics_at_its_epochs() {
        let v = FusedState::FLAG_VALID;
        let fused: Vec<FusedState> = (0..=10).map(|k| state(k * 100, 0.3, v)).collect();
        let truth: Vec<GroundTruth> = (0..=100).map(|k| truth_at(k * 10)).collect();
        let r = evaluate_recorded(&fused, &truth, None).unwrap();
        let m = r.metrics.unwrap();
        assert_eq!((r.states, m.epochs), (11, 11));
        assert!((m.rmse_east - 0.3).abs() < 1e-12 && m.rmse_north.abs() < 1e-12);
        assert!(m.nees_mean.is_some());
        assert!((r.rate_hz - 10.0).abs() < 1e-9);
        // The segment limits the epochs.
        let r = evaluate_recorded(&fused, &truth, Some((0, 450_000_000))).unwrap();
        assert_eq!(r.metrics.unwrap().epochs, 5);
        // No overlap: an error naming why.
        let late: Vec<GroundTruth> = (0..5).map(|k| truth_at(5000 + k * 10)).collect();
        assert!(matches!(
            evaluate_recorded(&fused, &late, None),
            Err(MetricsError::NoOverlap { .. })
        ));
        let empty = evaluate_recorded(&[], &[], None).unwrap();
        assert_eq!((empty.states, empty.rate_hz), (0, 0.0));
    }
}
