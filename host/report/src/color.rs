//! A colour reconstruction's `report.html`: the sRGB preview, each channel's
//! wavelength, shift, white point and score with a link to its own report, and the
//! warnings.

use std::path::{Path, PathBuf};

use anyhow::Result;
use fpm_host::color::{ColorReport, PREVIEW_NAME};

use crate::html::{Page, Row};

/// Write `out/report.html` for `report` (its files already in `out`); `reproduce` is
/// the command that makes it again.
pub fn write_page(report: &ColorReport, out: &Path, reproduce: &str) -> Result<PathBuf> {
    let mut page = Page::new("fpm reconstruct: colour");
    page.paragraph(&format!(
        "Dataset {}: each colour reconstructed with its own wavelength, LEDs and pupil, then registered to {}.",
        report.dataset, report.reference
    ));
    page.heading("Warnings");
    page.warnings(&report.all_warnings());
    page.heading("Image");
    let png = std::fs::read(out.join(PREVIEW_NAME))?;
    page.figures_scaled(&[(
        png.as_slice(),
        "sRGB preview",
        "sRGB preview: each channel's |t|², white-balanced on its clear background",
    )]);
    page.heading("Channels");
    channels(&mut page, report);
    page.table(&[
        Row::new("LED placement", report.geometry.clone()),
        Row::new(
            "pixel",
            format!("{:.4} µm in the sample plane", report.pixel_um),
        ),
    ]);
    page.heading("Outputs");
    page.files(&output_files(report));
    page.heading("Reproduce");
    page.command(reproduce);
    let path = out.join("report.html");
    page.write(&path)?;
    Ok(path)
}

/// A row per channel: its wavelength, LEDs, registration, clear level and errors.
fn channels(page: &mut Page, report: &ColorReport) {
    let rows: Vec<Vec<String>> = report
        .channels
        .iter()
        .map(|c| {
            vec![
                c.name.clone(),
                format!("{:.1} nm", c.wavelength_um * 1e3),
                format!(
                    "Δx {:+.3} mm, Δy {:+.3} mm, θ {:.2}°, h {:.2} mm",
                    c.geometry.dx_mm, c.geometry.dy_mm, c.geometry.theta_deg, c.geometry.height_mm
                ),
                c.shift_um
                    .map_or("—".into(), |[x, y]| format!("({x:+.2}, {y:+.2}) µm")),
                format!("{:.3}", c.clear_level),
                c.final_error.map_or("—".into(), |e| format!("{e:.4}")),
                c.versus_truth
                    .map_or("—".into(), |s| format!("{:.3}", s.complex_nrmse)),
            ]
        })
        .collect();
    page.grid(
        &[
            "channel",
            "wavelength",
            "LEDs",
            "shift to reference",
            "clear |t|²",
            "frames' error",
            "complex NRMSE vs truth",
        ],
        &rows,
    );
}

/// The colour images, the preview, the report and each channel's own outputs.
fn output_files(report: &ColorReport) -> Vec<(String, String)> {
    let mut files: Vec<(String, String)> = vec![
        (
            "amplitude.tif".into(),
            "amplitude, one OME-TIFF channel per wavelength, registered".into(),
        ),
        (
            "phase.tif".into(),
            "phase (radians), one channel per wavelength, registered".into(),
        ),
        (PREVIEW_NAME.into(), "sRGB preview".into()),
        ("report.json".into(), "this report's numbers".into()),
    ];
    files.extend(report.channels.iter().map(|c| {
        (
            format!("{}/report.html", c.output),
            format!("{}: its own reconstruction, pupil and report", c.name),
        )
    }));
    files
}

/// Write a colour run into `out` for people: each channel's own outputs, previews and
/// page in `out/<name>/` (as `fpm reconstruct` of its dataset writes them), the colour
/// images, preview and report.json, and this page. The page is an extra: its error is
/// returned beside, never fails the write.
pub fn write(
    run: &fpm_host::color::ColorRun,
    out: &Path,
    output: fpm_host::reconstruction::OutputOptions,
    reproduce: &str,
) -> Result<Result<PathBuf>> {
    for c in &run.channels {
        let written =
            crate::reconstruction::write(&c.finished, &out.join(&c.name), output, reproduce)?;
        if let Err(e) = &written.page {
            tracing::warn!("no HTML report for channel {}: {e:#}", c.name);
        }
    }
    fpm_host::color::write_outputs(run, out, output)?;
    let page = write_page(&run.report, out, reproduce);
    if let Err(e) = &page {
        tracing::warn!("no HTML report: {e:#}");
    }
    Ok(page)
}
