//! SVG figures of an evaluation, the equivalents of the paper's Figures 4-7:
//! the east/north trajectories against the truth, the signed east and north
//! errors over time and the horizontal distance error over time, one colour
//! per solution with a legend.
//!
//! Errors are "estimate minus truth", with the truth interpolated at each
//! estimate's epoch by [`TruthTrack`]; epochs the truth does not cover are
//! left out. Time is in seconds from the report's first epoch. Figures are
//! drawn with `plotters`' SVG backend (text as SVG `<text>` elements, no
//! font library) and written whole, so a figure on disk is never half drawn.

use std::path::{Path, PathBuf};

use insuwb_msg::GroundTruth;
use plotters::prelude::*;

use crate::metrics::{Estimate, TruthTrack};
use crate::run::EvalReport;

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
    #[error("cannot create the figure directory {}: {source}", dir.display())]
    CreateDir {
        /// The directory.
        dir: PathBuf,
        /// Why.
        source: std::io::Error,
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
    #[error("cannot write the figure {}: {source}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
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

/// One line of a figure.
struct Line<'a> {
    label: &'a str,
    color: RGBColor,
    points: Vec<(f64, f64)>,
}

/// Writes `trajectory.svg`, `error_east.svg`, `error_north.svg` and
/// `error_distance.svg` into `dir` (created if missing) and returns their
/// paths in that order.
///
/// # Errors
/// [`PlotError`]: the directory cannot be created, drawing fails, or a file
/// cannot be written.
pub fn write_figures(
    report: &EvalReport,
    truth: &[GroundTruth],
    dir: &Path,
) -> Result<Vec<PathBuf>, PlotError> {
    std::fs::create_dir_all(dir).map_err(|source| PlotError::CreateDir {
        dir: dir.to_path_buf(),
        source,
    })?;
    let track = TruthTrack::new(truth, TRUTH_MAX_GAP_NS);
    let t0_ns = report
        .epochs
        .first()
        .copied()
        .or_else(|| track.span().map(|s| s.0))
        .unwrap_or(0);
    let colors: Vec<RGBColor> = (0..report.solutions.len()).map(solution_color).collect();
    let errors: Vec<ErrorSeries> = report
        .solutions
        .iter()
        .map(|s| error_series(&s.track, &track, t0_ns))
        .collect();
    let name = &report.dataset;
    let mut written = Vec::with_capacity(4);

    // Trajectory: truth first, then each solution.
    let mut lines = vec![Line {
        label: "truth",
        color: BLACK,
        points: decimate(
            truth
                .iter()
                .map(|g| (g.pos_m[0], g.pos_m[1]))
                .filter(|(x, y)| x.is_finite() && y.is_finite())
                .collect(),
        ),
    }];
    for (s, c) in report.solutions.iter().zip(&colors) {
        lines.push(Line {
            label: &s.key,
            color: *c,
            points: decimate(
                s.track
                    .iter()
                    .map(|e| (e.pos_en_m[0], e.pos_en_m[1]))
                    .filter(|(x, y)| x.is_finite() && y.is_finite())
                    .collect(),
            ),
        });
    }
    let fig = Figure {
        file: "trajectory.svg",
        title: format!("{name}: trajectory"),
        x_desc: "east (m)",
        y_desc: "north (m)",
        size: TRAJECTORY_SIZE,
        equal_aspect: true,
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
    for (file, what, y_desc, pick) in series {
        let lines: Vec<Line<'_>> = report
            .solutions
            .iter()
            .zip(&colors)
            .zip(&errors)
            .map(|((s, c), e)| Line {
                label: &s.key,
                color: *c,
                points: decimate(e.t_s.iter().copied().zip(pick(e).iter().copied()).collect()),
            })
            .collect();
        let fig = Figure {
            file,
            title: format!("{name}: {what}"),
            x_desc: "time (s)",
            y_desc,
            size: SERIES_SIZE,
            equal_aspect: false,
        };
        written.push(fig.write(dir, &lines)?);
    }
    Ok(written)
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
}

impl Figure<'_> {
    /// Draws `lines` and writes the file into `dir`.
    fn write(&self, dir: &Path, lines: &[Line<'_>]) -> Result<PathBuf, PlotError> {
        let mut svg = self.draw(lines).map_err(|message| PlotError::Draw {
            figure: self.file,
            message,
        })?;
        insert_title(&mut svg, &self.title);
        let path = dir.join(self.file);
        std::fs::write(&path, svg).map_err(|source| PlotError::Write {
            path: path.clone(),
            source,
        })?;
        Ok(path)
    }

    fn draw(&self, lines: &[Line<'_>]) -> Result<String, String> {
        let all = || lines.iter().flat_map(|l| l.points.iter());
        let mut xr = padded_range(all().map(|p| p.0));
        let mut yr = padded_range(all().map(|p| p.1));
        if self.equal_aspect {
            (xr, yr) = equalise(xr, yr);
        }
        let mut svg = String::new();
        {
            let root = SVGBackend::with_string(&mut svg, self.size).into_drawing_area();
            root.fill(&WHITE).map_err(|e| e.to_string())?;
            let mut chart = ChartBuilder::on(&root)
                .caption(&self.title, ("sans-serif", 22))
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
            for line in lines {
                let color = line.color;
                chart
                    .draw_series(LineSeries::new(
                        line.points.iter().copied(),
                        color.stroke_width(2),
                    ))
                    .map_err(|e| e.to_string())?
                    .label(line.label)
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                    });
            }
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::UpperRight)
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .label_font(("sans-serif", 14))
                .draw()
                .map_err(|e| e.to_string())?;
            root.present().map_err(|e| e.to_string())?;
        }
        Ok(svg)
    }
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
            nees_mean: None,
            nis_mean: None,
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
                            vel_en_mps: None,
                            cov4: None,
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
                vel_en_mps: None,
                cov4: None,
            },
            // Outside the truth's span: skipped.
            Estimate {
                t_ns: 5_000_000_000,
                pos_en_m: [0.0, 0.0],
                vel_en_mps: None,
                cov4: None,
            },
            // Not finite: skipped.
            Estimate {
                t_ns: 1_500_000_000,
                pos_en_m: [f64::NAN, 0.0],
                vel_en_mps: None,
                cov4: None,
            },
            Estimate {
                t_ns: 2_000_000_000,
                pos_en_m: [1.0 - 0.6, 0.5 + 0.8],
                vel_en_mps: None,
                cov4: None,
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
        let files = write_figures(&rep, &truth(), &dir).unwrap();
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
        let files = write_figures(&rep, &truth(), &dir).unwrap();
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
        let e = write_figures(&report(&[("kf", 0.0, 0.0)]), &truth(), &dir).unwrap_err();
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
}
