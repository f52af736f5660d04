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
    let r = &result.report;
    let span = |img: &fpm_physics::Image| {
        let m = img.iter().fold(0.0f32, |m, v| m.max(v.abs())).max(1e-6);
        (-m, m)
    };
    // Previews are an extra: a failure is reported, never the run's.
    for (name, img, unit) in [
        ("phase.png", &result.object.phase, "rad"),
        ("absorption.png", &result.object.absorption, ""),
    ] {
        if let Err(e) = fpm_report::preview::write_png_preview_with_bar(
            &a.out.join(name),
            img,
            span(img),
            Some(r.pixel_um),
            unit,
        ) {
            tracing::warn!("{name} not written: {e:#}");
        }
    }
    let page = a.out.join("report.html");
    let outputs = [
        ("phase.tif", "the phase, radians (OME-TIFF)"),
        ("absorption.tif", "the absorption μ (OME-TIFF)"),
        ("dpc.json", "this report, machine-readable"),
    ]
    .map(|(f, what)| (f.to_string(), what.to_string()))
    .to_vec();
    let context = fpm_report::pages::dpc::Context {
        report: r,
        dataset: &a.dataset.display().to_string(),
        previews: vec![
            (a.out.join("phase.png"), "phase (radians)"),
            (a.out.join("absorption.png"), "absorption"),
        ],
        reproduce: &fpm_report::html::command_line(),
        outputs,
    };
    // The page is an extra: a failure is a warning, never the run's.
    if let Err(e) = fpm_report::pages::dpc::write(&context, &page) {
        tracing::warn!("{} not written: {e:#}", page.display());
    }
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
