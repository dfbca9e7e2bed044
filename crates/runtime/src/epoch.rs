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
//! one fix epoch every 12.8 s (BENCHMARKS.md, "The kernel tick"). 2.5 ms
//! after a whole millisecond count of 2.5 is half a millisecond from the
//! nearest tick at HZ 1000, and 1.5-2.5 ms from it at HZ 250 and 100, for
//! every fix epoch and IMU sample.
//!
//! Measurements are still grouped into fix epochs as in the recording: a
//! consumer that bins times by multiples of a period aligns its bins to the
//! epoch (`insuwb_uwb::fix::FixBuilder::align_to`,
//! `insuwb_fusion::engine::FusionEngine::align_to`).
//!
//! The module also places the stages' periodic housekeeping (heartbeats,
//! ticks) between the sample instants: [`housekeeping_due`].

/// Offset of every chosen epoch from a whole second, ns (see the module
/// documentation).
pub const EPOCH_PHASE_NS: u64 = 2_500_000;

/// Phase of every interval of a [`crate::Waiter`] (heartbeats, ticks), ns:
/// an interval of period `p` fires at the instants `t` with `t mod p ==
/// HOUSEKEEPING_PHASE_NS mod p`. Sample instants of a group (epoch plus
/// whole 10 ms: every IMU sample at 100 Hz, every fix epoch at 10 Hz) are
/// whole seconds plus [`EPOCH_PHASE_NS`] plus whole 10 ms; for periods that
/// divide a second (the 200 ms heartbeat, the 50 ms fusion tick) the
/// housekeeping instants lie 5 ms from every sample instant and 55 ms after
/// a fix epoch, so a heartbeat (a page-in scan takes 90-130 us, see
/// `crate::prefault`) never runs just before a sample its stage must handle
/// (BENCHMARKS.md, "Housekeeping between the samples").
pub const HOUSEKEEPING_PHASE_NS: u64 = EPOCH_PHASE_NS + 55_000_000;

/// The first housekeeping instant ([`HOUSEKEEPING_PHASE_NS`]) of period
/// `period_ns` at least one period after `now_ns` (so before two periods
/// have passed). `period_ns` 0 gives `now_ns`.
#[must_use]
pub fn housekeeping_due(now_ns: u64, period_ns: u64) -> u64 {
    if period_ns == 0 {
        return now_ns;
    }
    grid_at_or_after(
        now_ns.saturating_add(period_ns),
        period_ns,
        HOUSEKEEPING_PHASE_NS % period_ns,
    )
}

/// The first epoch at or after `t_ns`: a whole second plus [`EPOCH_PHASE_NS`].
#[must_use]
pub fn epoch_at_or_after(t_ns: u64) -> u64 {
    grid_at_or_after(t_ns, 1_000_000_000, EPOCH_PHASE_NS)
}

/// The first instant at or after `t_ns` of the grid `phase_ns + k *
/// period_ns` (`period_ns` > 0, `phase_ns` < `period_ns`).
fn grid_at_or_after(t_ns: u64, period_ns: u64, phase_ns: u64) -> u64 {
    t_ns.saturating_sub(phase_ns)
        .div_ceil(period_ns)
        .saturating_mul(period_ns)
        .saturating_add(phase_ns)
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

    #[test]
    fn housekeeping_falls_between_the_sample_instants() {
        const MS: u64 = 1_000_000;
        for period in [200 * MS, 50 * MS, 7 * MS, 1_500 * MS] {
            for now in [0, 1, 57 * MS, 123_456_789_012, 1_002_500_000] {
                let due = housekeeping_due(now, period);
                assert!(due >= now + period, "{now} + {period} -> {due}");
                assert!(due < now + 2 * period, "{now} + {period} -> {due}");
                assert_eq!(due % period, HOUSEKEEPING_PHASE_NS % period);
                if (1_000 * MS).is_multiple_of(period) && period.is_multiple_of(10 * MS) {
                    // 5 ms from every IMU sample, 55 ms after a fix epoch.
                    let since_epoch = (due - EPOCH_PHASE_NS) % (100 * MS);
                    assert_eq!(since_epoch % (10 * MS), 5 * MS, "{due}");
                    assert_eq!(since_epoch % (50 * MS), 5 * MS, "{due}");
                }
            }
        }
        assert_eq!(housekeeping_due(5, 0), 5);
    }
}
