//! Batch evaluation of many flights: the manifest that lists them, a work
//! queue that evaluates them on several threads and keeps the results in
//! manifest order, and the summary of each solution against the reference
//! columns (median and worst ratio, flights above 1).
//!
//! A manifest is a CSV file with a header line. It has at least the columns
//! `file` (the log) and `anchors` (its anchor survey; may be empty for an
//! insuwb log, which needs none), both relative to the manifest's folder.
//! Every other column whose name ends in `_m` holds a reference horizontal
//! RMSE in metres (empty: no reference for that flight); the remaining
//! columns are ignored. Fields are separated by commas and not quoted; blank
//! lines and lines starting with `#` are skipped.
//!
//! ```
//! use std::path::Path;
//! use insuwb_eval::batch::{ratio_stats, Manifest};
//!
//! let text = "file,anchors,mode,uwb_ls_ref_m\nlog-a,anchors.txt,tdoa2,0.150\nlog-b,anchors.txt,tdoa3,\n";
//! let m = Manifest::parse(text, Path::new("data/flights.csv"))?;
//! assert_eq!(m.references, ["uwb_ls_ref_m"]);
//! assert_eq!(m.flights[0].file, Path::new("data/log-a"));
//! assert_eq!(m.flights[0].references, [Some(0.150)]);
//! assert_eq!(m.flights[1].references, [None]);
//!
//! let s = ratio_stats(&[0.8, 1.2, 0.9]).unwrap();
//! assert_eq!((s.median, s.worst, s.above_1, s.flights), (0.9, 1.2, 1, 3));
//! # Ok::<(), insuwb_eval::batch::ManifestError>(())
//! ```
//!
//! The results of [`map_in_parallel`] do not depend on the number of threads:
//! each item's result is stored at its index, and each item is computed by
//! the same function on the same input whichever thread runs it.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Mutex;

use crate::metrics::Metrics;

/// The column naming each flight's log.
pub const FILE_COLUMN: &str = "file";
/// The column naming each flight's anchor survey.
pub const ANCHORS_COLUMN: &str = "anchors";
/// The optional column saying which part of each log is evaluated
/// (`flight`, `all`; empty: the config's).
pub const SEGMENT_COLUMN: &str = "segment";
/// Columns whose name ends in this hold reference horizontal RMSEs (m).
pub const REFERENCE_SUFFIX: &str = "_m";

/// Why a manifest could not be used. Every variant names the manifest; those
/// about one cell name its line (1-based, the header is line 1) and column.
#[derive(Debug, thiserror::Error)]
pub enum ManifestError {
    /// The manifest could not be read.
    #[error("{}: cannot read the manifest: {error}", path.display())]
    Read {
        /// The manifest.
        path: PathBuf,
        /// Why (shown in the message, not exposed as the source: once in a chain).
        error: std::io::Error,
    },
    /// The manifest has no header line.
    #[error("{}: the manifest is empty (a header line with `file` and `anchors` is needed)", path.display())]
    NoHeader {
        /// The manifest.
        path: PathBuf,
    },
    /// The manifest lists no flight.
    #[error("{}: the manifest lists no flight", path.display())]
    NoFlights {
        /// The manifest.
        path: PathBuf,
    },
    /// A `segment` cell that is neither `flight` nor `all`.
    #[error("{}:{line}: column `segment`: `{value}` is neither `flight` nor `all`", path.display())]
    BadSegment {
        /// The manifest.
        path: PathBuf,
        /// The line.
        line: usize,
        /// The cell.
        value: String,
    },
    /// A required column is missing from the header.
    #[error("{}:{line}: the header has no column `{column}`", path.display())]
    MissingColumn {
        /// The manifest.
        path: PathBuf,
        /// The header's line.
        line: usize,
        /// The column.
        column: &'static str,
    },
    /// A column name appears twice in the header.
    #[error("{}:{line}: column `{column}` appears twice in the header", path.display())]
    DuplicateColumn {
        /// The manifest.
        path: PathBuf,
        /// The header's line.
        line: usize,
        /// The column.
        column: String,
    },
    /// A line has another number of fields than the header.
    #[error("{}:{line}: {found} fields, the header has {expected}", path.display())]
    FieldCount {
        /// The manifest.
        path: PathBuf,
        /// The line.
        line: usize,
        /// Fields in the header.
        expected: usize,
        /// Fields on this line.
        found: usize,
    },
    /// A cell that must hold a file name is empty.
    #[error("{}:{line}: column `{column}` is empty", path.display())]
    EmptyCell {
        /// The manifest.
        path: PathBuf,
        /// The line.
        line: usize,
        /// The column.
        column: &'static str,
    },
    /// A file named by a cell does not exist.
    #[error("{}:{line}: column `{column}`: no such file {}", path.display(), file.display())]
    MissingFile {
        /// The manifest.
        path: PathBuf,
        /// The line.
        line: usize,
        /// The column.
        column: &'static str,
        /// The file, resolved against the manifest's folder.
        file: PathBuf,
    },
    /// A reference cell is not a positive finite number.
    #[error("{}:{line}: column `{column}`: '{value}' is not a positive number of metres", path.display())]
    BadNumber {
        /// The manifest.
        path: PathBuf,
        /// The line.
        line: usize,
        /// The column.
        column: String,
        /// The cell as written.
        value: String,
    },
}

/// One flight of a manifest.
#[derive(Debug, Clone, PartialEq)]
pub struct ManifestFlight {
    /// Its line in the manifest (1-based).
    pub line: usize,
    /// The `file` cell as written: the flight's name in reports.
    pub name: String,
    /// The log, resolved against the manifest's folder.
    pub file: PathBuf,
    /// The anchor survey, resolved against the manifest's folder (`None` when the cell is empty).
    pub anchors: Option<PathBuf>,
    /// One value per [`Manifest::references`] column (`None`: empty cell).
    pub references: Vec<Option<f64>>,
    /// The [`SEGMENT_COLUMN`] cell (`None`: no such column, or empty).
    pub segment: Option<crate::run::Segment>,
}

/// A parsed manifest.
#[derive(Debug, Clone, PartialEq)]
pub struct Manifest {
    /// The manifest's path, for messages.
    pub path: PathBuf,
    /// The reference columns (names ending in `_m`), in header order.
    pub references: Vec<String>,
    /// The flights, in manifest order.
    pub flights: Vec<ManifestFlight>,
}

impl Manifest {
    /// `flight NAME (MANIFEST, line N)` for the flight at `index` (its
    /// position in [`Manifest::flights`]): how errors name a flight.
    #[must_use]
    pub fn flight_label(&self, index: usize) -> String {
        match self.flights.get(index) {
            Some(f) => format!(
                "flight {} ({}, line {})",
                f.name,
                self.path.display(),
                f.line
            ),
            None => format!("flight {index} ({})", self.path.display()),
        }
    }

    /// Width of the flight-name column of a table: the longest name, at
    /// least 6.
    #[must_use]
    pub fn name_width(&self) -> usize {
        self.flights
            .iter()
            .map(|f| f.name.len())
            .max()
            .unwrap_or(0)
            .max(6)
    }

    /// Reads and parses the manifest at `path` and checks that every file it
    /// names exists.
    ///
    /// # Errors
    /// [`ManifestError`] naming the manifest, and the line and column at fault.
    pub fn load(path: &Path) -> Result<Self, ManifestError> {
        let text = std::fs::read_to_string(path).map_err(|error| ManifestError::Read {
            path: path.to_owned(),
            error,
        })?;
        let m = Self::parse(&text, path)?;
        m.check_files()?;
        Ok(m)
    }

    /// Parses manifest text; `path` names it in errors and its folder
    /// resolves the relative file names. Does not look at the files.
    ///
    /// # Errors
    /// [`ManifestError`] naming the manifest, and the line and column at fault.
    pub fn parse(text: &str, path: &Path) -> Result<Self, ManifestError> {
        let base = path.parent().unwrap_or_else(|| Path::new(""));
        let mut lines = text
            .trim_start_matches('\u{feff}')
            .lines()
            .enumerate()
            .map(|(i, l)| (i + 1, l.trim()))
            .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
        let (header_line, header) = lines.next().ok_or_else(|| ManifestError::NoHeader {
            path: path.to_owned(),
        })?;
        let columns: Vec<&str> = split(header).collect();
        for (i, c) in columns.iter().enumerate() {
            if columns[..i].contains(c) {
                return Err(ManifestError::DuplicateColumn {
                    path: path.to_owned(),
                    line: header_line,
                    column: (*c).to_owned(),
                });
            }
        }
        let find = |column: &'static str| {
            columns
                .iter()
                .position(|c| *c == column)
                .ok_or_else(|| ManifestError::MissingColumn {
                    path: path.to_owned(),
                    line: header_line,
                    column,
                })
        };
        let file_col = find(FILE_COLUMN)?;
        let anchors_col = find(ANCHORS_COLUMN)?;
        let segment_col = columns.iter().position(|c| *c == SEGMENT_COLUMN);
        let ref_cols: Vec<usize> = (0..columns.len())
            .filter(|&i| i != file_col && i != anchors_col)
            .filter(|&i| columns[i].ends_with(REFERENCE_SUFFIX))
            .collect();
        let mut flights = Vec::new();
        for (line, text) in lines {
            let cells: Vec<&str> = split(text).collect();
            if cells.len() != columns.len() {
                return Err(ManifestError::FieldCount {
                    path: path.to_owned(),
                    line,
                    expected: columns.len(),
                    found: cells.len(),
                });
            }
            let name = cells[file_col];
            if name.is_empty() {
                return Err(ManifestError::EmptyCell {
                    path: path.to_owned(),
                    line,
                    column: FILE_COLUMN,
                });
            }
            let anchors = cells[anchors_col];
            let references = ref_cols
                .iter()
                .map(|&c| {
                    parse_reference(cells[c]).map_err(|()| ManifestError::BadNumber {
                        path: path.to_owned(),
                        line,
                        column: columns[c].to_owned(),
                        value: cells[c].to_owned(),
                    })
                })
                .collect::<Result<Vec<_>, _>>()?;
            let segment = match segment_col.map(|c| cells[c]) {
                None | Some("") => None,
                Some(cell) => Some(cell.parse::<crate::run::Segment>().map_err(|_| {
                    ManifestError::BadSegment {
                        path: path.to_owned(),
                        line,
                        value: cell.to_owned(),
                    }
                })?),
            };
            flights.push(ManifestFlight {
                line,
                name: name.to_owned(),
                file: base.join(name),
                anchors: (!anchors.is_empty()).then(|| base.join(anchors)),
                references,
                segment,
            });
        }
        if flights.is_empty() {
            return Err(ManifestError::NoFlights {
                path: path.to_owned(),
            });
        }
        Ok(Self {
            path: path.to_owned(),
            references: ref_cols.iter().map(|&c| columns[c].to_owned()).collect(),
            flights,
        })
    }

    /// Checks that every log and anchor file named exists.
    ///
    /// # Errors
    /// [`ManifestError::MissingFile`] for the first one that does not.
    pub fn check_files(&self) -> Result<(), ManifestError> {
        for f in &self.flights {
            let files = [
                (FILE_COLUMN, Some(&f.file)),
                (ANCHORS_COLUMN, f.anchors.as_ref()),
            ];
            for (column, file) in files {
                if let Some(file) = file.filter(|p| !p.is_file()) {
                    return Err(ManifestError::MissingFile {
                        path: self.path.clone(),
                        line: f.line,
                        column,
                        file: file.clone(),
                    });
                }
            }
        }
        Ok(())
    }
}

/// The fields of a line, trimmed.
fn split(line: &str) -> impl Iterator<Item = &str> {
    line.split(',').map(str::trim)
}

/// An empty cell is no reference; anything else must be a positive finite number.
fn parse_reference(cell: &str) -> Result<Option<f64>, ()> {
    if cell.is_empty() {
        return Ok(None);
    }
    match cell.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(Some(v)),
        _ => Err(()),
    }
}

/// An item of [`map_in_parallel`] that failed, with its index.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ItemError<E> {
    /// The item's index.
    pub index: usize,
    /// Its error.
    pub error: E,
}

/// Computes `work(i)` for every `i` in `0..costs.len()` on `jobs` threads
/// (at least one, at most one per item) and returns the results in index
/// order. Items are handed out from a shared queue, the most costly first
/// (`costs`: any figure that orders the items' run times, such as file
/// sizes), so that a long item does not start last. `progress(done, total)`
/// is called, from the worker threads, after each item.
///
/// After the first failure no new item starts; the error returned is that of
/// the failed item with the lowest index.
///
/// # Errors
/// The failed item with the lowest index, and its error.
pub fn map_in_parallel<R, E, F, P>(
    costs: &[u64],
    jobs: usize,
    work: F,
    progress: P,
) -> Result<Vec<R>, ItemError<E>>
where
    R: Send,
    E: Send,
    F: Fn(usize) -> Result<R, E> + Sync,
    P: Fn(usize, usize) + Sync,
{
    let total = costs.len();
    let mut order: Vec<usize> = (0..total).collect();
    order.sort_by_key(|&i| std::cmp::Reverse(costs[i]));
    let next = AtomicUsize::new(0);
    let done = AtomicUsize::new(0);
    let failed = AtomicBool::new(false);
    let slots: Vec<Mutex<Option<Result<R, E>>>> = (0..total).map(|_| Mutex::new(None)).collect();
    let worker = || {
        while !failed.load(Ordering::Relaxed) {
            let Some(&i) = order.get(next.fetch_add(1, Ordering::Relaxed)) else {
                break;
            };
            let r = work(i);
            if r.is_err() {
                failed.store(true, Ordering::Relaxed);
            }
            if let Ok(mut slot) = slots[i].lock() {
                *slot = Some(r);
            }
            progress(done.fetch_add(1, Ordering::Relaxed) + 1, total);
        }
    };
    let threads = jobs.clamp(1, total.max(1));
    std::thread::scope(|s| {
        for _ in 1..threads {
            s.spawn(worker);
        }
        worker();
    });
    let mut out = Vec::with_capacity(total);
    let mut first_error = None;
    for (index, slot) in slots.into_iter().enumerate() {
        match slot.into_inner().ok().flatten() {
            Some(Ok(r)) => out.push(r),
            Some(Err(error)) => {
                first_error.get_or_insert(ItemError { index, error });
            }
            // Not run after a failure (or its worker panicked, which the
            // scope has already propagated).
            None => {}
        }
    }
    match first_error {
        Some(e) => Err(e),
        None => Ok(out),
    }
}

/// The median of the finite values (the mean of the middle two for an even
/// count), `None` when there is none.
#[must_use]
pub fn median(values: &[f64]) -> Option<f64> {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    Some(if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    })
}

/// Median and largest of a set of values.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Spread {
    /// Median.
    pub median: f64,
    /// Largest.
    pub worst: f64,
}

/// The [`Spread`] of the finite values, `None` when there is none.
#[must_use]
pub fn spread(values: &[f64]) -> Option<Spread> {
    let worst = values
        .iter()
        .copied()
        .filter(|x| x.is_finite())
        .max_by(f64::total_cmp)?;
    Some(Spread {
        median: median(values)?,
        worst,
    })
}

/// The ratios of a solution's RMSE to one reference over the flights that have both.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct RatioStats {
    /// Median ratio.
    pub median: f64,
    /// Largest ratio.
    pub worst: f64,
    /// Flights whose ratio exceeds 1 (the solution is worse than the reference).
    pub above_1: usize,
    /// Flights counted.
    pub flights: usize,
}

/// [`RatioStats`] of the finite ratios, `None` when there is none.
#[must_use]
pub fn ratio_stats(ratios: &[f64]) -> Option<RatioStats> {
    let s = spread(ratios)?;
    let finite = ratios.iter().filter(|r| r.is_finite());
    Some(RatioStats {
        median: s.median,
        worst: s.worst,
        above_1: finite.clone().filter(|r| **r > 1.0).count(),
        flights: finite.count(),
    })
}

/// The solutions' metrics on one flight, in the order the evaluation gave them.
pub type FlightMetrics = Vec<(String, Metrics)>;

/// One solution over all flights.
#[derive(Debug, Clone, PartialEq)]
pub struct SolutionSummary {
    /// The solution's key (`uwb`, `kf`, ...).
    pub key: String,
    /// Flights it ran on.
    pub flights: usize,
    /// Horizontal RMSE (m).
    pub rmse_horizontal: Spread,
    /// Ratio of the horizontal RMSE to each reference column, in
    /// [`Manifest::references`] order (`None`: no flight has that reference).
    pub references: Vec<Option<RatioStats>>,
    /// Largest horizontal distance error per flight (m).
    pub max_dist: Spread,
    /// Mean NEES per flight, for a solution with a covariance.
    pub nees_mean: Option<Spread>,
    /// Resets (the divergence monitor's, inside the flight segment) per
    /// flight, for a filter.
    pub divergences: Option<Spread>,
}

/// Summarises each solution over the flights of `manifest`, whose metrics
/// `results` holds in manifest order. Solutions come in the order they
/// first appear.
#[must_use]
pub fn summarize(manifest: &Manifest, results: &[FlightMetrics]) -> Vec<SolutionSummary> {
    let mut keys: Vec<&str> = Vec::new();
    for (k, _) in results.iter().flatten() {
        if !keys.contains(&k.as_str()) {
            keys.push(k);
        }
    }
    keys.into_iter()
        .filter_map(|key| {
            // (flight, metrics) for the flights this solution ran on.
            let runs: Vec<(&ManifestFlight, &Metrics)> = manifest
                .flights
                .iter()
                .zip(results)
                .filter_map(|(f, r)| r.iter().find(|(k, _)| k == key).map(|(_, m)| (f, m)))
                .collect();
            let pick = |g: fn(&Metrics) -> Option<f64>| -> Vec<f64> {
                runs.iter().filter_map(|(_, m)| g(m)).collect()
            };
            let references = (0..manifest.references.len())
                .map(|c| {
                    let ratios: Vec<f64> = runs
                        .iter()
                        .filter_map(|(f, m)| {
                            Some(m.rmse_horizontal / f.references.get(c).copied().flatten()?)
                        })
                        .collect();
                    ratio_stats(&ratios)
                })
                .collect();
            Some(SolutionSummary {
                key: key.to_owned(),
                flights: runs.len(),
                rmse_horizontal: spread(&pick(|m| Some(m.rmse_horizontal)))?,
                references,
                max_dist: spread(&pick(|m| Some(m.max_dist)))?,
                nees_mean: spread(&pick(|m| m.nees_mean)),
                divergences: spread(&pick(|m| m.divergences)),
            })
        })
        .collect()
}

/// The batch as one JSON object: `flights`, one entry per flight (the
/// single-flight object keyed by solution, plus `file` and the flight's
/// reference values), and `summary`, keyed by solution.
///
/// # Errors
/// The flight and solution holding a non-finite number.
pub fn to_json(
    manifest: &Manifest,
    results: &[FlightMetrics],
    summary: &[SolutionSummary],
) -> Result<serde_json::Value, String> {
    use serde_json::{json, Value};
    let mut flights = Vec::with_capacity(results.len());
    for (f, r) in manifest.flights.iter().zip(results) {
        let Value::Object(mut obj) =
            crate::run::to_json(r).map_err(|e| format!("{}: {e}", f.name))?
        else {
            return Err(format!("{}: the metrics are not a JSON object", f.name));
        };
        obj.insert(FILE_COLUMN.to_owned(), json!(f.name));
        for (col, v) in manifest.references.iter().zip(&f.references) {
            if let Some(v) = v {
                obj.insert(col.clone(), json!(v));
            }
        }
        flights.push(Value::Object(obj));
    }
    let mut sum = serde_json::Map::new();
    for s in summary {
        let mut o = serde_json::Map::new();
        o.insert("flights".to_owned(), json!(s.flights));
        o.insert("rmse_horizontal".to_owned(), json!(s.rmse_horizontal));
        for (col, r) in manifest.references.iter().zip(&s.references) {
            if let Some(r) = r {
                o.insert(col.clone(), json!(r));
            }
        }
        o.insert("max_dist".to_owned(), json!(s.max_dist));
        if let Some(n) = &s.nees_mean {
            o.insert("nees_mean".to_owned(), json!(n));
        }
        if let Some(n) = &s.divergences {
            o.insert("divergences".to_owned(), json!(n));
        }
        sum.insert(s.key.clone(), Value::Object(o));
    }
    Ok(json!({ "flights": flights, "summary": sum }))
}

/// A solution key as a column title.
#[must_use]
pub fn solution_title(key: &str) -> String {
    match key {
        "ins" => "INS-only".into(),
        "uwb" => "UWB".into(),
        k => k.to_uppercase(),
    }
}

/// One row per flight: the horizontal RMSE of each solution (m), then the
/// references. `-` where a solution did not run or a reference is missing.
#[must_use]
pub fn format_flights(
    manifest: &Manifest,
    results: &[FlightMetrics],
    summary: &[SolutionSummary],
) -> String {
    use std::fmt::Write as _;
    let name_w = manifest.name_width();
    let titles: Vec<String> = summary.iter().map(|s| solution_title(&s.key)).collect();
    let widths: Vec<usize> = titles.iter().map(|t| t.len().max(8)).collect();
    let mut s = String::new();
    let _ = write!(s, "{:<name_w$}", "flight");
    for (t, w) in titles.iter().zip(&widths) {
        let _ = write!(s, " {t:>w$}");
    }
    let _ = write!(s, " |");
    for c in &manifest.references {
        let _ = write!(s, " {c:>w$}", w = c.len().max(8));
    }
    let _ = writeln!(s, "    (horizontal RMSE, m)");
    for (f, r) in manifest.flights.iter().zip(results) {
        let _ = write!(s, "{:<name_w$}", f.name);
        for (sol, w) in summary.iter().zip(&widths) {
            match r.iter().find(|(k, _)| *k == sol.key) {
                Some((_, m)) => {
                    let _ = write!(s, " {:>w$.3}", m.rmse_horizontal);
                }
                None => {
                    let _ = write!(s, " {:>w$}", "-");
                }
            }
        }
        let _ = write!(s, " |");
        for (c, v) in manifest.references.iter().zip(&f.references) {
            let w = c.len().max(8);
            match v {
                Some(v) => {
                    let _ = write!(s, " {v:>w$.3}");
                }
                None => {
                    let _ = write!(s, " {:>w$}", "-");
                }
            }
        }
        let _ = writeln!(s);
    }
    s
}

/// One row per solution: for each reference, the median and worst ratio of
/// the horizontal RMSE to it and the flights above 1; then the median and
/// worst horizontal RMSE, maximum distance error, mean NEES and resets.
#[must_use]
pub fn format_summary(manifest: &Manifest, summary: &[SolutionSummary]) -> String {
    use std::fmt::Write as _;
    let spread = |sp: Option<Spread>, prec: usize| {
        sp.map_or("-".to_owned(), |sp| {
            format!("{:.prec$} / {:.prec$}", sp.median, sp.worst)
        })
    };
    let mut table: Vec<Vec<String>> = vec![std::iter::once("solution".to_owned())
        .chain(manifest.references.iter().cloned())
        .chain(["RMSE hor (m)", "max dist (m)", "NEES", "resets"].map(String::from))
        .collect()];
    for sol in summary {
        let mut row = vec![solution_title(&sol.key)];
        row.extend(sol.references.iter().map(|r| {
            r.map_or("-".to_owned(), |r| {
                format!(
                    "{:.2} / {:.2} / {:>2} of {}",
                    r.median, r.worst, r.above_1, r.flights
                )
            })
        }));
        row.push(spread(Some(sol.rmse_horizontal), 3));
        row.push(spread(Some(sol.max_dist), 3));
        row.push(spread(sol.nees_mean, 1));
        row.push(spread(sol.divergences, 0));
        table.push(row);
    }
    let widths: Vec<usize> = (0..table[0].len())
        .map(|c| table.iter().map(|r| r[c].len()).max().unwrap_or(0))
        .collect();
    let mut s = String::new();
    let _ = writeln!(
        s,
        "summary over {} flights: ratio of the horizontal RMSE to each reference (median / worst / flights above 1); horizontal RMSE, max distance error, mean NEES and resets in flight (median / worst)",
        manifest.flights.len()
    );
    for row in &table {
        for (c, (cell, w)) in row.iter().zip(&widths).enumerate() {
            let _ = if c == 0 {
                write!(s, "{cell:<w$}")
            } else {
                write!(s, "   {cell:>w$}")
            };
        }
        let _ = writeln!(s);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn path() -> &'static Path {
        Path::new("/data/util/flights.csv")
    }

    const GOOD: &str = "\u{feff}file,anchors,mode,takeoff_s,uwb_ls_ref_m,util_eskf_m\r\n\
        # a comment\r\n\
        cfBolt-log00, anchors-const3.txt ,tdoa2,9.2,0.150,0.098\r\n\
        \r\n\
        sub/flight-x,,tdoa3,2.1,0.105,\r\n";

    #[test]
    fn manifest_parses_columns_paths_and_references() {
        let m = Manifest::parse(GOOD, path()).unwrap();
        assert_eq!(m.references, ["uwb_ls_ref_m", "util_eskf_m"]);
        assert_eq!(m.flights.len(), 2);
        let a = &m.flights[0];
        assert_eq!(a.line, 3);
        assert_eq!(a.name, "cfBolt-log00");
        assert_eq!(a.file, Path::new("/data/util/cfBolt-log00"));
        assert_eq!(
            a.anchors.as_deref(),
            Some(Path::new("/data/util/anchors-const3.txt"))
        );
        assert_eq!(a.references, [Some(0.150), Some(0.098)]);
        let b = &m.flights[1];
        assert_eq!(b.line, 5);
        assert_eq!(b.file, Path::new("/data/util/sub/flight-x"));
        assert_eq!(b.anchors, None);
        assert_eq!(b.references, [Some(0.105), None]);
        // A manifest in the working directory: paths stay relative.
        let m = Manifest::parse("anchors,file\na.txt,log\n", Path::new("f.csv")).unwrap();
        assert_eq!(m.flights[0].file, Path::new("log"));
        assert!(m.references.is_empty());
    }

    fn err(text: &str) -> String {
        Manifest::parse(text, path()).unwrap_err().to_string()
    }

    #[test]
    fn bad_manifests_name_the_file_line_and_column() {
        let e = err("file,mode,uwb_ls_ref_m\nlog,tdoa2,0.1\n");
        assert_eq!(
            e,
            "/data/util/flights.csv:1: the header has no column `anchors`"
        );
        let e = err("# header follows\nanchors,uwb_ls_ref_m\n");
        assert_eq!(
            e,
            "/data/util/flights.csv:2: the header has no column `file`"
        );
        let e = err("file,anchors,x_m\na,b,0.1\nc,d,0.1x\n");
        assert_eq!(
            e,
            "/data/util/flights.csv:3: column `x_m`: '0.1x' is not a positive number of metres"
        );
        for bad in ["-0.1", "0", "NaN", "inf"] {
            let e = err(&format!("file,anchors,x_m\na,b,{bad}\n"));
            assert!(e.contains(":2: column `x_m`:"), "{e}");
        }
        let e = err("file,anchors,x_m\na,b\n");
        assert_eq!(e, "/data/util/flights.csv:2: 2 fields, the header has 3");
        let e = err("file,anchors\n,b\n");
        assert_eq!(e, "/data/util/flights.csv:2: column `file` is empty");
        let e = err("file,anchors,file\n");
        assert!(e.contains(":1: column `file` appears twice"), "{e}");
        assert!(err("").contains("the manifest is empty"));
        assert!(err("file,anchors\n# none\n").contains("lists no flight"));
    }

    #[test]
    fn load_names_a_missing_file_and_its_line() {
        let dir = std::env::temp_dir().join(format!("insuwb-batch-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("log-a"), b"x").unwrap();
        std::fs::write(dir.join("anchors.txt"), b"x").unwrap();
        let manifest = dir.join("flights.csv");
        std::fs::write(
            &manifest,
            "file,anchors\nlog-a,anchors.txt\nlog-a,\nlog-a,missing.txt\n",
        )
        .unwrap();
        let e = Manifest::load(&manifest).unwrap_err();
        assert!(matches!(e, ManifestError::MissingFile { line: 4, .. }));
        let msg = e.to_string();
        assert!(
            msg.starts_with(&format!(
                "{}:4: column `anchors`: no such file",
                manifest.display()
            )),
            "{msg}"
        );
        std::fs::write(&manifest, "file,anchors\nlog-a,anchors.txt\nlog-b,\n").unwrap();
        let msg = Manifest::load(&manifest).unwrap_err().to_string();
        assert!(msg.contains(":3: column `file`: no such file"), "{msg}");
        std::fs::write(&manifest, "file,anchors\nlog-a,anchors.txt\n").unwrap();
        assert_eq!(Manifest::load(&manifest).unwrap().flights.len(), 1);
        let e = Manifest::load(&dir.join("absent.csv")).unwrap_err();
        assert!(
            e.to_string()
                .contains("absent.csv: cannot read the manifest"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn median_worst_and_count_above_one() {
        assert_eq!(median(&[]), None);
        assert_eq!(median(&[f64::NAN]), None);
        assert_eq!(median(&[3.0]), Some(3.0));
        assert_eq!(median(&[4.0, 1.0, 3.0, 2.0]), Some(2.5));
        assert_eq!(median(&[5.0, f64::NAN, 1.0, 3.0]), Some(3.0));
        let s = ratio_stats(&[0.5, 1.0, 1.5, 2.5, f64::INFINITY]).unwrap();
        // 1.0 is not above 1; the infinite ratio is left out.
        assert_eq!(
            s,
            RatioStats {
                median: 1.25,
                worst: 2.5,
                above_1: 2,
                flights: 4
            }
        );
        assert_eq!(ratio_stats(&[]), None);
        assert_eq!(
            spread(&[0.2, 0.1, 0.3]),
            Some(Spread {
                median: 0.2,
                worst: 0.3
            })
        );
    }

    fn metrics(rmse: f64, nees: Option<f64>) -> Metrics {
        Metrics {
            rmse_east: rmse,
            rmse_north: rmse,
            rmse_mean: rmse,
            rmse_horizontal: rmse,
            range_east: [-rmse, rmse],
            range_north: [-rmse, rmse],
            max_dist: 2.0 * rmse,
            rmse_up: 0.0,
            nees_mean: nees,
            nis_mean: None,
            divergences: None,
            epochs: 10,
        }
    }

    #[test]
    fn summary_ratios_per_solution_and_reference() {
        let m = Manifest::parse(
            "file,anchors,ls_m,eskf_m\na,x,0.1,0.2\nb,x,0.2,\nc,x,0.4,0.1\n",
            path(),
        )
        .unwrap();
        let results: Vec<FlightMetrics> = vec![
            vec![
                ("uwb".into(), metrics(0.1, None)),
                ("kf".into(), metrics(0.05, Some(3.0))),
            ],
            vec![
                ("uwb".into(), metrics(0.3, None)),
                ("kf".into(), metrics(0.1, Some(5.0))),
            ],
            vec![("uwb".into(), metrics(0.2, None))],
        ];
        let s = summarize(&m, &results);
        assert_eq!(s.len(), 2);
        let (uwb, kf) = (&s[0], &s[1]);
        assert_eq!(uwb.key, "uwb");
        assert_eq!(uwb.flights, 3);
        // Ratios to ls_m: 1.0, 1.5, 0.5.
        let ls = uwb.references[0].unwrap();
        assert!((ls.median - 1.0).abs() < 1e-12 && (ls.worst - 1.5).abs() < 1e-12);
        assert_eq!((ls.above_1, ls.flights), (1, 3));
        // Ratios to eskf_m: 0.5 and 2.0 (flight b has none).
        let eskf = uwb.references[1].unwrap();
        assert!((eskf.median - 1.25).abs() < 1e-12 && (eskf.worst - 2.0).abs() < 1e-12);
        assert_eq!((eskf.above_1, eskf.flights), (1, 2));
        assert!((uwb.max_dist.worst - 0.6).abs() < 1e-12);
        assert_eq!(uwb.nees_mean, None);
        assert_eq!(kf.flights, 2);
        let ls = kf.references[0].unwrap();
        assert!((ls.median - 0.5).abs() < 1e-12 && ls.above_1 == 0);
        assert_eq!(kf.references[1].unwrap().flights, 1);
        assert_eq!(
            kf.nees_mean,
            Some(Spread {
                median: 4.0,
                worst: 5.0
            })
        );

        let v = to_json(&m, &results, &s).unwrap();
        assert_eq!(v["flights"][0]["file"], "a");
        assert_eq!(v["flights"][0]["ls_m"], 0.1);
        assert!(v["flights"][1].get("eskf_m").is_none());
        assert_eq!(v["flights"][2]["uwb"]["rmse_horizontal"], 0.2);
        assert!(v["flights"][2].get("kf").is_none());
        assert_eq!(v["summary"]["uwb"]["ls_m"]["above_1"], 1);
        assert_eq!(v["summary"]["kf"]["nees_mean"]["worst"], 5.0);
        assert!(v["summary"]["uwb"].get("nees_mean").is_none());

        let rows = format_flights(&m, &results, &s);
        assert_eq!(rows.lines().count(), 4, "{rows}");
        assert!(rows.lines().nth(3).unwrap().contains(" - |"), "{rows}");
        let table = format_summary(&m, &s);
        assert!(table.contains("1.00 / 1.50 /  1 of 3"), "{table}");
    }

    #[test]
    fn parallel_results_come_in_index_order_whatever_the_thread_count() {
        // Uneven run times so that items finish out of order.
        let costs: Vec<u64> = (0..17).map(|i| (i * 7) % 5).collect();
        let work = |i: usize| -> Result<(usize, f64), ()> {
            std::thread::sleep(std::time::Duration::from_millis(((i * 3) % 4) as u64));
            Ok((i, (i as f64).sqrt()))
        };
        let one = map_in_parallel(&costs, 1, work, |_, _| {}).unwrap();
        assert_eq!(one.len(), 17);
        assert!(one.iter().enumerate().all(|(i, r)| r.0 == i));
        for jobs in [2, 3, 8, 64] {
            let calls = AtomicUsize::new(0);
            let last = AtomicUsize::new(0);
            let r = map_in_parallel(&costs, jobs, work, |done, total| {
                calls.fetch_add(1, Ordering::Relaxed);
                last.fetch_max(done, Ordering::Relaxed);
                assert_eq!(total, 17);
            })
            .unwrap();
            assert_eq!(r, one, "jobs {jobs}");
            assert_eq!(calls.into_inner(), 17);
            assert_eq!(last.into_inner(), 17);
        }
        let none: Vec<u8> = map_in_parallel(&[], 4, |_| Ok::<u8, ()>(0), |_, _| {}).unwrap();
        assert!(none.is_empty());
    }

    #[test]
    fn parallel_failure_reports_the_lowest_failed_index() {
        let costs = vec![1u64; 10];
        for jobs in [1, 2, 4] {
            let e = map_in_parallel(
                &costs,
                jobs,
                |i| if i == 6 || i == 8 { Err(i) } else { Ok(i) },
                |_, _| {},
            )
            .unwrap_err();
            assert_eq!(e.index, e.error);
            assert!(e.index == 6 || e.index == 8, "jobs {jobs}: {e:?}");
        }
        // On one thread, in order: item 6 fails first and nothing after it starts.
        let started = AtomicUsize::new(0);
        let e = map_in_parallel(
            &costs,
            1,
            |i| {
                started.fetch_add(1, Ordering::Relaxed);
                if i == 6 {
                    Err("six")
                } else {
                    Ok(())
                }
            },
            |_, _| {},
        )
        .unwrap_err();
        assert_eq!(
            e,
            ItemError {
                index: 6,
                error: "six"
            }
        );
        assert_eq!(started.into_inner(), 7);
    }
}
