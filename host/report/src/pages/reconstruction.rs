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

/// What a user must know before trusting the images of `report`.
pub fn warnings(report: &Report) -> Vec<String> {
    let mut out = vec![];
    if report.geometry_source.is_nominal() {
        out.push(
            "the LED positions are the nominal ones, not calibrated: an array off by a fraction of a millimetre blurs and distorts the image (fpm calibrate, or --calibration)"
                .to_string(),
        );
    }
    if let (Some(first), Some(last)) = (report.error_per_pass.first(), report.error_per_pass.last())
    {
        // A rise within 5 % is the noise of the last pass, not a divergence.
        if *last > 1.05 * first {
            out.push(format!(
                "the frames' error rose over the passes ({first:.4} → {last:.4}): the geometry or the step sizes may be wrong"
            ));
        }
    }
    out.extend(report.refocus.warning());
    if let Some(r) = &report.refined_leds {
        out.extend(fpm_host::refinement::warnings(r));
    }
    if let Some(fit) = report.bright_field_fit.filter(|f| f.is_suspect()) {
        let floats = report.sample_bits == Some(32);
        let cause = match (report.camera_gamma, &report.camera_gamma_scan) {
            (_, Some(_)) => "stray light lifts the frames (the gamma read from them did not explain it)",
            (None, None) if floats => "stray light lifts the frames, or an offset was left in them when they were made floats (the dataset's dark_level takes a known one off); float frames carry no display gamma",
            (None, None) => "8-bit frames saved for viewing carry a display gamma (then reconstruct with --camera-gamma auto or 2.2, or set [camera] gamma = 2.2 and bit_depth in dataset.toml), or stray light lifts the frames",
            (Some(_), None) => "stray light lifts the frames, or the dataset's camera.gamma is not the camera's",
        };
        out.push(format!(
            "the bright-field frames hold {:.0} % of their light as an offset that no object explains (measured ≈ {:.2} × modelled + offset, correlation {:.3}): {cause}; the image will ring around edges",
            100.0 * fit.offset_share, fit.gain, fit.correlation
        ));
    }
    if let Some(scan) = report.camera_gamma_scan.as_ref().filter(|s| s.is_flat()) {
        out.push(format!(
            "the camera gamma read from the frames is weak: their error stays within {:.0} % of its least for every gamma from {:.1} to {:.1} (a sample with little contrast, or no dim dark-field light); state the camera's gamma if it is known",
            100.0 * fpm_physics::reconstruct::gamma::FLAT_WITHIN,
            scan.range.0,
            scan.range.1
        ));
    }
    if let Some(b) = report.height_from_boundary.filter(|b| b.disagrees()) {
        // A calibrated h is only as good as the defocus it was told; a dataset's h
        // may simply be wrong, and the edge's own estimate can stand in for it.
        let advice = if report.geometry_source.is_nominal() {
            format!(
                "the dataset's height_mm (or its NA) may be off: --led-height-mm {:.1} reconstructs with the edge's height",
                b.estimate.height_mm
            )
        } else {
            "check the defocus the calibration was told (h is proportional to it) and the NA"
                .to_string()
        };
        out.push(format!(
            "the bright/dark-field boundary puts the LEDs {:.2} ± {:.2} mm below the sample (the NA's {:.0} % included), the geometry {:.2} mm ({:+.1}σ): {advice}",
            b.estimate.height_mm, b.sigma_with_na_mm, b.na_relative_sigma * 100.0, b.geometry_height_mm, b.difference_sigma
        ));
    }
    if let Some(p) = report
        .height_from_boundary
        .and_then(|b| b.entrance_pupil)
        .filter(|p| p.fits_better(report.system.entrance_pupil_mm))
    {
        let (best, advice) = match p.entrance_pupil_mm {
            Some(mm) => (
                format!("an objective whose entrance pupil is {mm:.0} mm above the sample"),
                format!(
                    "if the objective is not telecentric (a camera lens, a simple low-power objective), reconstruct with --entrance-pupil-mm {mm:.0}{}",
                    if report.geometry_source.is_nominal() {
                        format!(" --led-height-mm {:.1}", p.height_mm)
                    } else {
                        String::new()
                    }
                ),
            ),
            None => (
                "a telecentric objective".to_string(),
                "leave --entrance-pupil-mm out".to_string(),
            ),
        };
        out.push(format!(
            "the frames' bright/dark-field edges fit {best} (h {:.1} mm) better than the system as given: {} blocks off against {}; {advice}",
            p.height_mm, p.mismatched_blocks, p.mismatched_blocks_as_given
        ));
    }
    let refused = report
        .background
        .dark_field_frames
        .iter()
        .filter(|f| !f.taken_off)
        .count();
    if refused * 2 > report.background.dark_field_frames.len().max(1) {
        out.push(format!(
            "{refused} of {} dark-field frames had a background that was not flat (sample light or structured stray light): it was left on",
            report.background.dark_field_frames.len()
        ));
    }
    let b = &report.background_phase;
    if b.block_um.is_some() && b.totals.fitted * 2 < b.totals.blocks {
        out.push(format!(
            "--flatten-background found clear background in only {} of {} blocks: elsewhere the slow phase is as EPRY left it (is the sample on clear glass? for one that fills the field, leave the flag off)",
            b.totals.fitted, b.totals.blocks
        ));
    }
    out
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
/// images `fpm_host::reconstruction::write_outputs` wrote into `dir`.
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
    if let Some(s) = &rep.versus_truth {
        rows.push(Row::with_id(
            "complex_nrmse",
            "against the simulation's truth: complex NRMSE",
            format!("{:.4}", s.complex_nrmse),
        ));
        rows.push(Row::new(
            "amplitude NRMSE / phase RMSE",
            format!("{:.4} / {:.4} rad", s.amplitude_nrmse, s.phase_rmse_rad),
        ));
    }
    page.table(&rows);
    page.heading("Warnings");
    page.warnings(&warnings(rep));

    page.heading("Charts");
    let plots = dir.join("plots");
    let plots = (plots.as_path(), "plots");
    embed_chart(
        &mut page,
        &ErrorPerPass { report: rep },
        plots,
        "error_per_pass",
        "Convergence: the frames' relative amplitude error after each pass (each tile thin, the mean bold).",
    );
    embed_chart(
        &mut page,
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
        &mut page,
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

    page.heading("Parameters");
    let g = &rep.geometry;
    let s = c.system;
    page.table(&[
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
                ),
                None => "not bracketed by these frames".to_string(),
            },
        ),
        Row::with_id(
            "bright_field_fit",
            "Bright-field frames against the result",
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
                        (Some(g), None) => format!("; frames decoded with the dataset's gamma {g}"),
                        (None, None) => String::new(),
                    }
                ),
                None => "no bright-field frame".to_string(),
            },
        ),
        Row::with_id(
            "refined_leds",
            "LEDs refined",
            match &rep.refined_leds {
                Some(r) => {
                    let board = r.board.map_or("no board could be fitted".to_string(), |b| {
                        format!("board fitted to them: {}", b.summary())
                    });
                    format!(
                        "moved {:.3} mm RMS ({:.2} mm of LED travel per frequency bin); {board}",
                        r.moved_rms_mm, r.bin_mm
                    )
                }
                None => "no (--refine-leds)".to_string(),
            },
        ),
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
        Row::new(
            "background",
            match rep.background.floor_sigma {
                Some(f) => format!(
                    "{}, floor {f}σ; {} of {} dark-field frames' backgrounds taken off",
                    rep.background.correction,
                    rep.background
                        .dark_field_frames
                        .iter()
                        .filter(|f| f.taken_off)
                        .count(),
                    rep.background.dark_field_frames.len()
                ),
                None => rep.background.correction.to_string(),
            },
        ),
        Row::new("background phase", background_phase(&rep.background_phase)),
        Row::new("disc placement", rep.disc_placement),
    ]);

    page.heading("Outputs");
    // The object is in whichever format the run wrote.
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
    page.files(&files);
    page.heading("Reproduce");
    page.command(c.reproduce);
    page.write(&dir.join("report.html"))
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
