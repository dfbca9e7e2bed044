//! The estimates of an evaluation as one CSV file, for analysis in other
//! tools: one row per solution and epoch, with the interpolated truth and
//! the signed error beside each estimate.
//!
//! Columns: `solution, t_ns, east_m, north_m, truth_east_m, truth_north_m,
//! err_east_m, err_north_m, in_segment, vel_east_mps, vel_north_mps,
//! truth_vel_east_mps, truth_vel_north_mps, yaw_rad, truth_yaw_rad, up_m,
//! truth_up_m`. Truth
//! and error are empty where the truth does not cover the epoch; `in_segment`
//! is 1 for the epochs the metrics count (the flight segment), else 0. A
//! solution's velocity and heading are empty where it has none (the fix, the
//! INS), the truth's heading where it has no attitude. The file is written whole
//! through a temporary file and renamed, so a reader never sees half of it.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::metrics::TruthTrack;
use crate::run::{Dataset, EvalReport};

/// Why the tracks could not be written.
#[derive(Debug, thiserror::Error)]
pub enum TracksError {
    /// The file (or its temporary) could not be written or renamed.
    #[error("cannot write the tracks file {}: {error}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        error: std::io::Error,
    },
}

/// The CSV header line.
pub const HEADER: &str =
    "solution,t_ns,east_m,north_m,truth_east_m,truth_north_m,err_east_m,err_north_m,in_segment,\
vel_east_mps,vel_north_mps,truth_vel_east_mps,truth_vel_north_mps,yaw_rad,truth_yaw_rad,up_m,\
truth_up_m";

/// The CSV text of every solution's track in `rep` against `data`'s truth.
#[must_use]
pub fn to_csv(rep: &EvalReport, data: &Dataset) -> String {
    let truth = TruthTrack::new(&data.truth, crate::plot::TRUTH_MAX_GAP_NS);
    let mut out = String::with_capacity(64 * rep.epochs.len() * rep.solutions.len().max(1));
    out.push_str(HEADER);
    out.push('\n');
    for s in &rep.solutions {
        for e in &s.track {
            let inside = data.segment.is_none_or(|(a, b)| (a..=b).contains(&e.t_ns));
            let [east, north] = e.pos_en_m;
            // Writing into a String cannot fail.
            let _ = write!(out, "{},{},{east:.6},{north:.6},", s.key, e.t_ns);
            let at = truth.at(e.t_ns);
            match at {
                Some((p, _)) => {
                    let _ = write!(
                        out,
                        "{:.6},{:.6},{:.6},{:.6},",
                        p[0],
                        p[1],
                        east - p[0],
                        north - p[1]
                    );
                }
                None => out.push_str(",,,,"),
            }
            out.push_str(if inside { "1," } else { "0," });
            match e.vel_en_mps {
                Some([ve, vn]) => {
                    let _ = write!(out, "{ve:.6},{vn:.6},");
                }
                None => out.push_str(",,"),
            }
            match at {
                Some((_, v)) => {
                    let _ = write!(out, "{:.6},{:.6},", v[0], v[1]);
                }
                None => out.push_str(",,"),
            }
            if let Some(y) = e.yaw_rad {
                let _ = write!(out, "{y:.6}");
            }
            out.push(',');
            if let Some(y) = truth.yaw_at(e.t_ns) {
                let _ = write!(out, "{y:.6}");
            }
            let _ = write!(out, ",{:.6},", e.up_m);
            if let Some((p, _)) = at {
                let _ = write!(out, "{:.6}", p[2]);
            }
            out.push('\n');
        }
    }
    out
}

/// Writes [`to_csv`] to `path` (whole: a temporary beside it, then renamed);
/// returns the number of rows.
///
/// # Errors
/// [`TracksError::Write`] when the file cannot be written or renamed.
pub fn write(rep: &EvalReport, data: &Dataset, path: &Path) -> Result<usize, TracksError> {
    let text = to_csv(rep, data);
    let rows = text.lines().count().saturating_sub(1);
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    let err = |error| TracksError::Write {
        path: path.to_path_buf(),
        error,
    };
    std::fs::write(&tmp, text).map_err(err)?;
    std::fs::rename(&tmp, path).map_err(err)?;
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::Estimate;
    use crate::run::Solution;
    use insuwb_msg::GroundTruth;

    fn truth(t_ns: u64, e: f64) -> GroundTruth {
        let mut g = GroundTruth::default();
        g.header.meas_time_ns = t_ns;
        g.pos_m = [e, 2.0, 1.0];
        // Heading north (90 degrees from east).
        let h = std::f64::consts::FRAC_PI_4;
        g.quat = [h.cos(), 0.0, 0.0, h.sin()];
        g
    }

    fn est(t_ns: u64, e: f64) -> Estimate {
        Estimate {
            t_ns,
            pos_en_m: [e, 2.5],
            up_m: 1.2,
            vel_en_mps: None,
            cov4: None,
            yaw_rad: None,
        }
    }

    fn est_moving(t_ns: u64, e: f64) -> Estimate {
        Estimate {
            vel_en_mps: Some([0.25, -0.5]),
            yaw_rad: Some(1.5),
            ..est(t_ns, e)
        }
    }

    #[test]
    fn rows_carry_truth_error_and_segment() {
        let data = Dataset {
            truth: vec![truth(0, 0.0), truth(10_000_000, 1.0)],
            segment: Some((0, 5_000_000)),
            ..Dataset::default()
        };
        let metrics = crate::metrics::compute(
            &[est(5_000_000, 0.7)],
            &TruthTrack::new(&data.truth, 100_000_000),
            None,
            &[],
        );
        let Ok(metrics) = metrics else {
            panic!("metrics: {metrics:?}");
        };
        let rep = EvalReport {
            dataset: "d".into(),
            solutions: vec![Solution {
                key: "uwb".into(),
                metrics,
                track: vec![
                    est_moving(5_000_000, 0.7),
                    est(8_000_000, 0.9),
                    est(20_000_000, 3.0),
                ],
                run: None,
            }],
            epochs: vec![5_000_000, 8_000_000, 20_000_000],
        };
        let csv = to_csv(&rep, &data);
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines[0], HEADER);
        // The truth moves 1 m east in 10 ms (its velocity: the slope over
        // its span) heading north.
        assert_eq!(
            lines[1],
            "uwb,5000000,0.700000,2.500000,0.500000,2.000000,0.200000,0.500000,1,\
             0.250000,-0.500000,100.000000,0.000000,1.500000,1.570796,1.200000,1.000000"
        );
        // Neither velocity nor heading: those columns are empty.
        assert!(
            lines[2].ends_with(",0,,,100.000000,0.000000,,1.570796,1.200000,1.000000"),
            "{}",
            lines[2]
        );
        assert!(lines[2].starts_with("uwb,8000000,0.900000,2.500000,0.800000,"));
        // No truth after the last sample: the truth and error columns are empty.
        assert_eq!(
            lines[3],
            "uwb,20000000,3.000000,2.500000,,,,,0,,,,,,,1.200000,"
        );
        assert_eq!(lines.len(), 4);
    }

    #[test]
    fn write_replaces_the_file_whole() {
        let dir = std::env::temp_dir().join(format!("insuwb-tracks-{}", std::process::id()));
        let _ = std::fs::create_dir_all(&dir);
        let path = dir.join("t.csv");
        let rep = EvalReport {
            dataset: "d".into(),
            solutions: Vec::new(),
            epochs: Vec::new(),
        };
        let rows = write(&rep, &Dataset::default(), &path);
        assert!(matches!(rows, Ok(0)), "{rows:?}");
        let text = std::fs::read_to_string(&path).unwrap_or_default();
        assert_eq!(text.trim_end(), HEADER);
        assert!(!dir.join("t.csv.tmp").exists());
        let bad = write(&rep, &Dataset::default(), &dir.join("missing/t.csv"));
        assert!(matches!(bad, Err(TracksError::Write { .. })), "{bad:?}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
