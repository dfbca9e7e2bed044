//! The start epoch of a group that paces its own samples (simulated or
//! replayed sources): when sample time 0 is due, CLOCK_MONOTONIC ns.
//!
//! An epoch is a whole second plus [`EPOCH_PHASE_NS`]. The kernel's timer
//! tick falls on whole milliseconds of CLOCK_MONOTONIC (every 1/HZ s), and
//! the work it starts wakes then too: timer-wheel callbacks, delayed kernel
//! work, kernel threads sleeping in jiffies. On a whole-second epoch every
//! fix epoch (whole 100 ms) and every other IMU sample would land on a tick
//! and race that work for the CPUs: on the project's VM a DAMON thread woken
//! every 512 ms by the tick ran up to 5.6 ms without yielding, and caught
//! one fix epoch every 12.8 s (BENCHMARKS.md, session 6). 2.5 ms after a
//! whole millisecond count of 2.5 is half a millisecond from the nearest
//! tick at HZ 1000, and 1.5-2.5 ms from it at HZ 250 and 100, for every fix
//! epoch and IMU sample.
//!
//! Measurements are still grouped into fix epochs as in the recording: a
//! consumer that bins times by multiples of a period aligns its bins to the
//! epoch (`insuwb_uwb::fix::FixBuilder::align_to`,
//! `insuwb_fusion::engine::FusionEngine::align_to`).

/// Offset of every chosen epoch from a whole second, ns (see the module
/// documentation).
pub const EPOCH_PHASE_NS: u64 = 2_500_000;

/// The first epoch at or after `t_ns`: a whole second plus [`EPOCH_PHASE_NS`].
#[must_use]
pub fn epoch_at_or_after(t_ns: u64) -> u64 {
    const SECOND: u64 = 1_000_000_000;
    let t = t_ns.saturating_sub(EPOCH_PHASE_NS);
    t.div_ceil(SECOND)
        .saturating_mul(SECOND)
        .saturating_add(EPOCH_PHASE_NS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn epochs_are_whole_seconds_plus_the_phase_and_never_early() {
        for t in [
            0,
            1,
            EPOCH_PHASE_NS,
            EPOCH_PHASE_NS + 1,
            999_999_999,
            1_000_000_000,
            1_002_500_000,
            1_002_500_001,
            123_456_789_012,
        ] {
            let e = epoch_at_or_after(t);
            assert!(e >= t, "{t} -> {e}");
            assert!(e - t < 1_000_000_000, "{t} -> {e}: the first one");
            assert_eq!(e % 1_000_000_000, EPOCH_PHASE_NS, "{t} -> {e}");
            // Off the tick grid (whole milliseconds): half a millisecond at least.
            assert_eq!(e % 1_000_000, 500_000, "{t} -> {e}");
        }
        assert_eq!(epoch_at_or_after(1_002_500_000), 1_002_500_000);
        assert_eq!(epoch_at_or_after(1_002_500_001), 2_002_500_000);
    }
}
