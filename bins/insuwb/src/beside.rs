//! The programs that live next to the `insuwb` executable: the stages, the
//! bridges, `insuwb-station` and the floor bench. `cargo build --release`
//! builds what the demo needs; the bridges and the station build with
//! `--workspace` or `-p NAME`, so a program that is not there is named with
//! the command that builds it.

use std::ffi::OsString;
use std::path::PathBuf;

use anyhow::{bail, Context, Result};

/// The path of program `name` (its package is named the same) beside this
/// executable.
///
/// # Errors
/// It is not built: the error says the command that builds it.
pub fn program(name: &str) -> Result<PathBuf> {
    let exe = std::env::current_exe().context("locating the insuwb executable")?;
    let dir = exe
        .parent()
        .context("the insuwb executable has no folder")?;
    let p = dir.join(name);
    if !p.is_file() {
        bail!(
            "{name} is not built ({} not found): build it with `cargo build --release -p {name}`, or everything with `cargo build --release --workspace`",
            p.display()
        );
    }
    Ok(p)
}

/// Runs program `name` with `args` in place of this process (its output,
/// exit status and signals are the command's).
///
/// # Errors
/// It is not built, or cannot be started.
pub fn exec(name: &str, args: &[OsString]) -> Result<()> {
    use std::os::unix::process::CommandExt;
    let p = program(name)?;
    let e = std::process::Command::new(&p).args(args).exec();
    Err(e).with_context(|| format!("starting {}", p.display()))
}
