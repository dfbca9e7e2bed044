//! The divergence monitor on a real flight: flight-a92f4787 of the UTIL data
//! (a high-vibration vehicle, on which the tight filter once ran 8.8 m
//! away with a mean NIS of 1993), through the lockstep runner with the
//! `config/util.toml` preset and its one monitor for every filter
//! (`[fusion.engine.monitor]`).
//!
//! - The tight filter: an IMU fault is injected, the accelerometer reading
//!   `FAULT_MPS2` too much along body x and y for `FAULT_S` from
//!   `FAULT_AT_S` (20 m/s of velocity error per axis), which it does not
//!   recover from by itself (every TDOA difference is then beyond its hard
//!   gate: the INS runs tens of metres away).
//! - A loose filter: the paper's IAKF diverges on this flight by itself
//!   (16.7 m without the monitor), no fault needed.
//!
//! Both run with the free vehicle model (every accelerometer axis
//! integrated, the tight filter learning the accelerometer's noise from its
//! innovations: the preset before its multirotor model), where the fault
//! enters the INS and the IAKF diverges: with the preset's multirotor model
//! the INS does not integrate the horizontal channels the fault is in, and
//! the IAKF no longer diverges on this flight ([`free_vehicle`]).
//!
//! Both run with the preset's vibration noise off (`[fusion.vibration]`,
//! the fixed noise densities only): with it on, the vibration the IMU
//! measures (the fault included, which reads as violent shaking) raises
//! the filters' velocity noise and neither diverges, which the last test
//! checks.
//!
//! In both the monitor must fire, the engine must re-initialise the filter
//! and the INS from agreeing UWB fixes and flag the outputs (not valid
//! from the trigger to the reset, `FLAG_RESET` on the reset's, the
//! diagnostics' `FLAG_RESET` at it), and `SETTLE_S` after each reset the
//! error must be back under `BOUND_M`; with the monitor off it is not.
//!
//! The data are not part of the repository: they are looked for at
//! `INSUWB_UTIL_DIR`, else at `<workspace>/../shared/data/util`. When they
//! are absent the tests say so and pass, unless the environment variable
//! `CI` is set, where they fail.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use crate::common;

use common::{data_dir, load, preset};
use insuwb_data::segment::{flight_segment, interpolate_truth};
use insuwb_data::util::UtilFlight;
use insuwb_fusion::config::FusionConfig;
use insuwb_fusion::runner::{self, RunOutput};
use insuwb_fusion::vibration::VibrationConfig;
use insuwb_msg::{FilterDiag, FilterKind, FusedState};

const FLIGHT: &str = "flight-a92f4787";
const ANCHORS: &str = "anchors-const3.txt";
/// The flight segment: ground-truth height above this, m (as the preset's `[eval]`).
const MIN_HEIGHT_M: f64 = 0.3;
/// Start of the IMU fault, s of the log (take-off at 2.3 s, landing near 30 s).
const FAULT_AT_S: f64 = 15.0;
/// Length of the fault, s.
const FAULT_S: f64 = 0.4;
/// What the accelerometer reads too much along body x and y meanwhile, m/s^2.
const FAULT_MPS2: f64 = 50.0;
/// Time left to the filter after a reset before the bound applies, s.
const SETTLE_S: f64 = 2.0;
/// Bound on the horizontal error over the second after `SETTLE_S`, m (the
/// tight filter's largest error on the flight without the fault: 0.59 m).
const BOUND_M: f64 = 1.0;
/// Bound on the tight filter's horizontal error while the IMU fault lasts
/// and `FAULT_SETTLE_S` after it, with the vibration noise (1.14 m with the
/// preset's 4-sigma hard gate, 0.70 m with 8 sigma), m.
const FAULT_BOUND_M: f64 = 2.0;
/// Time after the fault's end before `BOUND_M` applies again, s.
const FAULT_SETTLE_S: f64 = 1.0;

fn secs(t_ns: u64) -> f64 {
    t_ns as f64 * 1e-9
}

/// The preset with the free vehicle model and the tight filter's learnt
/// process-noise scale, as the preset was before its multirotor model:
/// each TDOA difference's error its own (no anchor states), the vibration
/// noise added to the tight filter's too.
fn free_vehicle(f: &mut FusionConfig) {
    f.vehicle = insuwb_nav::vehicle::VehicleKind::Free;
    f.eskf.q_adapt_time_s = 0.2;
    f.eskf.q_adapt_decay_factor = 100.0;
    f.eskf.q_scale_max = 1000.0;
    f.eskf.tdoa_anchor_sigma_m = 0.0;
    f.eskf.tdoa_sigma_m = 0.15;
    f.eskf.tdoa_corr_time_s = 0.25;
    f.eskf.kappa = 1.5;
    f.tight.vibration_noise = true;
}

/// One run: its output and the horizontal error of each fused state inside
/// the flight segment, with its time (s).
struct Run {
    out: RunOutput,
    err: Vec<(f64, f64)>,
}

fn run(flight: &UtilFlight, cfg: &FusionConfig, kind: FilterKind, fault: bool) -> Run {
    let mut imu = flight.imu.clone();
    if fault {
        for s in &mut imu {
            let t = secs(s.header.meas_time_ns);
            if (FAULT_AT_S..FAULT_AT_S + FAULT_S).contains(&t) {
                s.accel_mps2[0] += FAULT_MPS2;
                s.accel_mps2[1] += FAULT_MPS2;
            }
        }
    }
    let out = runner::run(&imu, &flight.tdoa, cfg, kind).unwrap();
    let segment = flight_segment(&flight.truth, MIN_HEIGHT_M).expect("a flight segment");
    let err = out
        .fused
        .iter()
        .filter(|s| (segment.0..=segment.1).contains(&s.header.meas_time_ns))
        .filter_map(|s| {
            let g = interpolate_truth(&flight.truth, s.header.meas_time_ns)?;
            let e = (s.pos_m[0] - g.pos_m[0]).hypot(s.pos_m[1] - g.pos_m[1]);
            Some((secs(s.header.meas_time_ns), e))
        })
        .collect();
    Run { out, err }
}

fn max_err(r: &Run, from_s: f64, to_s: f64) -> f64 {
    r.err
        .iter()
        .filter(|(t, _)| (from_s..to_s).contains(t))
        .map(|(_, e)| *e)
        .fold(0.0, f64::max)
}

/// Times of the fused states flagged as resets, inside the flight segment
/// (the initialisation is not flagged: it resets nothing).
fn resets(out: &RunOutput, end_s: f64) -> Vec<f64> {
    out.fused
        .iter()
        .filter(|s| s.header.flags & FusedState::FLAG_RESET != 0)
        .map(|s| secs(s.header.meas_time_ns))
        .filter(|&t| t <= end_s)
        .collect()
}

/// Runs `kind` on the flight (with the IMU fault when `fault`), with the
/// monitor and without, and checks what a divergence must bring: the
/// monitor fires, the filter is reset from UWB, the outputs are flagged,
/// the error comes back under the bound.
fn monitor_catches_a_divergence(kind: FilterKind, fault: bool) {
    let Some(dir) = data_dir(FLIGHT) else {
        return;
    };
    let mut p = preset();
    free_vehicle(&mut p.fusion);
    p.fusion.vibration = VibrationConfig::default();
    let flight = load(&dir, FLIGHT, ANCHORS, &p);
    let end = secs(flight_segment(&flight.truth, MIN_HEIGHT_M).unwrap().1);

    let on = run(&flight, &p.fusion, kind, fault);
    let mut cfg_off = p.fusion.clone();
    cfg_off.engine.monitor.window = 0;
    cfg_off.engine.monitor.max_reject_run_s = 0.0;
    cfg_off.engine.monitor.outlier_window_s = 0.0;
    let off = run(&flight, &cfg_off, kind, fault);
    let c = on.out.fusion;
    let at = resets(&on.out, end);
    let (on_max, off_max) = (max_err(&on, 0.0, end), max_err(&off, 0.0, end));
    println!(
        "{kind:?} on {FLIGHT}{}: resets in flight at {at:.2?} s, max error {on_max:.2} m \
         ({off_max:.2} m with the monitor off); {c:?}",
        if fault { " with the IMU fault" } else { "" }
    );
    assert!(!at.is_empty(), "{kind:?}: no reset in flight: {c:?}");
    assert!(c.nis_divergences >= at.len() as u64, "{kind:?}: {c:?}");
    assert_eq!(
        c.resets,
        1 + at.len() as u64,
        "{kind:?}: the first fix and the resets"
    );
    assert!(off.out.fusion.resets == 1 && off.out.fusion.nis_divergences == 0);

    let mut prev = 0.0;
    for &r in &at {
        // From the update the monitor fired on to the reset, the fused
        // states are not valid, and only then.
        let states: Vec<(f64, u32)> = on
            .out
            .fused
            .iter()
            .map(|s| (secs(s.header.meas_time_ns), s.header.flags))
            .filter(|(t, _)| *t > prev && *t < r)
            .collect();
        let trigger = states
            .iter()
            .position(|(_, f)| f & FusedState::FLAG_VALID == 0)
            .unwrap_or_else(|| panic!("{kind:?}: no output flagged before the reset at {r:.2} s"));
        assert!(
            states[trigger..]
                .iter()
                .all(|(_, f)| f & FusedState::FLAG_VALID == 0),
            "{kind:?}: a valid output between the trigger and the reset at {r:.2} s"
        );
        let fired = states[trigger].0;
        assert!(
            r - fired < 1.5,
            "{kind:?}: fired at {fired:.2} s, reset at {r:.2} s"
        );
        // The reset's output is valid; the first diagnostic after it says reset.
        let reset = on
            .out
            .fused
            .iter()
            .find(|s| secs(s.header.meas_time_ns) == r)
            .unwrap();
        assert!(reset.header.flags & FusedState::FLAG_VALID != 0);
        let diag = on
            .out
            .diag
            .iter()
            .filter(|d| d.header.flags & FilterDiag::FLAG_RESET != 0)
            .map(|d| secs(d.header.meas_time_ns))
            .find(|&t| t >= r)
            .unwrap_or_else(|| panic!("{kind:?}: no diagnostic flagged RESET"));
        assert!(
            diag - r < 0.5,
            "{kind:?}: reset at {r:.2} s, diagnostic at {diag:.2} s"
        );
        // The filter had diverged, and is back under the bound.
        let before = max_err(&on, r - 2.0, r);
        let after = max_err(&on, r + SETTLE_S, r + SETTLE_S + 1.0);
        println!(
            "  fired at {fired:.2} s, reset at {r:.2} s ({} outputs not valid): \
             max error {before:.2} m over the 2 s before, {after:.2} m {SETTLE_S} s after",
            states.len() - trigger
        );
        assert!(
            after < BOUND_M,
            "{kind:?}: {after:.2} m after the reset at {r:.2} s"
        );
        prev = r;
    }
    let first = at[0];
    assert!(
        max_err(&on, first - 2.0, first) > BOUND_M,
        "{kind:?}: no divergence before the reset at {first:.2} s"
    );
    assert!(
        off_max > 10.0,
        "{kind:?}: {off_max:.2} m with the monitor off"
    );
    assert!(
        on_max < 0.3 * off_max,
        "{kind:?}: {on_max:.2} m vs {off_max:.2} m off"
    );
}

/// The tight filter, with the IMU fault: one reset, right after the fault
/// (none in flight without it). The preset's hard gate (4 sigma) rejects
/// most differences once the INS is off, and the odd one that passes ends a
/// run of rejections: the share of outliers over
/// `monitor.outlier_window_s` catches it; without that share the reset
/// comes more than a second later.
#[test]
fn the_monitor_resets_the_tight_filter_after_an_imu_fault() {
    monitor_catches_a_divergence(FilterKind::IakfTdoa, true);
    let Some(dir) = data_dir(FLIGHT) else {
        return;
    };
    let mut p = preset();
    free_vehicle(&mut p.fusion);
    p.fusion.vibration = VibrationConfig::default();
    let flight = load(&dir, FLIGHT, ANCHORS, &p);
    let end = secs(flight_segment(&flight.truth, MIN_HEIGHT_M).unwrap().1);
    let clean = run(&flight, &p.fusion, FilterKind::IakfTdoa, false);
    assert_eq!(resets(&clean.out, end), Vec::<f64>::new());
    let faulty = run(&flight, &p.fusion, FilterKind::IakfTdoa, true);
    let at = resets(&faulty.out, end);
    assert!(
        at.len() == 1 && (FAULT_AT_S..FAULT_AT_S + 1.0).contains(&at[0]),
        "{at:?}"
    );
    assert!(p.fusion.engine.monitor.outlier_window_s > 0.0);
    p.fusion.engine.monitor.outlier_window_s = 0.0;
    let late = resets(
        &run(&flight, &p.fusion, FilterKind::IakfTdoa, true).out,
        end,
    );
    assert!(
        late.first().is_none_or(|&t| t > FAULT_AT_S + 1.0),
        "without the outliers' share: {late:?}"
    );
}

/// The paper's IAKF diverges on this flight by itself.
#[test]
fn the_monitor_resets_the_papers_iakf_where_it_diverges() {
    monitor_catches_a_divergence(FilterKind::Iakf, false);
}

/// With the preset's vibration noise on, neither filter diverges: the IAKF
/// stays within the bound by itself, and the tight filter comes back from
/// the IMU fault without a reset (the fault reads as shaking, which raises
/// its velocity noise until the TDOA differences have pulled the INS
/// back): at most `FAULT_BOUND_M` off while the fault lasts, within the
/// bound from `FAULT_SETTLE_S` after its end. The monitor stays quiet.
#[test]
fn with_the_vibration_noise_neither_filter_diverges() {
    let Some(dir) = data_dir(FLIGHT) else {
        return;
    };
    let mut p = preset();
    free_vehicle(&mut p.fusion);
    assert!(p.fusion.vibration.corr_time_s > 0.0);
    let flight = load(&dir, FLIGHT, ANCHORS, &p);
    let end = secs(flight_segment(&flight.truth, MIN_HEIGHT_M).unwrap().1);
    for (kind, fault) in [(FilterKind::Iakf, false), (FilterKind::IakfTdoa, true)] {
        let r = run(&flight, &p.fusion, kind, fault);
        let (from, to) = (FAULT_AT_S, FAULT_AT_S + FAULT_S + FAULT_SETTLE_S);
        let (during, after) = if fault {
            (
                max_err(&r, from, to),
                max_err(&r, 0.0, from).max(max_err(&r, to, end)),
            )
        } else {
            (0.0, max_err(&r, 0.0, end))
        };
        println!(
            "{kind:?} (fault {fault}): max error {during:.2} m with the fault, \
             {after:.2} m elsewhere, {:?}",
            r.out.fusion
        );
        assert!(after < BOUND_M, "{kind:?}: {after:.2} m");
        assert!(during < FAULT_BOUND_M, "{kind:?}: {during:.2} m");
        assert_eq!(resets(&r.out, end), Vec::<f64>::new(), "{kind:?}");
    }
}
