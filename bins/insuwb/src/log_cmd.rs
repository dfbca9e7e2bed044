//! `insuwb log info`, `insuwb log cat` and `insuwb log export`.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use insuwb_log::{LogReader, Record};

/// Log subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum LogCmd {
    /// Header, metadata, record counts per topic, time span and integrity of a log.
    Info {
        /// The log file (or a run directory of segments).
        file: PathBuf,
    },
    /// Print the records of a log, one per line.
    Cat {
        /// The log file.
        file: PathBuf,
        /// Only this topic (imu, uwb_tdoa, uwb_fix, nav, correction, fused, diag, truth, health, body_vel, uwb_range, height).
        #[arg(long)]
        topic: Option<String>,
        /// CSV instead of debug text: topic, seq, generation, meas_time_ns,
        /// pub_time_ns, then the sample's fields (diag: nis, fading, dim, then
        /// dim each of innovation, innovation variance, outlier weight, R in use;
        /// body_vel: velocity x, y, z, sigma x, y, z, source, range mm;
        /// height: range m, source).
        #[arg(long)]
        csv: bool,
    },
    /// Write every record of a log into an MCAP file (profile ros2, ROS 2
    /// CDR messages with ros2msg schemas) for Foxglove and the ROS 2 tools;
    /// topics, types and times: docs/MCAP_EXPORT.md.
    Export {
        /// The log file (or a run directory of segments).
        file: PathBuf,
        /// The MCAP file to write (replaced if it exists).
        #[arg(long)]
        mcap: PathBuf,
    },
}

/// Runs a log subcommand.
pub fn run(c: &LogCmd) -> Result<()> {
    match c {
        LogCmd::Info { file } => info(file),
        LogCmd::Cat { file, topic, csv } => cat(file, topic.as_deref(), *csv),
        LogCmd::Export { file, mcap } => export(file, mcap),
    }
}

fn export(file: &Path, mcap: &Path) -> Result<()> {
    let s = insuwb_mcap::export_log(file, mcap, &insuwb_mcap::ExportOptions::default())?;
    for c in &s.cuts {
        eprintln!("warning: {c}");
    }
    let skipped: u64 = s.stats.skipped.values().sum();
    if let Some(first) = &s.stats.first_skip {
        eprintln!("warning: {skipped} messages not converted; the first: {first}");
    }
    let mut out = std::io::stdout().lock();
    writeln!(
        out,
        "{}: {} messages on {} topics from {} records of {} file(s)",
        mcap.display(),
        s.stats.total_messages(),
        s.stats.messages.len(),
        s.stats.total_records(),
        s.files.len()
    )?;
    for (topic, n) in &s.stats.messages {
        writeln!(out, "  {topic:<20} {n:>9} messages")?;
    }
    Ok(())
}

fn files_of(path: &PathBuf) -> Result<Vec<PathBuf>> {
    if path.is_dir() {
        // The errors of the log reader name the file and the cause.
        let segs = insuwb_log::list_segments(path)?;
        if segs.is_empty() {
            bail!(
                "{}: no seg-*.iulog segment in this directory",
                path.display()
            );
        }
        Ok(segs.into_iter().map(|s| s.path).collect())
    } else {
        Ok(vec![path.clone()])
    }
}

fn info(path: &PathBuf) -> Result<()> {
    let mut out = std::io::stdout().lock();
    for f in files_of(path)? {
        let mut r = LogReader::open(&f)?;
        let h = r.header().clone();
        let mut counts = [0u64; Record::TOPICS.len()];
        let mut span: Option<(u64, u64)> = None;
        for rec in r.by_ref() {
            let rec = rec.with_context(|| format!("{}", f.display()))?;
            if let Some(i) = Record::TOPICS.iter().position(|t| *t == rec.topic()) {
                counts[i] += 1;
            }
            let t = rec.header().meas_time_ns;
            span = Some(span.map_or((t, t), |(a, b)| (a.min(t), b.max(t))));
        }
        writeln!(out, "{}", f.display())?;
        writeln!(
            out,
            "  format {} layout {} created {} ns, source: {}",
            h.format_version, h.layout_version, h.created_ns, h.meta.source
        )?;
        for (k, v) in &h.meta.entries {
            let first = v.lines().next().unwrap_or("");
            let more = if v.lines().count() > 1 { " ..." } else { "" };
            writeln!(out, "  meta {k} = {first}{more}")?;
        }
        for (t, n) in Record::TOPICS.iter().zip(counts) {
            if n > 0 {
                writeln!(out, "  {t:<11} {n:>9} records")?;
            }
        }
        if let Some((a, b)) = span {
            writeln!(
                out,
                "  time {:.3} .. {:.3} s ({:.3} s)",
                a as f64 * 1e-9,
                b as f64 * 1e-9,
                (b - a) as f64 * 1e-9
            )?;
        }
        match r.tail() {
            Some(t) => writeln!(out, "  DAMAGED: {t}")?,
            None => writeln!(out, "  intact")?,
        }
    }
    Ok(())
}

fn csv_line(rec: &Record) -> String {
    let h = rec.header();
    let head = format!(
        "{},{},{},{},{}",
        rec.topic(),
        h.seq,
        h.generation,
        h.meas_time_ns,
        h.pub_time_ns
    );
    let f = |v: &[f64]| {
        v.iter()
            .map(|x| format!("{x}"))
            .collect::<Vec<_>>()
            .join(",")
    };
    match rec {
        Record::Imu(s) => format!("{head},{},{}", f(&s.accel_mps2), f(&s.gyro_rps)),
        Record::Tdoa(s) => format!("{head},{},{},{}", s.anchor_a, s.anchor_b, s.diff_m),
        Record::Range(s) => format!(
            "{head},{},{},{},{}",
            s.anchor,
            s.range_m,
            s.quality,
            f(&s.anchor_pos_m)
        ),
        Record::Fix(s) => format!("{head},{},{},{}", f(&s.pos_m), f(&s.vel_mps), s.gdop),
        Record::Nav(s) => format!(
            "{head},{},{},{},{}",
            s.correction_id,
            f(&s.pos_m),
            f(&s.vel_mps),
            f(&s.quat)
        ),
        Record::Correction(s) => format!(
            "{head},{},{},{},{},{}",
            s.correction_id,
            s.apply_at_seq,
            f(&s.d_pos_m),
            f(&s.d_vel_mps),
            f(&s.d_att_rad)
        ),
        Record::Fused(s) => format!(
            "{head},{},{},{},{}",
            f(&s.pos_m),
            f(&s.vel_mps),
            s.yaw_rad,
            s.header.flags
        ),
        Record::Diag(s) => {
            let n = s.dim.min(8) as usize;
            format!(
                "{head},{},{},{},{},{},{},{}",
                s.nis,
                s.fading,
                n,
                f(&s.innovation[..n]),
                f(&s.innovation_var[..n]),
                f(&s.lambda[..n]),
                f(&s.r_diag[..n])
            )
        }
        Record::Truth(s) => format!("{head},{},{},{}", f(&s.pos_m), f(&s.vel_mps), f(&s.quat)),
        Record::Health(s) => format!(
            "{head},{},{},{},{}",
            insuwb_msg::name_str(&s.stage),
            s.pid,
            s.received,
            s.published
        ),
        Record::BodyVel(s) => format!(
            "{head},{},{},{},{}",
            f(&s.vel_mps),
            f(&s.sigma_mps),
            s.source,
            s.range_mm
        ),
        Record::Height(s) => format!("{head},{},{}", s.range_m, s.source),
    }
}

fn cat(path: &PathBuf, topic: Option<&str>, csv: bool) -> Result<()> {
    if let Some(t) = topic {
        if !Record::TOPICS.contains(&t) {
            bail!(
                "--topic: unknown topic '{t}' (known: {})",
                Record::TOPICS.join(", ")
            );
        }
    }
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    for f in files_of(path)? {
        let mut r = LogReader::open(&f)?;
        for rec in r.by_ref() {
            let rec = rec?;
            if topic.is_some_and(|t| t != rec.topic()) {
                continue;
            }
            if csv {
                writeln!(out, "{}", csv_line(&rec))?;
            } else {
                writeln!(out, "{rec:?}")?;
            }
        }
        if let Some(t) = r.tail() {
            eprintln!("warning: {}: {t}", f.display());
        }
    }
    Ok(())
}
