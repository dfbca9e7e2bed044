//! `insuwb soak`: the group for hours under periodic random faults, with
//! the Foxglove live view, the Zenoh bridge and the logger, looking every
//! minute at each process's resident memory, open file descriptors, the
//! group's shared-memory files and the fused rate; then whether anything
//! grew after warm-up. The chaos run of [`crate::chaos_cmd`] underneath,
//! with its undisturbed twin for the accuracy.

use std::collections::BTreeMap;
use std::time::Duration;

use anyhow::{bail, Result};

use insuwb_bench::cpu::warm_up_s;

use crate::chaos_cmd::{print_report, run_chaos, ChaosReport, ChaosRun};
use crate::group_run::ResourceSample;

/// Arguments of `insuwb soak`.
#[derive(Debug, clap::Args)]
pub struct SoakArgs {
    /// Seconds to run (at least 4 looks).
    #[arg(long, default_value_t = 3600.0)]
    pub duration: f64,
    /// Seed of the fault schedule.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Seconds between two looks at the processes.
    #[arg(long, default_value_t = 60.0)]
    pub every: f64,
    /// Print one JSON object on standard output.
    #[arg(long)]
    pub json: bool,
    /// Keep both groups' run directories and print where they are.
    #[arg(long)]
    pub keep: bool,
}

/// A process's resources at the end of warm-up, at the last look that
/// found it alive, and the most seen after warm-up.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct Growth {
    /// Anonymous resident memory (heap and stacks, `RssAnon`) at the end
    /// of warm-up, KiB.
    pub rss_anon_warm_kib: u64,
    /// At the last look that found it alive.
    pub rss_anon_last_kib: u64,
    /// The most after warm-up.
    pub rss_anon_max_kib: u64,
    /// Open file descriptors at the end of warm-up.
    pub fds_warm: u64,
    /// At the last look that found it alive.
    pub fds_last: u64,
    /// The most after warm-up.
    pub fds_max: u64,
}

/// What `insuwb soak` reports: the chaos run's figures (with every look in
/// `samples`) and what grew.
#[derive(Debug, serde::Serialize)]
struct SoakReport {
    #[serde(flatten)]
    chaos: ChaosReport,
    /// Seconds of warm-up: the first look at or after it is the reference.
    warm_up_s: f64,
    /// Each process seen at the end of warm-up and at the last look.
    growth: BTreeMap<String, Growth>,
    /// The group's shared-memory files at the end of warm-up and at the last look.
    group_files_warm: usize,
    /// At the last look.
    group_files_last: usize,
    /// The lowest fused rate of a look after warm-up, Hz.
    fused_rate_min_hz: f64,
}

/// Each process's growth between the first look at or after `warm_s` and
/// the last; the files and the lowest rate likewise.
fn growth(
    samples: &[ResourceSample],
    warm_s: f64,
) -> (BTreeMap<String, Growth>, usize, usize, f64) {
    let after: Vec<&ResourceSample> = samples.iter().filter(|s| s.elapsed_s >= warm_s).collect();
    let (Some(warm), Some(last)) = (after.first(), after.last()) else {
        return (BTreeMap::new(), 0, 0, 0.0);
    };
    let mut out = BTreeMap::new();
    let names: std::collections::BTreeSet<&str> = after
        .iter()
        .flat_map(|s| s.processes.iter().map(|(n, _)| n))
        .collect();
    for name in names {
        // A stage restarting at a look: its first and last looks alive.
        let (Some(w), Some(l)) = (
            after.iter().find_map(|s| s.processes.get(name)),
            after.iter().rev().find_map(|s| s.processes.get(name)),
        ) else {
            continue;
        };
        let seen = after.iter().filter_map(|s| s.processes.get(name));
        let (rss_max, fds_max) =
            seen.fold((0, 0), |(r, f), p| (p.rss_anon_kib.max(r), p.fds.max(f)));
        out.insert(
            name.to_owned(),
            Growth {
                rss_anon_warm_kib: w.rss_anon_kib,
                rss_anon_last_kib: l.rss_anon_kib,
                rss_anon_max_kib: rss_max,
                fds_warm: w.fds,
                fds_last: l.fds,
                fds_max,
            },
        );
    }
    let rate_min = after
        .iter()
        .map(|s| s.fused_rate_hz)
        .fold(f64::INFINITY, f64::min);
    (out, warm.group_files, last.group_files, rate_min)
}

/// Runs `insuwb soak`.
pub fn soak(a: &SoakArgs) -> Result<()> {
    if !(a.every.is_finite() && a.every >= 1.0) {
        bail!("--every must be at least 1 s, got {}", a.every);
    }
    if !(a.duration.is_finite() && a.duration >= 4.0 * a.every && a.duration <= 86_400.0) {
        bail!(
            "--duration must be in [4 x --every, 86400] s, got {} (--every {})",
            a.duration,
            a.every
        );
    }
    let chaos = run_chaos(&ChaosRun {
        duration_s: a.duration,
        seed: a.seed,
        live: false,
        keep: a.keep,
        bridges: true,
        sample_every: Some(Duration::from_secs_f64(a.every)),
    })?;
    let warm_s = warm_up_s(a.duration);
    let (growth, files_warm, files_last, rate_min) = growth(&chaos.samples, warm_s);
    print_report(
        &SoakReport {
            chaos,
            warm_up_s: warm_s,
            growth,
            group_files_warm: files_warm,
            group_files_last: files_last,
            fused_rate_min_hz: rate_min,
        },
        a.json,
    )
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;
    use crate::group_run::LookedProcesses;
    use crate::resources::ProcessResources;

    fn look(t: f64, rss: u64, fds: u64, files: usize, rate: f64) -> ResourceSample {
        let p = ProcessResources {
            pid: 1,
            rss_kib: rss + 1000,
            rss_anon_kib: rss,
            fds,
        };
        ResourceSample {
            elapsed_s: t,
            fused_rate_hz: rate,
            rmse_horizontal: None,
            restarts: 0,
            group_files: files,
            processes: {
                let mut t = LookedProcesses::default();
                assert!(t.insert("fusion", p));
                t
            },
        }
    }

    #[test]
    fn growth_is_measured_from_the_end_of_warm_up() {
        assert_eq!(warm_up_s(3600.0), 300.0);
        assert_eq!(warm_up_s(600.0), 120.0);
        let samples = [
            look(60.0, 100, 10, 5, 9.0),
            look(120.0, 200, 12, 7, 10.0),
            look(180.0, 260, 13, 7, 9.5),
            look(240.0, 210, 12, 7, 10.0),
        ];
        let (g, warm, last, rate) = growth(&samples, 120.0);
        assert_eq!(
            g["fusion"],
            Growth {
                rss_anon_warm_kib: 200,
                rss_anon_last_kib: 210,
                rss_anon_max_kib: 260,
                fds_warm: 12,
                fds_last: 12,
                fds_max: 13
            }
        );
        assert_eq!((warm, last), (7, 7));
        assert_eq!(rate, 9.5);
        assert!(growth(&samples, 500.0).0.is_empty());
        // A stage restarting at the end of warm-up: from its next look.
        let mut gone = samples.clone();
        gone[1].processes.clear();
        let (g, ..) = growth(&gone, 120.0);
        assert_eq!(g["fusion"].rss_anon_warm_kib, 260);
    }
}
