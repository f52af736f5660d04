//! `fpm reconstruct DIR --out OUT`: EPRY phase retrieval of a dataset.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use fpm_physics::reconstruct::Settings;

use crate::calibration::CalibrationFile;
use crate::dataset::Dataset;
use crate::reconstruction::{reconstruct, write_outputs};

/// Reconstruct the high-resolution amplitude and phase (and the pupil) with EPRY.
#[derive(Args, Debug)]
pub struct ReconstructArgs {
    /// Dataset directory (with dataset.toml); its in-focus frames are used.
    dir: PathBuf,
    /// Output directory.
    #[arg(long)]
    out: PathBuf,
    /// LED geometry from `fpm calibrate` instead of the dataset's nominal one.
    #[arg(long)]
    calibration: Option<PathBuf>,
    /// HR pixels per camera pixel.
    #[arg(long, default_value_t = 4)]
    upsample: usize,
    /// Passes over all frames.
    #[arg(long, default_value_t = 10)]
    passes: usize,
    /// Keep the ideal pupil instead of recovering it.
    #[arg(long)]
    fixed_pupil: bool,
}

/// Run `fpm reconstruct`.
pub fn run(a: ReconstructArgs) -> Result<()> {
    let ds = Dataset::load(&a.dir)?;
    let (geometry, source) = match &a.calibration {
        Some(path) => (
            CalibrationFile::read(path)?.geometry(),
            path.display().to_string(),
        ),
        None => (ds.manifest.geometry(), "nominal (dataset.toml)".to_string()),
    };
    let settings = Settings {
        upsample: a.upsample.max(1),
        update_pupil: !a.fixed_pupil,
        ..Settings::default()
    };
    let bar = indicatif::ProgressBar::new(1).with_style(
        indicatif::ProgressStyle::with_template(
            "reconstructing [{bar:40}] {pos}/{len} frame updates ({eta} left)",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let r = reconstruct(
        &ds,
        &geometry,
        &source,
        settings,
        a.passes,
        |done, total| {
            bar.set_length(total as u64);
            bar.set_position(done as u64);
        },
    )?;
    bar.finish_and_clear();
    write_outputs(&r, &a.out)?;
    let rep = &r.report;
    println!(
        "{} frames, {} passes, {}x upsampling in {:.2} s ({:.0} ms per pass); amplitude error per pass: first {:.4}, last {:.4}",
        rep.frames,
        rep.passes,
        rep.upsample,
        rep.total_ms / 1e3,
        rep.pass_ms.iter().sum::<f64>() / rep.pass_ms.len().max(1) as f64,
        rep.error_per_pass.first().copied().unwrap_or(f64::NAN),
        rep.error_per_pass.last().copied().unwrap_or(f64::NAN)
    );
    println!(
        "wrote amplitude/phase/pupil TIFFs and PNG previews and report.json to {}",
        a.out.display()
    );
    Ok(())
}
