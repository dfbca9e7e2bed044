//! `insuwb eval --flights MANIFEST.csv`: every flight of a manifest,
//! evaluated in parallel as `insuwb eval FILE --anchors A` evaluates one,
//! then one row per flight and a summary per solution against the
//! manifest's reference columns. With `--aiding flow`, a flight whose log
//! holds no flow records is left out and named (the others are evaluated).
//! The progress bar on a terminal is `indicatif`'s.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use insuwb_eval::batch::{self, FlightMetrics, Manifest, ManifestFlight};

use crate::dataset::NoFlowRecords;
use crate::eval_cmd::{evaluate_file, print_result, write_plots, EvalArgs};

/// Runs `insuwb eval --flights MANIFEST`.
pub fn eval_flights(a: &EvalArgs, manifest_path: &Path) -> Result<()> {
    let manifest = Manifest::load(manifest_path)?;
    let calibration = a
        .calibration
        .as_deref()
        .map(crate::calibrate_cmd::CalibrationFile::load)
        .transpose()?;
    let jobs = a.jobs.map_or_else(
        || std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get),
        std::num::NonZeroUsize::get,
    );
    // Longest first: the file size stands for the flight's run time.
    let costs: Vec<u64> = manifest
        .flights
        .iter()
        .map(|f| std::fs::metadata(&f.file).map_or(0, |m| m.len()))
        .collect();
    // Hidden by indicatif when standard error is not a terminal.
    let bar = progress_bar(manifest.flights.len());
    // Written between the bar's redraws, the flights' log lines would break
    // it: on the worker threads they go through the bar, which clears
    // itself, writes them and redraws below them.
    let above_bar = (!bar.is_hidden()).then(|| {
        let bar = bar.clone();
        tracing::Dispatch::new(
            tracing_subscriber::fmt()
                .with_writer(move || AboveBar(bar.clone()))
                .with_ansi(true)
                .with_env_filter(
                    tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| {
                        tracing_subscriber::EnvFilter::new(insuwb_runtime::DEFAULT_LOG_FILTER)
                    }),
                )
                .finish(),
        )
    });
    let t0 = std::time::Instant::now();
    let results = batch::map_in_parallel(
        &costs,
        jobs,
        |i| {
            let f = &manifest.flights[i];
            match &above_bar {
                Some(d) => tracing::dispatcher::with_default(d, || {
                    evaluate_flight(a, f, calibration.as_ref())
                }),
                None => evaluate_flight(a, f, calibration.as_ref()),
            }
        },
        |done, _| bar.set_position(done as u64),
    );
    bar.finish();
    let results = results.map_err(|e| e.error.context(manifest.flight_label(e.index)))?;
    let (manifest, results, left_out) = keep_evaluated(manifest, results)?;
    tracing::info!(
        "evaluated {} flights in {:.2} s on {} thread(s)",
        results.len(),
        t0.elapsed().as_secs_f64(),
        jobs.min(results.len())
    );
    let summary = batch::summarize(&manifest, &results);
    if let Some(dir) = &a.plot {
        let file = insuwb_eval::plot::write_summary_figure(&manifest, &results, dir)?;
        tracing::info!("wrote {}", file.display());
    }
    let mut head = manifest.path.display().to_string();
    if !left_out.is_empty() {
        head.push_str(&format!(
            "\n{} of {} flights left out, their logs hold no optical-flow records: {}",
            left_out.len(),
            left_out.len() + results.len(),
            left_out.join(", ")
        ));
    }
    let table = format!(
        "{head}\n{}\n{}",
        batch::format_flights(&manifest, &results, &summary),
        batch::format_summary(&manifest, &summary)
    );
    print_result(a.json, &table, || {
        let mut v = batch::to_json(&manifest, &results, &summary)
            .map_err(|e| anyhow::anyhow!("{}: {e}", manifest.path.display()))?;
        if let Some(o) = v.as_object_mut() {
            o.insert("left_out".into(), left_out.clone().into());
        }
        Ok(v)
    })
}

/// The manifest cut to the flights evaluated, their metrics, and the names
/// of those left out (`None`: no records of the aiding).
///
/// # Errors
/// Every flight was left out.
pub(crate) fn keep_evaluated<T>(
    manifest: Manifest,
    results: Vec<Option<T>>,
) -> Result<(Manifest, Vec<T>, Vec<String>)> {
    let mut kept = Manifest {
        flights: Vec::new(),
        ..manifest.clone()
    };
    let mut metrics = Vec::new();
    let mut left_out = Vec::new();
    for (f, r) in manifest.flights.into_iter().zip(results) {
        match r {
            Some(m) => {
                kept.flights.push(f);
                metrics.push(m);
            }
            None => left_out.push(f.name),
        }
    }
    if metrics.is_empty() {
        anyhow::bail!(
            "{}: no flight's log holds optical-flow records: --aiding flow needs logs of vehicles with a flow deck",
            kept.path.display()
        );
    }
    Ok((kept, metrics, left_out))
}

/// Evaluates one flight; with `--plot DIR`, its figures go to `DIR/<name>/`.
/// `None`: the log holds none of the aiding's records.
fn evaluate_flight(
    a: &EvalArgs,
    f: &ManifestFlight,
    calibration: Option<&crate::calibrate_cmd::CalibrationFile>,
) -> Result<Option<FlightMetrics>> {
    let evaluated = evaluate_file(
        &f.file,
        f.anchors.as_ref(),
        a.config.as_deref(),
        a.ignore_crc,
        a.filters.as_deref(),
        calibration,
        crate::dataset::RunChoice {
            vehicle: a.vehicle,
            aiding: a.aiding,
            segment: a.segment.or(f.segment),
        },
    );
    let (loaded, rep) = match evaluated {
        Err(e) if NoFlowRecords::is_cause_of(&e) => {
            tracing::warn!("{e}: left out");
            return Ok(None);
        }
        r => r?,
    };
    if let Some(dir) = &a.plot {
        write_plots(&rep, &loaded.data, &dir.join(figure_folder(&f.name)))
            .context("writing the figures")?;
    }
    Ok(Some(
        rep.solutions
            .into_iter()
            .map(|s| (s.key, s.metrics))
            .collect(),
    ))
}

/// A flight's name as one folder name: path separators and dots that could
/// leave the figure folder become `_`.
fn figure_folder(name: &str) -> PathBuf {
    let s: String = name
        .chars()
        .map(|c| if c == '/' || c == '\\' { '_' } else { c })
        .collect();
    PathBuf::from(if s.chars().all(|c| c == '.') {
        s.replace('.', "_")
    } else {
        s
    })
}

/// The flights' progress on standard error, `[#####     ] 7/23`
/// (`indicatif`; hidden where standard error is not a terminal).
fn progress_bar(flights: usize) -> ProgressBar {
    let bar = ProgressBar::new(flights as u64);
    if let Ok(style) = ProgressStyle::with_template("[{bar:30}] {pos}/{len}") {
        bar.set_style(style.progress_chars("## "));
    }
    bar
}

/// A log line's writer that writes it above the progress bar
/// (`ProgressBar::suspend`: the bar is cleared, the line written to
/// standard error, the bar redrawn).
struct AboveBar(ProgressBar);

impl Write for AboveBar {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0
            .suspend(|| std::io::stderr().lock().write_all(buf))
            .map(|()| buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        std::io::stderr().flush()
    }
}

#[cfg(test)]
mod tests {
    use super::{figure_folder, keep_evaluated};
    use insuwb_eval::batch::Manifest;
    use std::path::Path;

    #[test]
    fn flights_without_the_aiding_are_left_out_by_name_in_order() {
        let path = Path::new("/m/flights.csv");
        let text = "file,anchors,uwb_ls_ref_m\na,x.txt,0.1\nb,x.txt,0.2\nc,x.txt,0.3\n";
        let m = Manifest::parse(text, path).unwrap();
        let (kept, metrics, left_out) =
            keep_evaluated(m.clone(), vec![Some(1), None, Some(3)]).unwrap();
        let names: Vec<&str> = kept.flights.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(names, ["a", "c"]);
        assert_eq!(kept.flights[1].references, [Some(0.3)]);
        assert_eq!(metrics, [1, 3]);
        assert_eq!(left_out, ["b"]);
        let err = keep_evaluated::<u8>(m, vec![None, None, None]).unwrap_err();
        assert!(
            err.to_string()
                .starts_with("/m/flights.csv: no flight's log holds optical-flow records"),
            "{err}"
        );
    }

    #[test]
    fn figure_folders_stay_inside_the_plot_folder() {
        assert_eq!(figure_folder("cfBolt-log00"), Path::new("cfBolt-log00"));
        assert_eq!(figure_folder("sub/log.bin"), Path::new("sub_log.bin"));
        assert_eq!(figure_folder("../x"), Path::new(".._x"));
        assert_eq!(figure_folder(".."), Path::new("__"));
    }
}
