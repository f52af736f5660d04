//! `report.html` of a reconstruction: the images with scale bars, the convergence,
//! the pupil, the LED positions used, the parameters, warnings and how to run it
//! again.

use std::path::Path;

use anyhow::Result;
use fpm_physics::{LedGeometry, System};

use super::embed_chart;
use crate::charts::reconstruction::{ErrorPerPass, LedPositions, Pupil};
use crate::html::{Page, Row};
use crate::preview::object as write_object_previews;
use fpm_host::reconstruction::{Reconstruction, Report};

/// What the page is written from.
pub struct Context<'a> {
    /// The dataset's optics.
    pub system: &'a System,
    /// The dataset's nominal array.
    pub nominal: &'a LedGeometry,
    /// The command that reproduces the run.
    pub reproduce: &'a str,
}

/// Longest side of the images the page embeds: a larger object (a full field at
/// U = 4 runs to tens of thousands of pixels) is shown shrunk, its full-size PNGs
/// beside the page.
pub const PAGE_IMAGE_SIDE: usize = 2048;

/// The amplitude and phase previews for the page (PNG bytes and caption): the
/// full-size PNGs `write_outputs` wrote, or, for an object larger than
/// [`PAGE_IMAGE_SIDE`], shrunk copies written into `dir/plots/`. A preview that cannot
/// be had is left out with a warning.
fn page_previews(r: &Reconstruction, dir: &Path) -> Vec<(Vec<u8>, String)> {
    const AMPLITUDE: &str = "Amplitude (0.5–99.5 % of its range), scale bar in µm";
    const PHASE: &str = "Phase, −π (black) to +π (white), scale bar in µm, colour bar in rad";
    let read = |file: &Path, caption: String| match std::fs::read(file) {
        Ok(bytes) => Some((bytes, caption)),
        Err(e) => {
            tracing::warn!("{} not embedded in the report: {e}", file.display());
            None
        }
    };
    let Some((amplitude, complex, factor)) = fpm_host::pyramid::shrunk(&r.object, PAGE_IMAGE_SIDE)
    else {
        return [("amplitude.png", AMPLITUDE), ("phase.png", PHASE)]
            .into_iter()
            .filter_map(|(file, caption)| read(&dir.join(file), caption.to_string()))
            .collect();
    };
    let plots = dir.join("plots");
    let shrunk = |caption: &str, full: &str| {
        format!("{caption}; shown {factor}× smaller ({full} beside this page is full size)")
    };
    let amplitude_file = plots.join("amplitude-page.png");
    let phase_file = plots.join("phase-page.png");
    let written = std::fs::create_dir_all(&plots)
        .map_err(anyhow::Error::from)
        .and_then(|_| {
            write_object_previews(
                &amplitude,
                &complex.mapv(|z| z.arg()),
                r.report.pixel_um * factor as f64,
                &amplitude_file,
                &phase_file,
            )
        });
    if let Err(e) = written {
        tracing::warn!("no shrunk previews for the report: {e:#}");
        return vec![];
    }
    [
        (amplitude_file, shrunk(AMPLITUDE, "amplitude.png")),
        (phase_file, shrunk(PHASE, "phase.png")),
    ]
    .into_iter()
    .filter_map(|(file, caption)| read(&file, caption))
    .collect()
}

/// Write `dir/report.html` (charts into `dir/plots/`) for the reconstruction whose
/// images `fpm_host::reconstruction::write_outputs` wrote into `dir`: one section
/// after another.
pub fn write(r: &Reconstruction, dir: &Path, c: &Context<'_>) -> Result<()> {
    let rep = &r.report;
    let mut page = Page::new("fpm reconstruct: amplitude and phase (EPRY)");
    page.paragraph(&format!("Dataset {}.", rep.dataset));

    page.heading("Images");
    let previews = page_previews(r, dir);
    let figures: Vec<(&[u8], &str, &str)> = previews
        .iter()
        .map(|(b, caption)| (&b[..], caption.as_str(), caption.as_str()))
        .collect();
    page.figures(&figures);

    page.heading("Result");
    page.table(&result_rows(r));
    page.heading("Warnings");
    page.warnings(&fpm_host::reconstruction::warnings(rep));

    page.heading("Charts");
    charts(&mut page, r, dir, c);

    page.heading("Parameters");
    page.table(&parameter_rows(rep, c.system));

    page.heading("Outputs");
    page.files(&output_files(dir));
    page.heading("Reproduce");
    page.command(c.reproduce);
    page.write(&dir.join("report.html"))
}

/// The result's rows: the final error, the image's size, the time, and the truth's
/// comparison for a simulation.
fn result_rows(r: &Reconstruction) -> Vec<Row> {
    let rep = &r.report;
    let mut rows = vec![
        Row::with_id(
            "final_error",
            "frames' relative amplitude error, last pass",
            rep.error_per_pass
                .last()
                .map(|e| format!("{e:.4}"))
                .unwrap_or_else(|| "—".into()),
        ),
        Row::new(
            "image",
            format!(
                "{}×{} pixels of {:.4} µm ({}× the camera's sampling)",
                r.object.dim().1,
                r.object.dim().0,
                rep.pixel_um,
                rep.upsample
            ),
        ),
        Row::with_id(
            "total_ms",
            "time",
            format!(
                "{:.0} ms, {:.0} ms per pass, {} thread(s)",
                rep.total_ms, rep.ms_per_pass, rep.threads
            ),
        ),
    ];
    if let Some(share) = rep.automatic_share() {
        let steps: Vec<String> = rep
            .steps_ms
            .iter()
            .map(|s| format!("{} {:.0} ms", s.step, s.ms))
            .collect();
        rows.push(Row::with_id(
            "steps_ms",
            "time by step",
            format!(
                "{}; the automatic checks {:.0} % of it",
                steps.join(", "),
                100.0 * share
            ),
        ));
    }
    if let Some(s) = &rep.versus_truth {
        rows.push(Row::with_id(
            "complex_nrmse",
            "against the simulation's truth: complex NRMSE",
            format!("{:.4}", s.complex_nrmse),
        ));
        rows.push(Row::new(
            "complex NRMSE, slow phase (piston, tilts, quadratic) fitted out",
            format!("{:.4}", s.detail_nrmse),
        ));
        rows.push(Row::new(
            "amplitude NRMSE / phase RMSE",
            format!("{:.4} / {:.4} rad", s.amplitude_nrmse, s.phase_rmse_rad),
        ));
    }
    rows
}

/// The convergence, the pupil and the LED positions, as charts in `dir/plots/`.
fn charts(page: &mut Page, r: &Reconstruction, dir: &Path, c: &Context<'_>) {
    let rep = &r.report;
    let plots = dir.join("plots");
    let plots = (plots.as_path(), "plots");
    embed_chart(
        page,
        &ErrorPerPass { report: rep },
        plots,
        "error_per_pass",
        "Convergence: the frames' relative amplitude error after each pass (each tile thin, the mean bold).",
    );
    embed_chart(
        page,
        &Pupil {
            pupil: &r.pupil,
            system: c.system,
        },
        plots,
        "pupil",
        "The recovered pupil in NA units, with the objective's NA circle (green); phase white where the amplitude is under 5 %.",
    );
    let source = rep.geometry_source.to_string();
    embed_chart(
        page,
        &LedPositions {
            nominal: c.nominal,
            used: &rep.geometry,
            source: &source,
            system: c.system,
        },
        plots,
        "led_positions",
        "The LED positions the illumination wave vectors were computed from, against the nominal grid.",
    );
}

/// The parameters the run used: the array, the height, the frames' fit, the LEDs'
/// refinement, the optics, the tiling and the background.
fn parameter_rows(rep: &Report, s: &System) -> Vec<Row> {
    let g = &rep.geometry;
    vec![
        Row::new(
            "LED array",
            format!(
                "{}: Δx {:+.4} mm, Δy {:+.4} mm, θ {:+.4}°, h {:.3} mm",
                rep.geometry_source, g.dx_mm, g.dy_mm, g.theta_deg, g.height_mm
            ),
        ),
        Row::with_id(
            "height_from_boundary",
            "h from the bright/dark-field edge",
            height_from_boundary(rep),
        ),
        Row::with_id(
            "bright_field_fit",
            "Bright-field frames against the result",
            bright_field_fit(rep),
        ),
        Row::with_id("refined_leds", "LEDs refined", refined_leds(rep)),
        Row::new(
            "optics",
            format!(
                "λ {:.3} µm, NA {:.3}, objective {:.1}×, camera pixel {:.2} µm",
                s.wavelength_um, s.na, s.magnification, s.pixel_size_um
            ),
        ),
        Row::new(
            "frames",
            format!(
                "{} in focus, {}×{} pixels",
                rep.frames, rep.frame_size[0], rep.frame_size[1]
            ),
        ),
        Row::new("passes", rep.passes.to_string()),
        Row::new(
            "tiles",
            format!(
                "{} of {} px, overlap {} px, free border {} px, unblended border {} px",
                rep.tiles.len(),
                rep.tile_size,
                rep.tile_overlap,
                rep.tile_free_border,
                rep.tile_unblended_border
            ),
        ),
        Row::new("background", background(rep)),
        Row::new("background phase", background_phase(&rep.background_phase)),
        Row::new("disc placement", rep.disc_placement),
    ]
}

/// The height the bright/dark-field edges give, against the geometry's.
fn height_from_boundary(rep: &Report) -> String {
    match &rep.height_from_boundary {
        Some(b) => format!(
            "{:.2} ± {:.2} mm from the edges, ± {:.2} mm with the NA's {:.0} % ({} frames decide it, {} partly bright; {:+.1}σ from the geometry's {:.2} mm)",
            b.estimate.height_mm,
            b.estimate.sigma_mm,
            b.sigma_with_na_mm,
            b.na_relative_sigma * 100.0,
            b.estimate.deciding_frames,
            b.estimate.partly_bright,
            b.difference_sigma,
            b.geometry_height_mm
        ) + &rep
            .height_choice
            .map(|c| format!("; {c}"))
            .unwrap_or_default(),
        None => "not bracketed by these frames".to_string(),
    }
}

/// How well the bright-field frames fit the result, and how they were decoded.
fn bright_field_fit(rep: &Report) -> String {
    match &rep.bright_field_fit {
        Some(f) => format!(
            "measured ≈ {:.3} × modelled + {:.1} % of their light as offset, correlation {:.3} ({} frames over tiles){}",
            f.gain,
            100.0 * f.offset_share,
            f.correlation,
            f.frames,
            match (rep.camera_gamma, &rep.camera_gamma_scan) {
                (Some(g), Some(_)) => format!("; frames decoded with gamma {g}, read from them"),
                (None, Some(_)) => "; frames read as linear, as their scan found".to_string(),
                (Some(1.0), None) => "; frames linear, as the dataset states".to_string(),
                (Some(g), None) => format!("; frames decoded with the dataset's gamma {g}"),
                (None, None) => String::new(),
            }
        ),
        None => "no bright-field frame".to_string(),
    }
}

/// What the LEDs' refinement moved, and the board fitted to them.
fn refined_leds(rep: &Report) -> String {
    match &rep.refined_leds {
        Some(r) => {
            let board = r.board.map_or("no board could be fitted".to_string(), |b| {
                format!("board fitted to them: {}", b.summary())
            });
            let scatter = r.led_scatter_mm.map_or(String::new(), |t| {
                format!("; LEDs off the board model by {t:.3} mm (1σ, from the data)")
            });
            format!(
                "moved {:.3} mm RMS ({:.2} mm of LED travel per frequency bin){scatter}; {board}",
                r.moved_rms_mm, r.bin_mm
            )
        }
        None => "no (--refine-leds)".to_string(),
    }
}

/// The frames' background correction.
fn background(rep: &Report) -> String {
    match rep.background.floor_sigma {
        Some(f) => format!(
            "{}, floor {f}σ, noise band {}σ; {} of {} dark-field frames' backgrounds taken off",
            rep.background.correction,
            rep.background.noise_band_sigma.unwrap_or(0.0),
            rep.background
                .dark_field_frames
                .iter()
                .filter(|f| f.taken_off)
                .count(),
            rep.background.dark_field_frames.len()
        ),
        None => rep.background.correction.to_string(),
    }
}

/// The output files the run wrote (the object in whichever format it chose).
fn output_files(dir: &Path) -> Vec<(String, String)> {
    let object_files = [
        (
            "amplitude.tif",
            "amplitude, float32 OME-TIFF (pixel size in µm)",
        ),
        ("phase.tif", "phase in radians, float32 OME-TIFF"),
        (
            fpm_host::reconstruction::ZARR_NAME,
            "amplitude and phase, OME-Zarr pyramid (napari)",
        ),
    ];
    let mut files: Vec<(String, String)> = object_files
        .iter()
        .filter(|(name, _)| dir.join(name).exists())
        .map(|(name, what)| (name.to_string(), what.to_string()))
        .collect();
    files.extend([
        (
            "pupil_amplitude.tif".into(),
            "recovered pupil amplitude, float32 TIFF".into(),
        ),
        (
            "pupil_phase.tif".into(),
            "recovered pupil phase, float32 TIFF".into(),
        ),
        (
            "report.json".into(),
            "everything on this page, machine-readable".into(),
        ),
        ("plots/".into(), "the charts as PNG and SVG".into()),
    ]);
    files
}

/// The "background phase" row (and `fpm reconstruct`'s line): kept, or what the
/// flattening took off.
pub fn background_phase(b: &fpm_host::reconstruction::BackgroundPhaseReport) -> String {
    match b.block_um {
        None => "kept as EPRY left it (--flatten-background takes the clear glass's low-order phase off)".into(),
        Some(block) if b.totals.fitted == 0 => format!(
            "kept: too little clear background in any {block:.0} µm block to fit"
        ),
        Some(block) => format!(
            "flattened over {block:.0} µm blocks: {} of {} fitted ({:.0} % of their pixels at the clear amplitude), up to {:.2} rad taken off, background {:.3} rad RMS about the fit",
            b.totals.fitted,
            b.totals.blocks,
            100.0 * b.totals.clear_fraction,
            b.totals.peak_rad,
            b.totals.residual_rad
        ),
    }
}
