//! One path for a measurement: a simulated log seeded with every kind of bad
//! IMU sample and TDOA measurement (NaN and infinite values, values out of
//! range, one anchor twice, a difference longer than its anchors' distance,
//! a time going backwards, a repeated IMU time, a repeated anchor pair) is
//! replayed through the real processes and run through `insuwb eval`'s
//! in-process code path (`insuwb_fusion::runner`). Both refuse the same
//! samples: the drivers' heartbeat counters equal the runner's per-reason
//! refusals, which are the seeded ones; the recording holds exactly the
//! samples the gates pass, and the fixes and fused states are the runner's.
//!
//! The test starts processes: one at a time (a lock).

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::Path;

use insuwb_log::{LogWriter, Record};
use insuwb_msg::check::{ImuGate, ImuRefusals, TdoaGate, TdoaRefusals};
use insuwb_msg::{FilterKind, ImuSample, UwbTdoa};

use crate::common;
use common::{f, offline_run, one_at_a_time, records, run, succeeded, undegraded_fused, Group};

/// `s` at `dt_ns` after its own time, with `edit` applied.
fn imu_at(s: &ImuSample, dt_ns: i64, edit: impl Fn(&mut ImuSample)) -> Record {
    let mut b = *s;
    b.header.meas_time_ns = s.header.meas_time_ns.saturating_add_signed(dt_ns);
    edit(&mut b);
    Record::Imu(b)
}

fn tdoa_with(m: &UwbTdoa, edit: impl Fn(&mut UwbTdoa)) -> Record {
    let mut b = *m;
    edit(&mut b);
    Record::Tdoa(b)
}

/// Distance between a measurement's anchors, m.
fn baseline_m(m: &UwbTdoa) -> f64 {
    (0..3)
        .map(|i| (m.anchor_a_pos_m[i] - m.anchor_b_pos_m[i]).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// The records of `clean` with bad samples inserted after some of its
/// IMU samples and TDOA measurements, each stream kept in its order (a
/// sample whose time goes backwards stays behind its predecessor, as a
/// sensor would send it); and what each gate must refuse of them.
fn seeded(clean: &[Record]) -> (Vec<Record>, ImuRefusals, TdoaRefusals) {
    let imu: Vec<ImuSample> = clean
        .iter()
        .filter_map(|r| match r {
            Record::Imu(s) => Some(*s),
            _ => None,
        })
        .collect();
    let tdoa: Vec<UwbTdoa> = clean
        .iter()
        .filter_map(|r| match r {
            Record::Tdoa(m) => Some(*m),
            _ => None,
        })
        .collect();
    assert!(
        imu.len() > 1000 && tdoa.len() > 450,
        "{} {}",
        imu.len(),
        tdoa.len()
    );
    let (mut ki, mut kt) = (0usize, 0usize);
    let mut out = Vec::new();
    for r in clean {
        out.push(*r);
        match r {
            Record::Imu(s) => {
                let bad = match ki {
                    300 => Some(imu_at(s, 3_000_000, |b| b.accel_mps2[0] = f64::NAN)),
                    400 => Some(imu_at(s, 3_000_000, |b| b.accel_mps2[2] = 450.0)),
                    500 => Some(imu_at(s, 3_000_000, |b| b.gyro_rps[1] = f64::INFINITY)),
                    600 => Some(imu_at(s, 3_000_000, |b| b.gyro_rps[2] = -80.0)),
                    // Its predecessor's time again, other values.
                    700 => Some(imu_at(s, 0, |b| b.accel_mps2[0] += 0.5)),
                    // Three samples back.
                    800 => Some(Record::Imu(imu[ki - 3])),
                    // Back in time and not finite: refused for its value.
                    900 => Some(imu_at(s, -20_000_000, |b| b.gyro_rps[0] = f64::NAN)),
                    _ => None,
                };
                out.extend(bad);
                ki += 1;
            }
            Record::Tdoa(m) => {
                let bad = match kt {
                    60 => Some(tdoa_with(m, |b| b.diff_m = f64::NAN)),
                    120 => Some(tdoa_with(m, |b| b.anchor_b_pos_m[1] = f64::NAN)),
                    180 => Some(tdoa_with(m, |b| b.anchor_b = b.anchor_a)),
                    240 => Some(tdoa_with(m, |b| b.diff_m = baseline_m(b) + 0.5)),
                    // The same pair again at its time.
                    300 => Some(Record::Tdoa(*m)),
                    // The pair the other way round at its time.
                    330 => Some(tdoa_with(m, |b| {
                        (b.anchor_a, b.anchor_b) = (b.anchor_b, b.anchor_a);
                        b.anchor_a_pos_m = m.anchor_b_pos_m;
                        b.anchor_b_pos_m = m.anchor_a_pos_m;
                        b.diff_m = -m.diff_m;
                    })),
                    // A measurement of an earlier epoch.
                    400 => Some(Record::Tdoa(tdoa[kt - 20])),
                    _ => None,
                };
                out.extend(bad);
                kt += 1;
            }
            _ => {}
        }
    }
    let imu_refused = ImuRefusals {
        non_finite: 3,
        out_of_range: 2,
        time_backwards: 1,
        time_repeated: 1,
    };
    let tdoa_refused = TdoaRefusals {
        non_finite: 2,
        same_anchor: 1,
        impossible: 1,
        time_backwards: 1,
        pair_repeated: 2,
    };
    (out, imu_refused, tdoa_refused)
}

/// The samples of `recs` that the gates pass, with their times less
/// `offset_ns`: IMU `(time, accel, gyro)` and TDOA `(time, a, b, diff)`.
#[allow(clippy::type_complexity)]
fn passed(
    recs: &[Record],
    gated: bool,
    offset_ns: u64,
) -> (Vec<(u64, [f64; 3], [f64; 3])>, Vec<(u64, u32, u32, f64)>) {
    let (mut ig, mut tg) = (ImuGate::new(), TdoaGate::new());
    let (mut imu, mut tdoa) = (Vec::new(), Vec::new());
    for r in recs {
        match r {
            Record::Imu(s) if !gated || ig.check(s).is_ok() => {
                imu.push((s.header.meas_time_ns - offset_ns, s.accel_mps2, s.gyro_rps))
            }
            Record::Tdoa(m) if !gated || tg.check(m).is_ok() => tdoa.push((
                m.header.meas_time_ns - offset_ns,
                m.anchor_a,
                m.anchor_b,
                m.diff_m,
            )),
            _ => {}
        }
    }
    (imu, tdoa)
}

fn write_log(path: &Path, meta: &insuwb_log::Metadata, recs: &[Record]) {
    let mut w = LogWriter::create(path, meta, 0).unwrap();
    for r in recs {
        w.append(r).unwrap();
    }
    w.finish().unwrap();
}

#[test]
fn eval_and_the_drivers_refuse_the_same_samples() {
    let _lock = one_at_a_time();
    let tmp = std::env::temp_dir().join(format!("insuwb-test-refusals-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir_all(&tmp).unwrap();
    let clean_log = tmp.join("clean.iulog");
    succeeded(&run(&[
        "sim",
        "--scenario",
        "paper-4.4-dynamic",
        "--seed",
        "5",
        "--out",
        clean_log.to_str().unwrap(),
    ]));
    let (clean, _, header) = insuwb_log::read_all(&clean_log).unwrap();
    let (bad, imu_seeded, tdoa_seeded) = seeded(&clean);
    let log = tmp.join("seeded.iulog");
    write_log(&log, &header.meta, &bad);

    // `insuwb eval`'s code path: the seeded refusals on top of what the
    // clean log has (a simulated NLOS burst may hold an impossible
    // difference), by reason.
    let base = offline_run(&clean_log, FilterKind::Iakf).refusals;
    let out = offline_run(&log, FilterKind::Iakf);
    let r = out.refusals;
    let minus_imu = |a: ImuRefusals, b: ImuRefusals| ImuRefusals {
        non_finite: a.non_finite - b.non_finite,
        out_of_range: a.out_of_range - b.out_of_range,
        time_backwards: a.time_backwards - b.time_backwards,
        time_repeated: a.time_repeated - b.time_repeated,
    };
    let minus_tdoa = |a: TdoaRefusals, b: TdoaRefusals| TdoaRefusals {
        non_finite: a.non_finite - b.non_finite,
        same_anchor: a.same_anchor - b.same_anchor,
        impossible: a.impossible - b.impossible,
        time_backwards: a.time_backwards - b.time_backwards,
        pair_repeated: a.pair_repeated - b.pair_repeated,
    };
    assert_eq!(minus_imu(r.imu, base.imu), imu_seeded);
    assert_eq!(minus_tdoa(r.tdoa, base.tdoa), tdoa_seeded);

    // The processes, replaying the seeded log at 10x (lazily, as eval
    // predicts: see `replay_at_10x_through_the_processes_equals_eval`).
    let g = Group::with_config(
        "refusals",
        &format!(
            "imu = \"replay:{0}\"\nuwb = \"replay:{0}\"\nspeed = 10.0",
            log.display()
        ),
        "filter = \"iakf\"\neager_lag_s = -1.0\n",
        "",
    );
    // 18 s of data at 10x.
    let report = g.launch(4.0, &[]);
    let stage = |name: &str, key: &str| f(&report["stages"][name], key) as u64;
    eprintln!(
        "refused: imu {:?}, tdoa {:?}; fix builder: impossible once calibrated {}, pair table full {}",
        r.imu, r.tdoa, out.fix_stats.dropped_impossible, out.fix_stats.dropped_capacity
    );
    assert_eq!(stage("imu", "dropped_invalid"), r.imu.invalid(), "{report}");
    assert_eq!(stage("imu", "dropped_time"), r.imu.time(), "{report}");
    assert_eq!(
        stage("uwb", "dropped_invalid"),
        r.tdoa.invalid(),
        "{report}"
    );
    assert_eq!(stage("uwb", "dropped_time"), r.tdoa.time(), "{report}");

    // What the drivers published (the logger's recording) is what the
    // gates pass of the seeded log, which is what they pass of the clean one.
    let recorded = records(&g.log_dir());
    let first = |recs: &[Record]| {
        recs.iter()
            .find_map(|r| match r {
                Record::Imu(s) if s.accel_mps2.iter().all(|v| v.is_finite()) => {
                    Some(s.header.meas_time_ns)
                }
                _ => None,
            })
            .unwrap()
    };
    let offset = first(&recorded) - first(&clean);
    let (rec_imu, rec_tdoa) = passed(&recorded, false, offset);
    let (want_imu, want_tdoa) = passed(&bad, true, 0);
    assert_eq!(
        passed(&clean, true, 0),
        (want_imu.clone(), want_tdoa.clone())
    );
    assert_eq!(rec_imu.len(), want_imu.len());
    assert!(
        rec_imu == want_imu,
        "the IMU driver published other samples"
    );
    assert_eq!(rec_tdoa.len(), want_tdoa.len());
    assert!(
        rec_tdoa == want_tdoa,
        "the UWB driver published other measurements"
    );

    // The same fixes ...
    let fixes: Vec<(u64, [f64; 3])> = recorded
        .iter()
        .filter_map(|r| match r {
            Record::Fix(x) => Some((x.header.meas_time_ns - offset, x.pos_m)),
            _ => None,
        })
        .collect();
    let eval_fixes: Vec<(u64, [f64; 3])> = out
        .fixes
        .iter()
        .map(|x| (x.header.meas_time_ns, x.pos_m))
        .collect();
    assert!(eval_fixes.len() > 150, "{} fixes", eval_fixes.len());
    // (the builder's last epoch is flushed at the end of a run only).
    assert!(
        fixes.len() + 1 >= eval_fixes.len() && fixes.len() <= eval_fixes.len(),
        "{} fixes published, {} in eval",
        fixes.len(),
        eval_fixes.len()
    );
    for (p, e) in fixes.iter().zip(&eval_fixes) {
        assert_eq!(p.0, e.0);
        let d = (0..3).map(|i| (p.1[i] - e.1[i]).abs()).fold(0.0, f64::max);
        assert!(d <= 1e-9, "fix at {} ns differs by {d} m", p.0);
    }
    // ... and the same fused states.
    let piped = undegraded_fused(&g.log_dir());
    common::assert_same_fused(&piped, &out.fused);
    let _ = std::fs::remove_dir_all(&tmp);
}
