//! `fpm simulate scan` and `fpm stitch`: whole slides (`fpm_host::scan`).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;
use clap::Args;
use fpm_host::reconstruction::Job;
use fpm_host::scan::{self, SimulatedScan, StitchEvent, StitchOptions};
use fpm_host::simulation::{self, Scene};
use fpm_physics::reconstruct::Settings;
use fpm_physics::simulate::SampleKind;
use fpm_physics::System;

use crate::flatten::FlattenArgs;
use crate::progress;

/// `fpm simulate scan`.
#[derive(Args, Debug, Clone)]
pub struct SimulateScanArgs {
    /// Output directory: scan.json, fields/r*c*/ (one dataset each), truth/.
    #[arg(long)]
    pub out: PathBuf,
    /// The grid, ROWSxCOLS.
    #[arg(long, default_value = "3x3", value_parser = rows_cols)]
    pub fields: (usize, usize),
    /// Neighbouring fields overlap by this fraction of a field.
    #[arg(long, default_value_t = 0.15)]
    pub overlap: f64,
    /// Sensor side, pixels (each field).
    #[arg(long, default_value_t = 128)]
    pub size: usize,
    /// The objective's magnification (the paper's 4×; lower gives a wider field).
    #[arg(long, default_value_t = 4.0)]
    pub magnification: f64,
    /// The stage misses each commanded position by up to this much, µm.
    #[arg(long, default_value_t = 20.0)]
    pub stage_error_um: f64,
    /// Simulation pixels per camera pixel.
    #[arg(long, default_value_t = 2)]
    pub upsample: usize,
    /// Light only the central LEDS × LEDS of the array (odd; default: all 21 × 21).
    #[arg(long)]
    pub leds: Option<usize>,
    /// Random seed (slide, stage errors, noise).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Print what was written as JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn rows_cols(s: &str) -> Result<(usize, usize), String> {
    let (r, c) = s
        .split_once(['x', '×'])
        .ok_or_else(|| format!("`{s}`: give ROWSxCOLS, e.g. 3x3"))?;
    let n = |t: &str| {
        t.trim()
            .parse::<usize>()
            .ok()
            .filter(|v| (1..=20).contains(v))
            .ok_or_else(|| format!("`{t}` in `{s}`: give 1–20"))
    };
    Ok((n(r)?, n(c)?))
}

/// Run `fpm simulate scan`.
pub fn simulate(a: SimulateScanArgs) -> Result<()> {
    let started = Instant::now();
    let s = SimulatedScan {
        rows: a.fields.0,
        cols: a.fields.1,
        overlap: a.overlap,
        scene: Scene {
            truth: Scene::placed(0.0, 0.0, 0.0, 92.0),
            noise: simulation::Noise::Realistic,
            size: a.size,
            seed: a.seed,
            stray_light: 0.0,
        },
        system: System {
            magnification: a.magnification,
            ..System::paper()
        },
        upsample: a.upsample,
        stage_error_um: a.stage_error_um,
        sample: SampleKind::Cells,
    };
    let s = match a.leds {
        Some(n) => s.central_leds(n),
        None => s,
    };
    let bar = progress::counter("simulating", "fields");
    let manifest = scan::simulate(&s, &a.out, &|k, total| progress::advance(&bar, k, total))?;
    bar.finish_and_clear();
    if a.json {
        println!(
            "{}",
            serde_json::json!({
                "out": a.out,
                "fields": manifest.fields.len(),
                "seconds": started.elapsed().as_secs_f64(),
            })
        );
    } else {
        println!(
            "wrote a {}×{} scan ({} fields of {}², overlap {:.0} %, stage off by up to {} µm) to {} in {:.1} s; the slide's truth in truth/",
            s.rows,
            s.cols,
            manifest.fields.len(),
            a.size,
            100.0 * a.overlap,
            a.stage_error_um,
            a.out.display(),
            started.elapsed().as_secs_f64()
        );
    }
    Ok(())
}

/// `fpm stitch`.
#[derive(Args, Debug, Clone)]
pub struct StitchArgs {
    /// The scan directory (scan.json, fields/).
    pub scan: PathBuf,
    /// Where the mosaic goes (mosaic.zarr, stitch.json). Default: SCAN/mosaic.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Reconstruct every field again, even those with a reconstruction.
    #[arg(long)]
    pub redo: bool,
    /// Field reconstructions kept in memory at most, MiB (the rest are read again
    /// from disk as the mosaic is written; at least two rows of fields are kept).
    #[arg(long, default_value_t = scan::FIELD_MEMORY_BYTES >> 20)]
    pub field_memory_mib: usize,
    /// The stage's position error, 1σ, µm: how far overlaps are searched (4σ) and how
    /// much the stage's positions weigh against the images'.
    #[arg(long, default_value_t = 10.0)]
    pub stage_sigma_um: f64,
    /// HR pixels per camera pixel of each field's reconstruction.
    #[arg(long, default_value_t = 2)]
    pub upsample: usize,
    /// Passes over all frames, each field.
    #[arg(long, default_value_t = fpm_physics::reconstruct::defaults::PASSES)]
    pub passes: usize,
    #[command(flatten)]
    pub flatten: FlattenArgs,
    /// Print stitch.json instead of a summary.
    #[arg(long)]
    pub json: bool,
}

/// Run `fpm stitch`.
pub fn stitch(a: StitchArgs) -> Result<()> {
    if !(a.stage_sigma_um.is_finite() && a.stage_sigma_um > 0.0) {
        anyhow::bail!(
            "--stage-sigma-um {}: give a distance above 0",
            a.stage_sigma_um
        );
    }
    let options = stitch_options(&a);
    let manifest = scan::ScanManifest::read(&a.scan)?;
    let bar = progress::counter("reconstructing", "fields");
    let total = manifest.fields.len();
    let out = a.out.clone().unwrap_or_else(|| a.scan.join("mosaic"));
    let (stitched, page) = fpm_report::slide::stitch(
        &a.scan,
        &options,
        &out,
        &fpm_report::html::command_line(),
        &mut |e| match e {
            StitchEvent::Field { done, .. } => progress::advance(&bar, done, total),
            StitchEvent::Registering { done, total: pairs } => {
                bar.set_message(format!("registering overlap {} of {pairs}", done + 1))
            }
            StitchEvent::Writing { done, total: rows } => {
                progress::advance(&bar, total, total);
                bar.set_message(format!("writing row {done} of {rows}"));
            }
        },
    )?;
    bar.finish_and_clear();
    let zarr = &stitched.mosaic;
    let r = &stitched.report;
    if a.json {
        println!("{}", serde_json::to_string_pretty(r)?);
        return Ok(());
    }
    print_stitch(r, zarr);
    if let Ok(page) = page {
        println!("report: {}", page.display());
    }
    Ok(())
}

/// The stitch's options from its flags (the reconstruction's defaults for the rest).
fn stitch_options(a: &StitchArgs) -> StitchOptions {
    StitchOptions {
        job: Job {
            settings: Settings {
                upsample: a.upsample,
                flatten: a.flatten.flatten(),
                ..Settings::default()
            },
            passes: a.passes,
            ..Job::default()
        },
        settings: fpm_physics::stitch::Settings {
            stage_sigma_um: a.stage_sigma_um,
            ..Default::default()
        },
        redo: a.redo,
        field_memory_bytes: a.field_memory_mib << 20,
    }
}

/// What `fpm stitch` says of the mosaic it wrote to `zarr`.
fn print_stitch(r: &fpm_host::scan::StitchReport, zarr: &std::path::Path) {
    let used = r.pairs.iter().filter(|p| p.used).count();
    println!(
        "{} fields joined into {}×{} px ({:.2} µm) in {}: {used} of {} overlaps registered, residual {:.2} µm rms",
        r.fields.len(),
        r.canvas.width,
        r.canvas.height,
        r.canvas.pitch_um,
        zarr.display(),
        r.pairs.len(),
        r.residual_rms_um
    );
    let moved = r
        .fields
        .iter()
        .map(|f| f.correction_um[0].hypot(f.correction_um[1]))
        .fold(0.0, f64::max);
    println!("largest correction to the stage's positions: {moved:.1} µm");
    if let Some(t) = &r.versus_truth {
        println!(
            "against the hidden slide: mosaic complex NRMSE {:.3}, the fields' own {:.3} ({:.2}×); fields placed within {:.2} µm (rms {:.2}; the stage alone {:.1} µm rms); seam step {:.3} rad against {:.3} across a field",
            t.complex_nrmse,
            t.fields_complex_nrmse,
            t.ratio,
            t.max_position_error_um,
            t.rms_position_error_um,
            t.rms_stage_error_um,
            t.seam_step_rad,
            t.within_step_rad
        );
    }
    for w in &r.warnings {
        println!("warning: {w}");
    }
}

/// `fpm scan`.
#[derive(Args, Debug, Clone)]
pub struct ScanArgs {
    /// The grid, ROWSxCOLS; field (0, 0) is where the stage is now, the scan runs
    /// over +x and +y from there.
    #[arg(long, default_value = "3x3", value_parser = rows_cols)]
    pub fields: (usize, usize),
    /// Neighbouring fields overlap by this fraction of a field.
    #[arg(long, default_value_t = 0.15)]
    pub overlap: f64,
    /// The stage's position error, 1σ, µm (for stitching).
    #[arg(long, default_value_t = 10.0)]
    pub stage_sigma_um: f64,
    /// Do not focus each field before acquiring it (by default the defocus is read
    /// from a few bright-field frames and the stage moves when it is clear).
    #[arg(long)]
    pub no_autofocus: bool,
    /// The acquisition of each field (--out is the scan directory; --calibrate
    /// calibrates at the first field; --reconstruct reconstructs each field while the
    /// next is acquired, then stitches them).
    #[command(flatten)]
    pub acquire: crate::acquire::AcquireArgs,
}

/// Run `fpm scan`.
pub fn scan(a: ScanArgs) -> Result<()> {
    let acq = &a.acquire;
    if !acq.colors.is_empty() {
        anyhow::bail!("--colors: a scan is in one colour for now; scan each colour separately");
    }
    let dev = crate::acquire::open_controller(acq)?;
    let mut stage = acq.stage.open_scan()?;
    let scan_plan = fpm_acquire::scan::ScanPlan {
        autofocus: !a.no_autofocus,
        ..fpm_acquire::scan::ScanPlan::new(
            a.fields.0,
            a.fields.1,
            a.overlap,
            crate::acquire::plan(acq),
            a.stage_sigma_um,
        )
    };
    let control = fpm_acquire::pipeline::Control::cancelled_by(crate::acquire::cancel_on_signal()?);
    let bar = progress::counter("scanning", "fields");
    let total = a.fields.0 * a.fields.1;
    let summary = fpm_acquire::scan::run(
        &dev,
        stage.as_mut(),
        &scan_plan,
        &mut |e| show_scan_event(&bar, total, e),
        &control,
    )?;
    bar.finish_and_clear();
    if acq.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
        return Ok(());
    }
    println!(
        "scanned {} fields ({} acquired now) into {} in {:.1} s: {:.0} fields per hour",
        summary.fields,
        summary.acquired,
        acq.out.display(),
        summary.seconds,
        summary.fields_per_hour
    );
    if let (Some(mosaic), Some(stitch)) = (&summary.mosaic, &summary.stitch) {
        println!(
            "mosaic: {} (pairs agree to {:.2} µm rms)",
            mosaic.display(),
            stitch.residual_rms_um
        );
        for w in &stitch.warnings {
            eprintln!("warning: {w}");
        }
    }
    Ok(())
}

/// A scan's progress on its bar (`total` fields).
fn show_scan_event(bar: &indicatif::ProgressBar, total: usize, e: fpm_acquire::scan::ScanEvent) {
    match e {
        fpm_acquire::scan::ScanEvent::Moving { index, .. } => {
            progress::advance(bar, index, total);
            bar.set_message(format!("field {}: moving", index + 1));
        }
        fpm_acquire::scan::ScanEvent::Acquiring {
            index, progress: p, ..
        } => {
            bar.set_message(format!("field {}: {}/{} frames", index + 1, p.frames, p.of));
        }
        fpm_acquire::scan::ScanEvent::Skipped { index } => progress::advance(bar, index + 1, total),
        fpm_acquire::scan::ScanEvent::Reconstructed { .. } => {}
        fpm_acquire::scan::ScanEvent::Focused {
            index,
            measured_um,
            moved,
        } => bar.set_message(match (measured_um, moved) {
            (Some(z), true) => format!("field {}: refocused by {z:+.0} µm", index + 1),
            (Some(z), false) => format!("field {}: in focus ({z:+.0} µm)", index + 1),
            (None, _) => format!("field {}: too blank to focus, focus kept", index + 1),
        }),
        fpm_acquire::scan::ScanEvent::Stitching { done, total } => {
            progress::advance(bar, total, total);
            bar.set_message(if done < total {
                format!("stitching: field {}", done + 1)
            } else {
                "stitching: registering and blending".into()
            });
        }
    }
}
