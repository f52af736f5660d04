//! `fpm dpc`: quantitative phase from the four half-circle patterns of a dataset's
//! bright-field frames, for a first look and for focusing.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use fpm_physics::dpc::Regularisation;

/// `fpm dpc DATASET --out DIR`.
#[derive(Args, Debug)]
pub struct DpcArgs {
    /// The dataset (its in-focus bright-field frames make the four half-circle frames).
    dataset: PathBuf,
    /// Where to write phase.tif, absorption.tif (OME-TIFF), PNG previews and dpc.json.
    #[arg(long)]
    out: PathBuf,
    /// Tikhonov weight on the phase: higher holds the slowest phase (which DPC hardly
    /// sees) nearer zero and the noise lower, at the cost of detail.
    #[arg(long, default_value_t = Regularisation::default().phase)]
    reg_phase: f64,
    /// Tikhonov weight on the absorption.
    #[arg(long, default_value_t = Regularisation::default().absorption)]
    reg_absorption: f64,
    /// Print dpc.json.
    #[arg(long)]
    json: bool,
}

pub fn run(a: DpcArgs) -> Result<()> {
    for (name, v) in [
        ("--reg-phase", a.reg_phase),
        ("--reg-absorption", a.reg_absorption),
    ] {
        if !(v.is_finite() && v > 0.0) {
            anyhow::bail!("{name} {v}: give a positive weight (default 0.001)");
        }
    }
    let ds = fpm_host::dataset::Dataset::load(&a.dataset)?;
    let reg = Regularisation {
        absorption: a.reg_absorption,
        phase: a.reg_phase,
    };
    let result = fpm_host::dpc::dpc_of(&ds, reg)?;
    fpm_host::dpc::write(&result, &ds, &a.out)?;
    let page = fpm_report::pages::dpc::write_extras(&result, &a.dataset, &a.out);
    let r = &result.report;
    for w in &r.warnings {
        eprintln!("warning: {w}");
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(r)?);
        return Ok(());
    }
    let counts: Vec<String> = r
        .halves
        .iter()
        .map(|h| format!("{} {}", h.half, h.leds.len()))
        .collect();
    println!(
        "DPC from four half-circle patterns ({} bright-field LEDs), up to {:.3} cycles/µm",
        counts.join(", "),
        r.max_frequency
    );
    if let Some(s) = r.versus_truth {
        println!(
            "versus the simulation's truth (low-passed to 2·NA/λ): phase RMSE {:.3} rad, NRMSE {:.3} ({:.3} with the slow phase fitted out)",
            s.phase_rmse_rad, s.phase_nrmse, s.detail_nrmse
        );
    }
    println!(
        "wrote phase.tif, absorption.tif (OME-TIFF, pixel size in µm), PNG previews and dpc.json to {}",
        a.out.display()
    );
    println!(
        "wrote {} (the report: open it in a browser)",
        page.display()
    );
    Ok(())
}
