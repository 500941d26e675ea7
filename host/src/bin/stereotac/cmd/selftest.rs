//! `stereotac selftest`: the command checks of [`stereotac::selftest`] on one sensor.

use anyhow::{Context, Result, bail};

use crate::sensor_args::{DeviceArgs, open};

/// `stereotac selftest`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub device: DeviceArgs,
}

pub fn run(a: Args) -> Result<()> {
    let mut opened = open(&a.device)?;
    let report = stereotac::selftest::run_command_checks(&mut opened.sensor)
        .context("running the command checks")?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        for c in &report.checks {
            let mark = if c.passed { "ok  " } else { "FAIL" };
            println!("{mark} {}", c.name);
            if !c.passed {
                println!("     {}", c.detail);
            }
        }
    }
    let failed = report.failures().count();
    if failed > 0 {
        bail!("{failed} of {} checks failed", report.checks.len());
    }
    if !a.json {
        println!("all {} checks passed", report.checks.len());
    }
    Ok(())
}
