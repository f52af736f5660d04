//! The DPC run's `report.html`: the phase and absorption, the patterns, the warnings,
//! the score against a simulation's truth, and how to run it again.

use std::path::{Path, PathBuf};

use anyhow::Result;
use fpm_host::dpc::DpcReport;

use crate::html::{Page, Row};

/// What the page is written from.
pub struct Context<'a> {
    /// The result.
    pub report: &'a DpcReport,
    /// The dataset.
    pub dataset: &'a str,
    /// The phase and absorption previews (PNG files), if written.
    pub previews: Vec<(std::path::PathBuf, &'static str)>,
    /// The command that reproduces the run.
    pub reproduce: &'a str,
    /// The result files, relative to the page, with what each is.
    pub outputs: Vec<(String, String)>,
}

/// A DPC run's extras beside its images in `out`: the phase and absorption previews
/// (PNG, with a scale and colour bar) and `report.html`; `dataset` names the data
/// on the page. Each is an extra: a failure is a warning, never the run's. Returns the
/// page's path.
pub fn write_extras(result: &fpm_host::dpc::DpcResult, dataset: &Path, out: &Path) -> PathBuf {
    let r = &result.report;
    let span = |img: &fpm_physics::Image| {
        let m = img.iter().fold(0.0f32, |m, v| m.max(v.abs())).max(1e-6);
        (-m, m)
    };
    for (name, img, unit) in [
        ("phase.png", &result.object.phase, "rad"),
        ("absorption.png", &result.object.absorption, ""),
    ] {
        if let Err(e) = crate::preview::write_png_preview_with_bar(
            &out.join(name),
            img,
            span(img),
            Some(r.pixel_um),
            unit,
        ) {
            tracing::warn!("{name} not written: {e:#}");
        }
    }
    let page = out.join("report.html");
    let outputs = [
        ("phase.tif", "the phase, radians (OME-TIFF)"),
        ("absorption.tif", "the absorption μ (OME-TIFF)"),
        ("dpc.json", "this report, machine-readable"),
    ]
    .map(|(f, what)| (f.to_string(), what.to_string()))
    .to_vec();
    let context = Context {
        report: r,
        dataset: &dataset.display().to_string(),
        previews: vec![
            (out.join("phase.png"), "phase (radians)"),
            (out.join("absorption.png"), "absorption"),
        ],
        reproduce: &crate::html::command_line(),
        outputs,
    };
    if let Err(e) = write(&context, &page) {
        tracing::warn!("{} not written: {e:#}", page.display());
    }
    page
}

/// Write the page to `path`.
pub fn write(c: &Context<'_>, path: &Path) -> Result<()> {
    let r = c.report;
    let mut page = Page::new("fpm dpc: phase of a weak object from four half-circle patterns");
    page.paragraph(&format!(
        "Dataset {}: its in-focus bright-field frames summed by half of the pupil, as the patterns would light them.",
        c.dataset
    ));
    page.heading("Warnings");
    page.warnings(&r.warnings);
    page.heading("Images");
    let figures: Vec<(Vec<u8>, &str)> = c
        .previews
        .iter()
        .filter_map(|(file, caption)| std::fs::read(file).ok().map(|png| (png, *caption)))
        .collect();
    let refs: Vec<(&[u8], &str, &str)> = figures
        .iter()
        .map(|(png, caption)| (png.as_slice(), *caption, *caption))
        .collect();
    page.figures_scaled(&refs);
    page.heading("Patterns");
    let rows: Vec<Vec<String>> = r
        .halves
        .iter()
        .map(|h| {
            let leds: Vec<String> = h.leds.iter().map(|l| l.to_string()).collect();
            vec![
                h.half.to_string(),
                h.leds.len().to_string(),
                format!("{:.3}", h.contrast_rms),
                leds.join(" "),
            ]
        })
        .collect();
    page.grid(&["half", "LEDs", "RMS contrast", "LEDs (row, col)"], &rows);
    page.heading("Parameters");
    let mut table = vec![
        Row::new(
            "Tikhonov weights",
            format!(
                "absorption {}, phase {}",
                r.regularisation[0], r.regularisation[1]
            ),
        ),
        Row::new("pixel", format!("{:.4} µm in the sample plane", r.pixel_um)),
        Row::new(
            "resolution",
            format!("up to 2·NA/λ = {:.3} cycles/µm", r.max_frequency),
        ),
    ];
    if let Some(s) = r.versus_truth {
        table.push(Row::with_id(
            "versus_truth",
            "versus the simulation's truth",
            format!(
                "phase NRMSE {:.3} with the slow phase fitted out, {:.3} without ({:.4} rad), both low-passed to 2·NA/λ",
                s.detail_nrmse, s.phase_nrmse, s.phase_rmse_rad
            ),
        ));
    }
    page.table(&table);
    page.heading("Outputs");
    page.files(&c.outputs);
    page.heading("Reproduce");
    page.command(c.reproduce);
    page.write(path)
}
