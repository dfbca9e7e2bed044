//! SVG figures of an evaluation, the equivalents of the paper's Figures 4-7:
//! the east/north trajectories against the truth, the signed east and north
//! errors over time and the horizontal distance error over time, one colour
//! per solution with a legend; and the summary of a batch of flights.
//!
//! Errors are "estimate minus truth", with the truth interpolated at each
//! estimate's epoch by [`TruthTrack`]; epochs the truth does not cover are
//! left out. Time is in seconds from the report's first epoch. The
//! trajectory's axes fit the truth and the anchors, so that a drifting
//! INS-only track does not set the scale: INS-only, once it leaves that box,
//! gets a figure of its own. Figures are drawn with `plotters`' SVG backend
//! (text as SVG `<text>` elements, no font library) and written whole, so a
//! figure on disk is never half drawn.

use std::path::{Path, PathBuf};

use insuwb_msg::{GroundTruth, UwbTdoa};
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::batch::{FlightMetrics, Manifest};
use crate::metrics::{Estimate, TruthTrack};
use crate::run::{EvalReport, Solution};

/// Longest truth gap bridged by interpolation (ns): 100 ms, as the evaluation runner.
pub const TRUTH_MAX_GAP_NS: u64 = 100_000_000;

/// Most points drawn per line; longer series are decimated evenly.
pub const MAX_POINTS_PER_LINE: usize = 20_000;

/// Size of the time-series figures, pixels.
const SERIES_SIZE: (u32, u32) = (1000, 600);
/// Size of the trajectory figure, pixels.
const TRAJECTORY_SIZE: (u32, u32) = (800, 800);

/// Why the figures could not be written.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// The output directory could not be created.
    #[error("cannot create the figure directory {}: {error}", dir.display())]
    CreateDir {
        /// The directory.
        dir: PathBuf,
        /// Why.
        error: std::io::Error,
    },
    /// `plotters` failed to draw a figure.
    #[error("drawing {figure} failed: {message}")]
    Draw {
        /// The figure's file name.
        figure: &'static str,
        /// The drawing error.
        message: String,
    },
    /// A drawn figure could not be written.
    #[error("cannot write the figure {}: {error}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        error: std::io::Error,
    },
}

/// Signed errors of one solution at the epochs where the truth is known.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ErrorSeries {
    /// Epoch, s from the reference time.
    pub t_s: Vec<f64>,
    /// East error (estimate minus truth), m.
    pub east_m: Vec<f64>,
    /// North error (estimate minus truth), m.
    pub north_m: Vec<f64>,
    /// Horizontal distance error `sqrt(east^2 + north^2)`, m.
    pub dist_m: Vec<f64>,
}

/// The errors of `track` against `truth`, with time in seconds from `t0_ns`
/// (negative before it). Estimates that are not finite or that the truth
/// does not cover are skipped.
#[must_use]
pub fn error_series(track: &[Estimate], truth: &TruthTrack<'_>, t0_ns: u64) -> ErrorSeries {
    let mut s = ErrorSeries::default();
    for e in track {
        if !e.pos_en_m.iter().all(|v| v.is_finite()) {
            continue;
        }
        let Some((tp, _)) = truth.at(e.t_ns) else {
            continue;
        };
        let ex = e.pos_en_m[0] - tp[0];
        let ey = e.pos_en_m[1] - tp[1];
        s.t_s.push(rel_s(e.t_ns, t0_ns));
        s.east_m.push(ex);
        s.north_m.push(ey);
        s.dist_m.push(ex.hypot(ey));
    }
    s
}

/// `t_ns - t0_ns` in seconds, signed.
fn rel_s(t_ns: u64, t0_ns: u64) -> f64 {
    (i128::from(t_ns) - i128::from(t0_ns)) as f64 * 1e-9
}

/// One line of a figure, possibly in several pieces (a line clipped to the axes).
struct Line<'a> {
    label: &'a str,
    color: RGBColor,
    pieces: Vec<Vec<(f64, f64)>>,
}

impl<'a> Line<'a> {
    fn new(label: &'a str, color: RGBColor, points: Vec<(f64, f64)>) -> Self {
        Self {
            label,
            color,
            pieces: vec![points],
        }
    }
}

/// The key of the INS-only solution, which figures leave out when it leaves the view.
pub const INS_KEY: &str = "ins";

/// The file of the INS-only trajectory, written when INS-only leaves the view.
pub const INS_TRAJECTORY_FILE: &str = "trajectory_ins.svg";

/// Margin added around the truth and the anchors: this fraction of the
/// larger side, at least [`VIEW_MIN_MARGIN_M`].
pub const VIEW_MARGIN_FRACTION: f64 = 0.1;

/// Smallest margin around the truth and the anchors, m.
pub const VIEW_MIN_MARGIN_M: f64 = 1.0;

/// An axis-aligned east/north box, m.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewBox {
    /// West and south edges.
    pub min: [f64; 2],
    /// East and north edges.
    pub max: [f64; 2],
}

impl ViewBox {
    /// The box around the finite points, grown by the margin
    /// ([`VIEW_MARGIN_FRACTION`] of its larger side, at least
    /// [`VIEW_MIN_MARGIN_M`]); `None` when there is no finite point.
    #[must_use]
    pub fn around(points: impl Iterator<Item = [f64; 2]>) -> Option<Self> {
        let mut b: Option<Self> = None;
        for p in points.filter(|p| p.iter().all(|v| v.is_finite())) {
            let v = b.get_or_insert(Self { min: p, max: p });
            v.min = [v.min[0].min(p[0]), v.min[1].min(p[1])];
            v.max = [v.max[0].max(p[0]), v.max[1].max(p[1])];
        }
        let mut b = b?;
        let side = (b.max[0] - b.min[0]).max(b.max[1] - b.min[1]);
        let margin = (VIEW_MARGIN_FRACTION * side).max(VIEW_MIN_MARGIN_M);
        b.min = b.min.map(|v| v - margin);
        b.max = b.max.map(|v| v + margin);
        Some(b)
    }

    /// Whether `p` lies inside (edges included).
    #[must_use]
    pub fn contains(&self, p: [f64; 2]) -> bool {
        (0..2).all(|k| self.min[k] <= p[k] && p[k] <= self.max[k])
    }

    /// The pieces of the polyline `points` inside the box: segments that
    /// cross an edge are cut there; non-finite points break the line.
    #[must_use]
    pub fn clip(&self, points: &[(f64, f64)]) -> Vec<Vec<(f64, f64)>> {
        let mut pieces: Vec<Vec<(f64, f64)>> = Vec::new();
        let mut cur: Vec<(f64, f64)> = Vec::new();
        let mut flush = |cur: &mut Vec<(f64, f64)>| {
            if !cur.is_empty() {
                pieces.push(std::mem::take(cur));
            }
        };
        let mut prev: Option<(f64, f64)> = None;
        for &p in points {
            if !(p.0.is_finite() && p.1.is_finite()) {
                flush(&mut cur);
                prev = None;
                continue;
            }
            match prev {
                None => {
                    if self.contains([p.0, p.1]) {
                        cur.push(p);
                    }
                }
                Some(a) => match self.clip_segment(a, p) {
                    Some((s, e)) => {
                        if cur.last() != Some(&s) {
                            flush(&mut cur);
                            cur.push(s);
                        }
                        cur.push(e);
                        if e != p {
                            flush(&mut cur);
                        }
                    }
                    None => flush(&mut cur),
                },
            }
            prev = Some(p);
        }
        flush(&mut cur);
        pieces
    }

    /// The part of the segment `a`-`b` inside the box (Liang-Barsky).
    fn clip_segment(&self, a: (f64, f64), b: (f64, f64)) -> Option<((f64, f64), (f64, f64))> {
        let d = (b.0 - a.0, b.1 - a.1);
        let (mut t0, mut t1) = (0.0f64, 1.0f64);
        for (p, q) in [
            (-d.0, a.0 - self.min[0]),
            (d.0, self.max[0] - a.0),
            (-d.1, a.1 - self.min[1]),
            (d.1, self.max[1] - a.1),
        ] {
            if p == 0.0 {
                if q < 0.0 {
                    return None;
                }
            } else {
                let r = q / p;
                if p < 0.0 {
                    t0 = t0.max(r);
                } else {
                    t1 = t1.min(r);
                }
            }
        }
        if t0 > t1 {
            return None;
        }
        let at = |t: f64| {
            if t == 0.0 {
                a
            } else if t == 1.0 {
                b
            } else {
                (a.0 + t * d.0, a.1 + t * d.1)
            }
        };
        Some((at(t0), at(t1)))
    }
}

/// The distinct anchor positions of a TDOA stream, in order of first appearance.
#[must_use]
pub fn anchor_positions(tdoa: &[UwbTdoa]) -> Vec<[f64; 3]> {
    let mut out: Vec<[f64; 3]> = Vec::new();
    for m in tdoa {
        for p in [m.anchor_a_pos_m, m.anchor_b_pos_m] {
            if p.iter().all(|v| v.is_finite()) && !out.contains(&p) {
                out.push(p);
            }
        }
    }
    out
}

/// Writes `trajectory.svg`, `error_east.svg`, `error_north.svg` and
/// `error_distance.svg` into `dir` (created if missing) and returns their
/// paths in that order.
///
/// The trajectory's axes fit the truth and the `anchors` (drawn as
/// triangles) plus a margin ([`ViewBox::around`]); lines are cut at its
/// edges. INS-only, when its track leaves that box, is left out of these
/// four figures (their titles say so) and drawn with the truth at its own
/// scale in [`INS_TRAJECTORY_FILE`], returned fifth.
///
/// # Errors
/// [`PlotError`]: the directory cannot be created, drawing fails, or a file
/// cannot be written.
pub fn write_figures(
    report: &EvalReport,
    truth: &[GroundTruth],
    anchors: &[[f64; 3]],
    dir: &Path,
) -> Result<Vec<PathBuf>, PlotError> {
    std::fs::create_dir_all(dir).map_err(|source| PlotError::CreateDir {
        dir: dir.to_path_buf(),
        error: source,
    })?;
    let track = TruthTrack::new(truth, TRUTH_MAX_GAP_NS);
    let t0_ns = report
        .epochs
        .first()
        .copied()
        .or_else(|| track.span().map(|s| s.0))
        .unwrap_or(0);
    let colors: Vec<RGBColor> = (0..report.solutions.len()).map(solution_color).collect();
    let view = ViewBox::around(
        truth
            .iter()
            .map(|g| [g.pos_m[0], g.pos_m[1]])
            .chain(anchors.iter().map(|a| [a[0], a[1]])),
    );
    // INS-only is left out when a finite point of its track leaves the view.
    let hide_ins = |key: &str, t: &[Estimate]| {
        key == INS_KEY
            && view.is_some_and(|v| {
                t.iter()
                    .any(|e| e.pos_en_m.iter().all(|x| x.is_finite()) && !v.contains(e.pos_en_m))
            })
    };
    let shown: Vec<(usize, &Solution)> = report
        .solutions
        .iter()
        .enumerate()
        .filter(|(_, s)| !hide_ins(&s.key, &s.track))
        .collect();
    let ins_hidden = shown.len() < report.solutions.len();
    let note = if ins_hidden {
        format!(" (INS-only, off this scale: {INS_TRAJECTORY_FILE})")
    } else {
        String::new()
    };
    let name = short_name(&report.dataset);
    let mut written = Vec::with_capacity(5);

    let truth_points = || {
        decimate(
            truth
                .iter()
                .map(|g| (g.pos_m[0], g.pos_m[1]))
                .filter(|(x, y)| x.is_finite() && y.is_finite())
                .collect(),
        )
    };
    let track_points = |s: &Solution| {
        decimate(
            s.track
                .iter()
                .map(|e| (e.pos_en_m[0], e.pos_en_m[1]))
                .filter(|(x, y)| x.is_finite() && y.is_finite())
                .collect(),
        )
    };
    let anchor_points: Vec<(f64, f64)> = anchors.iter().map(|a| (a[0], a[1])).collect();

    // Trajectory: truth first, then each solution shown, cut to the view.
    let mut lines = vec![Line::new("truth", BLACK, truth_points())];
    for &(i, s) in &shown {
        lines.push(Line::new(&s.key, colors[i], track_points(s)));
    }
    if let Some(v) = view {
        for l in &mut lines {
            l.pieces = l.pieces.iter().flat_map(|p| v.clip(p)).collect();
        }
    }
    let fig = Figure {
        file: "trajectory.svg",
        title: format!("{name}: trajectory{note}"),
        x_desc: "east (m)",
        y_desc: "north (m)",
        size: TRAJECTORY_SIZE,
        equal_aspect: true,
        view,
        anchors: &anchor_points,
    };
    written.push(fig.write(dir, &lines)?);

    type Pick = fn(&ErrorSeries) -> &Vec<f64>;
    let series: [(&'static str, &str, &'static str, Pick); 3] = [
        ("error_east.svg", "east error", "east error (m)", |e| {
            &e.east_m
        }),
        ("error_north.svg", "north error", "north error (m)", |e| {
            &e.north_m
        }),
        (
            "error_distance.svg",
            "horizontal distance error",
            "distance error (m)",
            |e| &e.dist_m,
        ),
    ];
    let errors: Vec<(usize, &Solution, ErrorSeries)> = shown
        .iter()
        .map(|&(i, s)| (i, s, error_series(&s.track, &track, t0_ns)))
        .collect();
    for (file, what, y_desc, pick) in series {
        let lines: Vec<Line<'_>> = errors
            .iter()
            .map(|(i, s, e)| {
                Line::new(
                    &s.key,
                    colors[*i],
                    decimate(e.t_s.iter().copied().zip(pick(e).iter().copied()).collect()),
                )
            })
            .collect();
        let fig = Figure {
            file,
            title: format!("{name}: {what}{note}"),
            x_desc: "time (s)",
            y_desc,
            size: SERIES_SIZE,
            equal_aspect: false,
            view: None,
            anchors: &[],
        };
        written.push(fig.write(dir, &lines)?);
    }

    if ins_hidden {
        let mut lines = vec![Line::new("truth", BLACK, truth_points())];
        for (i, s) in report.solutions.iter().enumerate() {
            if s.key == INS_KEY {
                lines.push(Line::new(&s.key, colors[i], track_points(s)));
            }
        }
        let fig = Figure {
            file: INS_TRAJECTORY_FILE,
            title: format!("{name}: INS-only trajectory"),
            x_desc: "east (m)",
            y_desc: "north (m)",
            size: TRAJECTORY_SIZE,
            equal_aspect: true,
            view: None,
            anchors: &anchor_points,
        };
        written.push(fig.write(dir, &lines)?);
    }
    Ok(written)
}

/// The file of the batch summary figure.
pub const SUMMARY_FILE: &str = "summary.svg";

/// Colours of the reference columns' marks in the summary figure, in column order.
const REFERENCE_COLORS: [RGBColor; 3] = [
    RGBColor(0x00, 0x00, 0x00),
    RGBColor(0x99, 0x99, 0x99),
    RGBColor(0xCC, 0xAA, 0x55),
];

/// Writes [`SUMMARY_FILE`] into `dir` (created if missing): one row per
/// flight of `manifest`, each solution's horizontal RMSE as a dot (the
/// colours of the per-flight figures) and each reference column as a
/// vertical bar across the row, on a logarithmic axis. INS-only is left out
/// (it drifts by orders of magnitude more). `results` holds the flights'
/// metrics in manifest order.
///
/// # Errors
/// [`PlotError`]: the directory cannot be created, drawing fails, or the
/// file cannot be written.
pub fn write_summary_figure(
    manifest: &Manifest,
    results: &[FlightMetrics],
    dir: &Path,
) -> Result<PathBuf, PlotError> {
    std::fs::create_dir_all(dir).map_err(|source| PlotError::CreateDir {
        dir: dir.to_path_buf(),
        error: source,
    })?;
    let title = format!(
        "{}: horizontal RMSE per flight (INS-only left out)",
        manifest.path.file_name().map_or_else(
            || manifest.path.display().to_string(),
            |n| n.to_string_lossy().into_owned()
        )
    );
    let svg = draw_summary(manifest, results, &title).map_err(|message| PlotError::Draw {
        figure: SUMMARY_FILE,
        message,
    })?;
    write_svg(dir, SUMMARY_FILE, svg, &title)
}

/// References above this multiple of the largest solution value are not
/// scaled in the summary figure but written as numbers at its right edge.
pub const SUMMARY_REFERENCE_REACH: f64 = 3.0;

/// Pixel height of one flight's row in the summary figure.
const SUMMARY_ROW_PX: u32 = 30;

fn draw_summary(
    manifest: &Manifest,
    results: &[FlightMetrics],
    title: &str,
) -> Result<String, String> {
    // Solutions in order of first appearance; colour by that order (INS
    // included) so that they match the per-flight figures.
    let mut keys: Vec<&str> = Vec::new();
    for (k, _) in results.iter().flatten() {
        if !keys.contains(&k.as_str()) {
            keys.push(k);
        }
    }
    let solutions: Vec<(usize, &str)> = keys
        .iter()
        .copied()
        .enumerate()
        .filter(|(_, k)| *k != INS_KEY)
        .collect();
    let rows = manifest.flights.len().min(results.len());
    let positive = |v: &f64| v.is_finite() && *v > 0.0;
    let values: Vec<f64> = results
        .iter()
        .take(rows)
        .flat_map(|r| {
            r.iter()
                .filter(|(k, _)| k != INS_KEY)
                .map(|(_, m)| m.rmse_horizontal)
        })
        .filter(positive)
        .collect();
    let refs: Vec<f64> = manifest
        .flights
        .iter()
        .take(rows)
        .flat_map(|f| f.references.iter().flatten().copied())
        .filter(positive)
        .collect();
    // The axis covers the solutions and the references up to
    // SUMMARY_REFERENCE_REACH times the largest solution value; a reference
    // beyond it (a diverged reference filter) is written as a number at the
    // right edge.
    let top = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let reach = if top.is_finite() {
        SUMMARY_REFERENCE_REACH * top
    } else {
        f64::INFINITY
    };
    let (lo, hi) = values
        .iter()
        .chain(refs.iter().filter(|r| **r <= reach))
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(*v), b.max(*v))
        });
    let (lo, hi) = if lo <= hi {
        (lo / 1.3, hi * 1.3)
    } else {
        (0.01, 1.0)
    };
    let name_w = manifest
        .flights
        .iter()
        .map(|f| f.name.chars().count())
        .max()
        .unwrap_or(0);
    let label_px = 20 + 8 * u32::try_from(name_w).unwrap_or(40).min(40);
    let height = 140 + SUMMARY_ROW_PX * u32::try_from(rows).unwrap_or(200).min(200);
    // Row i (manifest order) at y = rows - 1 - i: the first flight on top.
    let y_of = |i: usize| (rows - 1 - i) as f64;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (1100, height)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", caption_px(title, 1100)))
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(label_px)
            .build_cartesian_2d((lo..hi).log_scale(), -0.5..(rows as f64 - 0.5))
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .disable_y_mesh()
            .light_line_style(TRANSPARENT)
            .y_labels(0)
            .x_labels(10)
            .x_desc("horizontal RMSE (m, logarithmic)")
            .x_label_formatter(&|v| format_metres(*v))
            .label_style(("sans-serif", 14))
            .axis_desc_style(("sans-serif", 16))
            .draw()
            .map_err(|e| e.to_string())?;
        // Row separators and flight names.
        let grey = RGBColor(0xDD, 0xDD, 0xDD);
        chart
            .draw_series((1..rows).map(|i| {
                let y = i as f64 - 0.5;
                PathElement::new(vec![(lo, y), (hi, y)], grey.stroke_width(1))
            }))
            .map_err(|e| e.to_string())?;
        let name_style = TextStyle::from(("sans-serif", 14).into_font())
            .pos(Pos::new(HPos::Right, VPos::Center));
        for (i, f) in manifest.flights.iter().take(rows).enumerate() {
            let (px, py) = chart.backend_coord(&(lo, y_of(i)));
            root.draw(&Text::new(f.name.clone(), (px - 8, py), &name_style))
                .map_err(|e| e.to_string())?;
        }
        // References: a bar across each row.
        for (c, col) in manifest.references.iter().enumerate() {
            let color = REFERENCE_COLORS
                .get(c)
                .copied()
                .unwrap_or(REFERENCE_COLORS[REFERENCE_COLORS.len() - 1]);
            let mut bars: Vec<PathElement<(f64, f64)>> = Vec::new();
            let mut beyond: Vec<(f64, f64)> = Vec::new();
            for (i, f) in manifest.flights.iter().take(rows).enumerate() {
                let Some(v) = f.references.get(c).copied().flatten() else {
                    continue;
                };
                let y = y_of(i);
                if v <= hi {
                    bars.push(PathElement::new(
                        vec![(v, y - 0.42), (v, y + 0.42)],
                        color.stroke_width(3),
                    ));
                } else {
                    beyond.push((v, y));
                }
            }
            chart
                .draw_series(bars)
                .map_err(|e| e.to_string())?
                .label(col.as_str())
                .legend(move |(x, y)| {
                    PathElement::new(
                        vec![(x + 10, y - 7), (x + 10, y + 7)],
                        color.stroke_width(3),
                    )
                });
            let beyond_style = TextStyle::from(("sans-serif", 13).into_font())
                .color(&color)
                .pos(Pos::new(HPos::Right, VPos::Center));
            for (v, y) in beyond {
                let (px, py) = chart.backend_coord(&(hi, y));
                root.draw(&Text::new(
                    format!("{col} {} \u{2192}", format_metres(v)),
                    (px - 4, py),
                    &beyond_style,
                ))
                .map_err(|e| e.to_string())?;
            }
        }
        // Solutions: a dot each, spread over the row's height.
        let n = solutions.len().max(1);
        for (k, &(ci, key)) in solutions.iter().enumerate() {
            let color = solution_color(ci);
            let dy = if n > 1 {
                0.3 - 0.6 * k as f64 / (n - 1) as f64
            } else {
                0.0
            };
            let dots: Vec<Circle<(f64, f64), i32>> = results
                .iter()
                .take(rows)
                .enumerate()
                .filter_map(|(i, r)| {
                    let (_, m) = r.iter().find(|(k, _)| k == key)?;
                    let v = m.rmse_horizontal;
                    (v.is_finite() && v > 0.0)
                        .then(|| Circle::new((v, y_of(i) + dy), 4, color.filled()))
                })
                .collect();
            chart
                .draw_series(dots)
                .map_err(|e| e.to_string())?
                .label(key)
                .legend(move |(x, y)| Circle::new((x + 10, y), 4, color.filled()));
        }
        draw_legend(&mut chart)?;
        root.present().map_err(|e| e.to_string())?;
    }
    Ok(svg)
}

/// The legend box, upper right.
fn draw_legend<'a, DB, CT>(chart: &mut ChartContext<'a, DB, CT>) -> Result<(), String>
where
    DB: DrawingBackend + 'a,
    CT: plotters::coord::CoordTranslate,
{
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .draw()
        .map_err(|e| e.to_string())
}

/// An axis value in metres with at most three significant digits.
fn format_metres(v: f64) -> String {
    if v >= 100.0 {
        format!("{v:.0}")
    } else if v >= 1.0 {
        format!("{}", (v * 10.0).round() / 10.0)
    } else {
        let digits = (-v.log10()).ceil().max(1.0) as usize + 1;
        let s = format!("{v:.digits$}");
        s.trim_end_matches('0').trim_end_matches('.').to_owned()
    }
}

/// Colours of the first ten solutions (the "Tableau 10" palette, readable on white).
const COLORS: [RGBColor; 10] = [
    RGBColor(0x1F, 0x77, 0xB4),
    RGBColor(0xFF, 0x7F, 0x0E),
    RGBColor(0x2C, 0xA0, 0x2C),
    RGBColor(0xD6, 0x27, 0x28),
    RGBColor(0x94, 0x67, 0xBD),
    RGBColor(0x8C, 0x56, 0x4B),
    RGBColor(0xE3, 0x77, 0xC2),
    RGBColor(0x7F, 0x7F, 0x7F),
    RGBColor(0xBC, 0xBD, 0x22),
    RGBColor(0x17, 0xBE, 0xCF),
];

/// The colour of solution `i` (black is the truth's; past ten, a 99-colour palette).
fn solution_color(i: usize) -> RGBColor {
    COLORS.get(i).copied().unwrap_or_else(|| {
        let (r, g, b) = Palette99::pick(i).rgb();
        RGBColor(r, g, b)
    })
}

/// Keeps at most [`MAX_POINTS_PER_LINE`] evenly spaced points (the last one included).
fn decimate(points: Vec<(f64, f64)>) -> Vec<(f64, f64)> {
    let n = points.len();
    if n <= MAX_POINTS_PER_LINE {
        return points;
    }
    let stride = n.div_ceil(MAX_POINTS_PER_LINE - 1);
    let last = points.last().copied();
    let mut out: Vec<(f64, f64)> = points.into_iter().step_by(stride).collect();
    if let Some(p) = last {
        if out.last() != Some(&p) {
            out.push(p);
        }
    }
    out
}

/// `[min, max]` of the finite values, padded by 5 % (centre +- 1 when they
/// are equal up to 1e-9 relative; `[-1, 1]` when there is none).
fn padded_range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
    if lo > hi {
        return (-1.0, 1.0);
    }
    if hi - lo <= 1e-9 * lo.abs().max(hi.abs()).max(1.0) {
        // Constant up to rounding: do not blow the rounding noise up to full scale.
        let c = 0.5 * (lo + hi);
        return (c - 1.0, c + 1.0);
    }
    let pad = 0.05 * (hi - lo);
    (lo - pad, hi + pad)
}

/// Widens the narrower of two ranges about its centre so both span the same length.
fn equalise(x: (f64, f64), y: (f64, f64)) -> ((f64, f64), (f64, f64)) {
    let span = (x.1 - x.0).max(y.1 - y.0);
    let widen = |r: (f64, f64)| {
        let c = 0.5 * (r.0 + r.1);
        (c - 0.5 * span, c + 0.5 * span)
    };
    (widen(x), widen(y))
}

/// What one figure shows.
struct Figure<'a> {
    file: &'static str,
    title: String,
    x_desc: &'a str,
    y_desc: &'a str,
    size: (u32, u32),
    equal_aspect: bool,
    /// Axes fitted to this box instead of the data.
    view: Option<ViewBox>,
    /// Anchor positions, drawn as triangles.
    anchors: &'a [(f64, f64)],
}

/// Colour of the anchor markers.
const ANCHOR_COLOR: RGBColor = RGBColor(0x55, 0x55, 0x55);

impl Figure<'_> {
    /// Draws `lines` and writes the file into `dir`.
    fn write(&self, dir: &Path, lines: &[Line<'_>]) -> Result<PathBuf, PlotError> {
        let svg = self.draw(lines).map_err(|message| PlotError::Draw {
            figure: self.file,
            message,
        })?;
        write_svg(dir, self.file, svg, &self.title)
    }

    fn draw(&self, lines: &[Line<'_>]) -> Result<String, String> {
        let all = || {
            lines
                .iter()
                .flat_map(|l| l.pieces.iter().flatten())
                .chain(self.anchors.iter())
        };
        let (mut xr, mut yr) = match self.view {
            Some(v) => ((v.min[0], v.max[0]), (v.min[1], v.max[1])),
            None => (
                padded_range(all().map(|p| p.0)),
                padded_range(all().map(|p| p.1)),
            ),
        };
        if self.equal_aspect {
            (xr, yr) = equalise(xr, yr);
        }
        let mut svg = String::new();
        {
            let root = SVGBackend::with_string(&mut svg, self.size).into_drawing_area();
            root.fill(&WHITE).map_err(|e| e.to_string())?;
            let mut chart = ChartBuilder::on(&root)
                .caption(
                    &self.title,
                    ("sans-serif", caption_px(&self.title, self.size.0)),
                )
                .margin(12)
                .x_label_area_size(45)
                .y_label_area_size(65)
                .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)
                .map_err(|e| e.to_string())?;
            chart
                .configure_mesh()
                .x_desc(self.x_desc)
                .y_desc(self.y_desc)
                .label_style(("sans-serif", 14))
                .axis_desc_style(("sans-serif", 16))
                .draw()
                .map_err(|e| e.to_string())?;
            if !self.anchors.is_empty() {
                chart
                    .draw_series(
                        self.anchors
                            .iter()
                            .map(|&p| TriangleMarker::new(p, 7, ANCHOR_COLOR.filled())),
                    )
                    .map_err(|e| e.to_string())?
                    .label("anchors")
                    .legend(|(x, y)| TriangleMarker::new((x + 10, y), 6, ANCHOR_COLOR.filled()));
            }
            for line in lines {
                let color = line.color;
                // A line cut away entirely still gets its legend entry.
                let empty = [Vec::new()];
                let pieces = if line.pieces.is_empty() {
                    &empty[..]
                } else {
                    &line.pieces[..]
                };
                for (k, piece) in pieces.iter().enumerate() {
                    let drawn = chart
                        .draw_series(LineSeries::new(
                            piece.iter().copied(),
                            color.stroke_width(2),
                        ))
                        .map_err(|e| e.to_string())?;
                    if k == 0 {
                        drawn.label(line.label).legend(move |(x, y)| {
                            PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                        });
                    }
                }
            }
            draw_legend(&mut chart)?;
            root.present().map_err(|e| e.to_string())?;
        }
        Ok(svg)
    }
}

/// The last component of a dataset name that is a path (`../data/log` is
/// shown as `log`).
fn short_name(name: &str) -> &str {
    name.rsplit(['/', '\\'])
        .next()
        .filter(|s| !s.is_empty())
        .unwrap_or(name)
}

/// A caption's font size, px: 22, smaller (down to 12) for a title that
/// would not fit `width_px` (sans-serif glyphs average about 0.55 em).
fn caption_px(title: &str, width_px: u32) -> u32 {
    let chars = title.chars().count().max(1) as f64;
    let fit = (f64::from(width_px) - 30.0) / (0.55 * chars);
    fit.clamp(12.0, 22.0) as u32
}

/// Adds the `<title>` and writes `svg` as `dir/file`.
fn write_svg(dir: &Path, file: &str, mut svg: String, title: &str) -> Result<PathBuf, PlotError> {
    insert_title(&mut svg, title);
    let path = dir.join(file);
    std::fs::write(&path, svg).map_err(|source| PlotError::Write {
        path: path.clone(),
        error: source,
    })?;
    Ok(path)
}

/// Puts an SVG `<title>` (escaped) right after the opening `<svg ...>` tag.
fn insert_title(svg: &mut String, title: &str) {
    let Some(start) = svg.find("<svg") else {
        return;
    };
    let Some(end) = svg.get(start..).and_then(|s| s.find('>')) else {
        return;
    };
    let mut t = String::with_capacity(title.len() + 16);
    t.push_str("\n<title>");
    for c in title.chars() {
        match c {
            '<' => t.push_str("&lt;"),
            '>' => t.push_str("&gt;"),
            '&' => t.push_str("&amp;"),
            _ => t.push(c),
        }
    }
    t.push_str("</title>");
    svg.insert_str(start + end + 1, &t);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::Metrics;
    use crate::run::Solution;
    use insuwb_msg::Header;

    fn truth() -> Vec<GroundTruth> {
        // Moving east at 1 m/s and north at 0.5 m/s, 100 Hz for 2 s, from t = 1 s.
        (0..=200u64)
            .map(|i| {
                let t = i as f64 * 0.01;
                GroundTruth {
                    header: Header::new(i, 1_000_000_000 + i * 10_000_000),
                    pos_m: [t, 0.5 * t, 0.0],
                    vel_mps: [1.0, 0.5, 0.0],
                    ..GroundTruth::default()
                }
            })
            .collect()
    }

    fn metrics() -> Metrics {
        Metrics {
            rmse_east: 0.0,
            rmse_north: 0.0,
            rmse_mean: 0.0,
            rmse_horizontal: 0.0,
            range_east: [0.0; 2],
            range_north: [0.0; 2],
            max_dist: 0.0,
            rmse_up: 0.0,
            nees_mean: None,
            nis_mean: None,
            divergences: None,
            epochs: 0,
        }
    }

    /// Solutions offset from the truth by a constant (east, north) error, 10 Hz.
    fn report(offsets: &[(&str, f64, f64)]) -> EvalReport {
        let epochs: Vec<u64> = (0..20u64)
            .map(|k| 1_000_000_000 + k * 100_000_000)
            .collect();
        let solutions = offsets
            .iter()
            .map(|&(key, de, dn)| Solution {
                key: key.to_owned(),
                metrics: metrics(),
                track: epochs
                    .iter()
                    .map(|&t_ns| {
                        let t = (t_ns - 1_000_000_000) as f64 * 1e-9;
                        Estimate {
                            t_ns,
                            pos_en_m: [t + de, 0.5 * t + dn],
                            up_m: 0.0,
                            vel_en_mps: None,
                            cov4: None,
                            yaw_rad: None,
                        }
                    })
                    .collect(),
                run: None,
            })
            .collect();
        EvalReport {
            dataset: "synthetic <A&B>".to_owned(),
            solutions,
            epochs,
        }
    }

    fn temp_dir(tag: &str) -> PathBuf {
        std::env::temp_dir().join(format!("insuwb-eval-plot-{tag}-{}", std::process::id()))
    }

    #[test]
    fn error_series_hand_computed() {
        let t = truth();
        let tt = TruthTrack::new(&t, TRUTH_MAX_GAP_NS);
        let est = [
            // Between truth samples: truth (0.155, 0.0775) at 1.155 s.
            Estimate {
                t_ns: 1_155_000_000,
                pos_en_m: [0.155 + 0.3, 0.0775 - 0.4],
                up_m: 0.0,
                vel_en_mps: None,
                cov4: None,
                yaw_rad: None,
            },
            // Outside the truth's span: skipped.
            Estimate {
                t_ns: 5_000_000_000,
                pos_en_m: [0.0, 0.0],
                up_m: 0.0,
                vel_en_mps: None,
                cov4: None,
                yaw_rad: None,
            },
            // Not finite: skipped.
            Estimate {
                t_ns: 1_500_000_000,
                pos_en_m: [f64::NAN, 0.0],
                up_m: 0.0,
                vel_en_mps: None,
                cov4: None,
                yaw_rad: None,
            },
            Estimate {
                t_ns: 2_000_000_000,
                pos_en_m: [1.0 - 0.6, 0.5 + 0.8],
                up_m: 0.0,
                vel_en_mps: None,
                cov4: None,
                yaw_rad: None,
            },
        ];
        let s = error_series(&est, &tt, 1_100_000_000);
        assert_eq!(s.t_s.len(), 2);
        assert!((s.t_s[0] - 0.055).abs() < 1e-12 && (s.t_s[1] - 0.9).abs() < 1e-12);
        assert!((s.east_m[0] - 0.3).abs() < 1e-12 && (s.north_m[0] + 0.4).abs() < 1e-12);
        assert!((s.dist_m[0] - 0.5).abs() < 1e-12);
        assert!((s.east_m[1] + 0.6).abs() < 1e-12 && (s.north_m[1] - 0.8).abs() < 1e-12);
        assert!((s.dist_m[1] - 1.0).abs() < 1e-12);
        // Before the reference time: negative seconds.
        let s = error_series(&est[..1], &tt, 2_000_000_000);
        assert!((s.t_s[0] + 0.845).abs() < 1e-12);
    }

    #[test]
    fn writes_four_svg_figures_with_one_line_per_solution() {
        let dir = temp_dir("figs");
        let _ = std::fs::remove_dir_all(&dir);
        let rep = report(&[("uwb", 0.1, -0.2), ("ins", 0.5, 0.4), ("kf", 0.05, 0.02)]);
        let files = write_figures(&rep, &truth(), &[], &dir).unwrap();
        let names: Vec<String> = files
            .iter()
            .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        assert_eq!(
            names,
            [
                "trajectory.svg",
                "error_east.svg",
                "error_north.svg",
                "error_distance.svg"
            ]
        );
        let colors: Vec<String> = (0..3)
            .map(|i| {
                let RGBColor(r, g, b) = solution_color(i);
                format!("stroke=\"#{r:02X}{g:02X}{b:02X}\"")
            })
            .collect();
        assert!(colors[0] != colors[1] && colors[1] != colors[2] && colors[0] != colors[2]);
        for (path, name) in files.iter().zip(&names) {
            assert!(path.starts_with(&dir));
            let text = std::fs::read_to_string(path).unwrap();
            assert!(
                text.starts_with("<svg") || text.starts_with("<?xml"),
                "{name}"
            );
            assert!(text.trim_end().ends_with("</svg>"), "{name}");
            assert!(text.contains("<title>synthetic &lt;A&amp;B&gt;:"), "{name}");
            let polylines: Vec<&str> = text.split("<polyline").skip(1).collect();
            for (key, color) in ["uwb", "ins", "kf"].iter().zip(&colors) {
                // The data line and the legend sample.
                let n = polylines
                    .iter()
                    .filter(|p| p.contains(color.as_str()))
                    .count();
                assert_eq!(n, 2, "{name}: {key} {color}");
                assert!(
                    text.contains(&format!(">\n{key}\n</text>")),
                    "{name}: legend {key}"
                );
            }
            // The data line holds one vertex per epoch (20), the legend 2.
            let longest = polylines
                .iter()
                .filter(|p| p.contains(colors[2].as_str()))
                .map(|p| {
                    let pts = p
                        .split("points=\"")
                        .nth(1)
                        .unwrap()
                        .split('"')
                        .next()
                        .unwrap();
                    pts.split_whitespace().count()
                })
                .max()
                .unwrap();
            assert_eq!(longest, 20, "{name}");
            if name == "trajectory.svg" {
                assert!(text.contains(">\ntruth\n</text>"));
                assert!(polylines.iter().any(|p| p.contains("stroke=\"#000000\"")));
            }
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Pixel y of each vertex of the longest polyline drawn in `color`.
    fn line_ys(text: &str, color: RGBColor) -> Vec<i64> {
        let RGBColor(r, g, b) = color;
        let stroke = format!("stroke=\"#{r:02X}{g:02X}{b:02X}\"");
        let pts = text
            .split("<polyline")
            .filter(|p| p.contains(stroke.as_str()))
            .map(|p| {
                p.split("points=\"")
                    .nth(1)
                    .unwrap()
                    .split('"')
                    .next()
                    .unwrap()
                    .to_owned()
            })
            .max_by_key(|p| p.len())
            .unwrap();
        pts.split_whitespace()
            .map(|xy| xy.split(',').nth(1).unwrap().parse().unwrap())
            .collect()
    }

    #[test]
    fn constant_errors_are_flat_lines_at_their_values() {
        // East errors +0.5, 0 and -1 m: three horizontal lines whose pixel
        // heights are affine in the error: (y(0) - y(0.5)) / (y(-1) - y(0.5)) = 1/3.
        // North errors all 0.25 (up to rounding): a flat line, not rounding noise.
        let dir = temp_dir("flat");
        let _ = std::fs::remove_dir_all(&dir);
        let rep = report(&[("a", 0.5, 0.25), ("b", 0.0, 0.25), ("c", -1.0, 0.25)]);
        let files = write_figures(&rep, &truth(), &[], &dir).unwrap();
        let east = std::fs::read_to_string(&files[1]).unwrap();
        let mut level = Vec::new();
        for i in 0..3 {
            let ys = line_ys(&east, solution_color(i));
            assert_eq!(ys.len(), 20);
            assert!(ys.iter().all(|y| *y == ys[0]), "{i}: {ys:?}");
            level.push(ys[0] as f64);
        }
        // SVG y grows downwards.
        assert!(level[0] < level[1] && level[1] < level[2], "{level:?}");
        let ratio = (level[1] - level[0]) / (level[2] - level[0]);
        assert!((ratio - 1.0 / 3.0).abs() < 0.01, "{ratio}");
        let north = std::fs::read_to_string(&files[2]).unwrap();
        let ys = line_ys(&north, solution_color(1));
        assert!(ys.iter().all(|y| *y == ys[0]), "{ys:?}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn directory_that_cannot_be_created_is_named() {
        let file = temp_dir("blocker");
        std::fs::write(&file, b"not a directory").unwrap();
        let dir = file.join("figs");
        let e = write_figures(&report(&[("kf", 0.0, 0.0)]), &truth(), &[], &dir).unwrap_err();
        assert!(matches!(e, PlotError::CreateDir { .. }));
        assert!(e.to_string().contains(&dir.display().to_string()), "{e}");
        std::fs::remove_file(&file).unwrap();
    }

    #[test]
    fn decimation_bounds_the_points() {
        let pts: Vec<(f64, f64)> = (0..50_001).map(|i| (f64::from(i), 0.0)).collect();
        let d = decimate(pts);
        assert!(d.len() <= MAX_POINTS_PER_LINE);
        assert_eq!(d.first(), Some(&(0.0, 0.0)));
        assert_eq!(d.last(), Some(&(50_000.0, 0.0)));
        assert_eq!(padded_range([2.0, 2.0].into_iter()), (1.0, 3.0));
        assert_eq!(padded_range([f64::NAN].into_iter()), (-1.0, 1.0));
        let (lo, hi) = padded_range([0.0, 10.0].into_iter());
        assert!((lo + 0.5).abs() < 1e-12 && (hi - 10.5).abs() < 1e-12);
        let (x, y) = equalise((0.0, 4.0), (10.0, 11.0));
        assert_eq!(x, (0.0, 4.0));
        assert_eq!(y, (8.5, 12.5));
    }

    #[test]
    fn view_box_grows_by_its_margin_and_clips_lines_at_its_edges() {
        let v = ViewBox::around([[0.0, 0.0], [20.0, 5.0], [f64::NAN, 1.0]].into_iter()).unwrap();
        // Margin: 10 % of the larger side (20 m), at least 1 m.
        assert_eq!(
            v,
            ViewBox {
                min: [-2.0, -2.0],
                max: [22.0, 7.0]
            }
        );
        let small = ViewBox::around([[1.0, 1.0]].into_iter()).unwrap();
        assert_eq!(
            small,
            ViewBox {
                min: [0.0, 0.0],
                max: [2.0, 2.0]
            }
        );
        assert!(ViewBox::around(std::iter::empty()).is_none());
        let b = ViewBox {
            min: [0.0, 0.0],
            max: [10.0, 10.0],
        };
        // In, out across the east edge, back in across it, a NaN break, then
        // a segment that crosses the whole box.
        let pts = [
            (1.0, 1.0),
            (5.0, 5.0),
            (15.0, 5.0),
            (20.0, 5.0),
            (5.0, 8.0),
            (f64::NAN, 0.0),
            (-5.0, 5.0),
            (15.0, 5.0),
        ];
        let pieces = b.clip(&pts);
        assert_eq!(
            pieces,
            vec![
                vec![(1.0, 1.0), (5.0, 5.0), (10.0, 5.0)],
                vec![(10.0, 7.0), (5.0, 8.0)],
                vec![(0.0, 5.0), (10.0, 5.0)],
            ]
        );
        assert!(b.clip(&[(20.0, 20.0), (30.0, 30.0)]).is_empty());
    }

    #[test]
    fn ins_only_leaving_the_anchors_box_gets_its_own_figure() {
        let dir = temp_dir("ins");
        let _ = std::fs::remove_dir_all(&dir);
        // INS-only 300 m off; anchors around the truth.
        let rep = report(&[("uwb", 0.1, 0.0), ("ins", 300.0, 0.0), ("kf", 0.0, 0.1)]);
        let anchors = [[-4.0, -4.0, 0.2], [6.0, -4.0, 3.0], [6.0, 5.0, 0.2]];
        let files = write_figures(&rep, &truth(), &anchors, &dir).unwrap();
        assert_eq!(files.len(), 5);
        assert!(files[4].ends_with(INS_TRAJECTORY_FILE));
        let ins = solution_color(1);
        let RGBColor(r, g, b) = ins;
        let stroke = format!("stroke=\"#{r:02X}{g:02X}{b:02X}\"");
        for f in &files[..4] {
            let text = std::fs::read_to_string(f).unwrap();
            assert!(!text.contains(&stroke), "{}", f.display());
            assert!(!text.contains(">\nins\n</text>"), "{}", f.display());
            assert!(text.contains(INS_TRAJECTORY_FILE), "{}", f.display());
        }
        let traj = std::fs::read_to_string(&files[0]).unwrap();
        assert!(traj.contains(">\nanchors\n</text>"));
        let own = std::fs::read_to_string(&files[4]).unwrap();
        assert!(own.contains(&stroke) && own.contains(">\ntruth\n</text>"));
        // Inside the box, INS-only stays in the figures.
        let rep = report(&[("ins", 0.5, 0.0)]);
        let files = write_figures(&rep, &truth(), &anchors, &dir).unwrap();
        assert_eq!(files.len(), 4);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn summary_figure_has_a_row_per_flight_and_numbers_for_far_references() {
        use crate::batch::{FlightMetrics, Manifest};
        let dir = temp_dir("summary");
        let _ = std::fs::remove_dir_all(&dir);
        let m = Manifest::parse(
            "file,anchors,ls_m,eskf_m\nlog-a,x,0.15,0.1\nlog-b,x,0.1,487\n",
            Path::new("/d/flights.csv"),
        )
        .unwrap();
        let with = |rmse: f64| Metrics {
            rmse_horizontal: rmse,
            ..metrics()
        };
        let results: Vec<FlightMetrics> = vec![
            vec![
                ("uwb".into(), with(0.2)),
                ("ins".into(), with(900.0)),
                ("kf".into(), with(0.1)),
            ],
            vec![
                ("uwb".into(), with(0.3)),
                ("ins".into(), with(50.0)),
                ("kf".into(), with(0.12)),
            ],
        ];
        let f = write_summary_figure(&m, &results, &dir).unwrap();
        assert!(f.ends_with(SUMMARY_FILE));
        let text = std::fs::read_to_string(&f).unwrap();
        assert!(text.contains("<title>flights.csv: horizontal RMSE per flight"));
        for label in ["log-a", "log-b", "ls_m", "eskf_m", "uwb", "kf"] {
            assert!(text.contains(&format!(">\n{label}\n</text>")), "{label}");
        }
        assert!(!text.contains(">\nins\n</text>"));
        // 487 m is far beyond the solutions (at most 0.3 m): written, not scaled.
        assert!(text.contains("eskf_m 487 \u{2192}"), "far reference");
        // One dot per solution and flight, plus the two legend dots.
        assert_eq!(text.matches("<circle").count(), 6);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
