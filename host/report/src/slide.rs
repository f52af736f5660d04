//! A stitched scan's `report.html`: the slide's preview (amplitude and phase), how
//! each field was placed against where the stage put it, every registered overlap,
//! the score against a simulation's hidden slide, and the warnings.

use std::path::{Path, PathBuf};

use anyhow::Result;
use fpm_host::scan::{StitchEvent, StitchOptions, StitchReport, Stitched};

use crate::html::{Page, Row};

/// Join the scan in `dir` into `out` ([`fpm_host::scan::stitch`]) for people: the
/// mosaic, stitch.json, and [`write_page`] beside them. The page is an extra: its error
/// is returned beside, never fails the stitch.
pub fn stitch(
    dir: &Path,
    options: &StitchOptions,
    out: &Path,
    reproduce: &str,
    on: &mut dyn FnMut(StitchEvent),
) -> Result<(Stitched, Result<PathBuf>)> {
    let stitched = fpm_host::scan::stitch(dir, options, out, on)?;
    let page = write_page(&stitched, out, reproduce);
    if let Err(e) = &page {
        tracing::warn!("no HTML report for the mosaic: {e:#}");
    }
    Ok((stitched, page))
}

/// Write the mosaic's previews (`amplitude.png`, `phase.png`, from its smallest
/// pyramid level of at most 2048 px a side) and `report.html` into `out` (beside
/// `mosaic.zarr` and `stitch.json`); `reproduce` is the command that makes it again.
/// One section after another.
pub fn write_page(stitched: &Stitched, out: &Path, reproduce: &str) -> Result<PathBuf> {
    let r = &stitched.report;
    let p = &stitched.preview;
    let (amplitude_png, phase_png) = previews(stitched, out)?;

    let mut page = Page::new("fpm stitch: one slide image");
    page.paragraph(&format!(
        "Scan {}: {} fields registered on their overlaps and placed by least squares with the stage's positions as the prior, blended into one image of {} × {} px at {:.3} µm ({:.2} × {:.2} mm).",
        r.scan,
        r.fields.len(),
        r.canvas.width,
        r.canvas.height,
        r.canvas.pitch_um,
        r.canvas.width as f64 * r.canvas.pitch_um / 1e3,
        r.canvas.height as f64 * r.canvas.pitch_um / 1e3,
    ));
    page.heading("Warnings");
    page.warnings(&r.warnings);
    page.heading("Slide");
    let scale = (p.pixel_um / r.canvas.pitch_um).round();
    let caption = |what: &str| {
        if scale > 1.0 {
            format!("{what}, the pyramid level {scale:.0}× smaller than the mosaic (open mosaic.zarr for every pixel)")
        } else {
            what.to_string()
        }
    };
    page.figures(&[
        (amplitude_png.as_slice(), "amplitude", &caption("amplitude")),
        (phase_png.as_slice(), "phase", &caption("phase (radians)")),
    ]);
    page.table(&summary_rows(r));
    page.heading("Fields");
    fields(&mut page, r);
    page.heading("Overlaps");
    overlaps(&mut page, r);
    page.heading("Outputs");
    page.files(&[
        (
            "mosaic.zarr".into(),
            "OME-Zarr: amplitude and phase (radians), a pyramid, in the slide's µm".into(),
        ),
        ("stitch.json".into(), "this report's numbers".into()),
        ("amplitude.png".into(), "amplitude preview".into()),
        ("phase.png".into(), "phase preview".into()),
    ]);
    page.heading("Reproduce");
    page.command(reproduce);
    let path = out.join("report.html");
    page.write(&path)?;
    Ok(path)
}

/// The amplitude and phase previews as PNG bytes, written into `out` too.
fn previews(stitched: &Stitched, out: &Path) -> Result<(Vec<u8>, Vec<u8>)> {
    let p = &stitched.preview;
    // Where no field reached: black in the amplitude, −π in the phase.
    let amplitude = p.amplitude.mapv(|a| if a.is_finite() { a } else { 0.0 });
    let phase = p.object.mapv(|z| {
        if z.re.is_finite() && z.im.is_finite() {
            z.arg()
        } else {
            -std::f32::consts::PI
        }
    });
    let amplitude_png = crate::preview::amplitude_png_bytes(&amplitude, p.pixel_um)?;
    let phase_png = crate::preview::phase_png_bytes(&phase, p.pixel_um)?;
    std::fs::write(out.join("amplitude.png"), &amplitude_png)?;
    std::fs::write(out.join("phase.png"), &phase_png)?;
    Ok((amplitude_png, phase_png))
}

/// How well the fields fit together, and against the hidden slide for a simulation.
fn summary_rows(r: &StitchReport) -> Vec<Row> {
    let used = r.pairs.iter().filter(|p| p.used).count();
    let moved = r
        .fields
        .iter()
        .map(|f| f.correction_um[0].hypot(f.correction_um[1]))
        .fold(0.0, f64::max);
    let mut rows = vec![
        Row::with_id(
            "pairs-used",
            "overlaps registered",
            format!("{used} of {}", r.pairs.len()),
        ),
        Row::with_id(
            "residual",
            "pairs' disagreement with the layout",
            format!("{:.2} µm rms", r.residual_rms_um),
        ),
        Row::new(
            "largest correction to the stage",
            format!(
                "{moved:.1} µm (the stage's σ taken as {:.1} µm)",
                r.settings.stage_sigma_um
            ),
        ),
    ];
    if let Some(t) = &r.versus_truth {
        rows.extend([
            Row::with_id(
                "mosaic-nrmse",
                "complex NRMSE against the hidden slide",
                format!(
                    "{:.3} (the fields' own {:.3}: {:.2}×)",
                    t.complex_nrmse, t.fields_complex_nrmse, t.ratio
                ),
            ),
            Row::with_id(
                "position-error",
                "fields placed within",
                format!(
                    "{:.2} µm (rms {:.2}; the stage alone {:.1} µm rms)",
                    t.max_position_error_um, t.rms_position_error_um, t.rms_stage_error_um
                ),
            ),
            Row::new(
                "phase step across seams",
                format!(
                    "{:.3} rad rms (across a field's middle: {:.3})",
                    t.seam_step_rad, t.within_step_rad
                ),
            ),
        ]);
    }
    rows
}

/// A row per field: where the stage put it, where it was placed.
fn fields(page: &mut Page, r: &StitchReport) {
    let fields: Vec<Vec<String>> = r
        .fields
        .iter()
        .map(|f| {
            vec![
                f.dataset.clone(),
                format!("({:.1}, {:.1})", f.stage_um[0], f.stage_um[1]),
                format!("({:.2}, {:.2})", f.placed_um[0], f.placed_um[1]),
                format!("({:+.2}, {:+.2})", f.correction_um[0], f.correction_um[1]),
                f.versus_truth
                    .map_or("—".into(), |s| format!("{:.3}", s.complex_nrmse)),
            ]
        })
        .collect();
    page.grid(
        &[
            "field",
            "stage (x, y) µm",
            "placed (x, y) µm",
            "correction µm",
            "complex NRMSE vs truth",
        ],
        &fields,
    );
}

/// A row per overlap: what its registration measured, and whether it was used.
fn overlaps(page: &mut Page, r: &StitchReport) {
    let name = |k: usize| r.fields.get(k).map_or("?".into(), |f| f.dataset.clone());
    let pairs: Vec<Vec<String>> = r
        .pairs
        .iter()
        .map(|p| {
            vec![
                format!("{} – {}", name(p.a), name(p.b)),
                format!(
                    "({:+.2}, {:+.2})",
                    p.offset_um.0 - p.stage_offset_um.0,
                    p.offset_um.1 - p.stage_offset_um.1
                ),
                format!("{:.3}", p.peak),
                format!("{:.2}", p.runner_up),
                format!("{:.2}", p.overlap_fraction),
                if p.used { "yes" } else { "no" }.into(),
            ]
        })
        .collect();
    page.grid(
        &[
            "fields",
            "measured − stage offset µm",
            "correlation",
            "runner-up",
            "overlap matched",
            "used",
        ],
        &pairs,
    );
}
