//! `calibration.html`: the calibrated array with its uncertainties, the warnings, the
//! residual and array charts, every LED's fate, and how to run it again.

use std::path::Path;

use anyhow::Result;
use fpm_physics::System;

use super::{embed_chart, pm};
use crate::charts::calibration::{status_label, LedGrid, Residuals};
use crate::html::{Page, Row};
use fpm_host::calibration::{warnings, CalibrationFile};

/// What the page is written from.
pub struct Context<'a> {
    /// The result.
    pub file: &'a CalibrationFile,
    /// The dataset's optics.
    pub system: &'a System,
    /// Whether the first-moment bias correction was applied.
    pub bias_correction: bool,
    /// The command that reproduces the run.
    pub reproduce: &'a str,
    /// The result files, relative to the page, with what each is.
    pub outputs: Vec<(String, String)>,
}

/// Write the page to `path` (its charts into `plots/` beside it, as `calibration_*`):
/// one section after another.
pub fn write(c: &Context<'_>, path: &Path) -> Result<()> {
    let cal = &c.file.calibration;
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut page = Page::new("fpm calibrate: LED array position (pdcFPM)");
    page.paragraph(&format!("Dataset {}.", c.file.dataset));

    page.heading("Result (1σ)");
    page.table(&result_rows(c));
    if let Some(b) = &cal.uncertainty_sources {
        uncertainty_sources(&mut page, b, &cal.uncertainty);
    }
    page.heading("Warnings");
    page.warnings(&warnings(cal));

    page.heading("Parameters");
    page.table(&parameter_rows(c));

    page.heading("Charts");
    charts(&mut page, c, dir);

    page.heading("Every defocused frame");
    every_frame(&mut page, cal);

    page.heading("Outputs");
    page.files(&c.outputs);
    page.heading("Reproduce");
    page.command(c.reproduce);
    page.write(path)
}

/// The fitted array with its uncertainties, the residual, the feature and the time.
fn result_rows(c: &Context<'_>) -> Vec<Row> {
    let cal = &c.file.calibration;
    let u = &cal.uncertainty;
    vec![
        Row::with_id("dx_mm", "Δx", pm(cal.placement.dx_mm, u.dx_mm, 4, "mm")),
        Row::with_id("dy_mm", "Δy", pm(cal.placement.dy_mm, u.dy_mm, 4, "mm")),
        Row::with_id("theta_deg", "θ", pm(cal.placement.theta_deg, u.theta_deg, 4, "°")),
        Row::with_id(
            "height_mm",
            "h",
            format!(
                "{:.3} ± {:.3} mm (with the defocus known to ±{} µm; h moves {:.4} mm per µm of defocus error)",
                cal.placement.height_mm, u.height_mm, cal.defocus_sigma_um, cal.height_per_defocus_um
            ),
        ),
        Row::with_id(
            "tilt_deg",
            "tilt",
            if cal.tilt_observable {
                format!(
                    "{} about x, {} about y",
                    pm(cal.placement.tilt_x_deg, u.tilt_x_deg, 2, "°"),
                    pm(cal.placement.tilt_y_deg, u.tilt_y_deg, 2, "°")
                )
            } else {
                format!(
                    "not observable (1σ {:.2}° / {:.2}°): the board was taken as flat",
                    u.tilt_x_deg, u.tilt_y_deg
                )
            },
        ),
        Row::with_id(
            "rms_residual_um",
            "rms residual",
            format!("{:.4} µm per component", cal.rms_residual_um),
        ),
        Row::new(
            "feature",
            format!(
                "at ({:.1}, {:.1}) µm, pixel ({:.1}, {:.1}), {} px, {:?}",
                cal.feature.x_um,
                cal.feature.y_um,
                cal.feature.pixel[0],
                cal.feature.pixel[1],
                cal.feature.area_px,
                cal.feature.polarity
            ),
        ),
        Row::new("time", format!("{:.1} ms (frames in memory)", c.file.time_ms)),
    ]
}

/// What the uncertainty `u` is made of, source by source.
fn uncertainty_sources(
    page: &mut Page,
    b: &fpm_physics::calibrate::uncertainty::Budget,
    u: &fpm_physics::calibrate::Uncertainty,
) {
    page.paragraph("What the uncertainty is made of (1σ each, added in quadrature):");
    let row = |name: &str, u: &fpm_physics::calibrate::Uncertainty| {
        vec![
            name.to_string(),
            format!("{:.4}", u.dx_mm),
            format!("{:.4}", u.dy_mm),
            format!("{:.4}", u.theta_deg),
            format!("{:.4}", u.height_mm),
        ]
    };
    page.grid(
        &["source", "Δx (mm)", "Δy (mm)", "θ (°)", "h (mm)"],
        &[
            row(
                "fit spread (residuals, jackknife, pixel noise)",
                &b.statistical,
            ),
            row("reference frame's pixel noise", &b.reference_frame),
            row("model bias correction", &b.model_bias),
            row("defocus", &b.defocus),
            row(
                "board tilt (fitted, or unseen)",
                &b.tilt.unwrap_or_default(),
            ),
            row("total", u),
        ],
    );
}

/// The defocus, the optics, the nominal array and the bias correction used.
fn parameter_rows(c: &Context<'_>) -> Vec<Row> {
    let cal = &c.file.calibration;
    let s = c.system;
    let n = &c.file.nominal;
    vec![
        Row::new("defocus", format!("{:+.1} µm", cal.defocus_um)),
        Row::new("defocused frames", cal.leds.len().to_string()),
        Row::new(
            "optics",
            format!(
                "λ {:.3} µm, NA {:.3}, objective {:.1}×, camera pixel {:.2} µm ({:.3} µm at the sample)",
                s.wavelength_um,
                s.na,
                s.magnification,
                s.pixel_size_um,
                s.sample_pixel_um()
            ),
        ),
        Row::new(
            "nominal array",
            format!(
                "{}×{} LEDs, pitch {:.3} mm, centre LED ({}, {}), h {:.2} mm",
                n.rows, n.cols, n.pitch_mm, n.center.row, n.center.col, n.height_mm
            ),
        ),
        Row::new(
            "bias correction",
            if c.bias_correction {
                "model-based first-moment bias subtracted"
            } else {
                "off (--no-bias-correction)"
            },
        ),
    ]
}

/// The residuals and the fitted array, as charts in `dir/plots/`.
fn charts(page: &mut Page, c: &Context<'_>, dir: &Path) {
    let cal = &c.file.calibration;
    let (s, n) = (c.system, &c.file.nominal);
    let plots = (dir.join("plots"), "plots");
    let plots = (plots.0.as_path(), plots.1);
    embed_chart(
        page,
        &Residuals { cal, system: s },
        plots,
        "calibration_residuals",
        "How the feature moved under each LED (crosses, bias-corrected) against the fitted model (circles); residuals magnified.",
    );
    embed_chart(
        page,
        &LedGrid {
            cal,
            nominal: n,
            system: s,
        },
        plots,
        "calibration_array",
        "The fitted LED array against the nominal grid in the illumination plane; the calibration's LEDs marked by what became of them.",
    );
}

/// A row per defocused frame: its LED, its fate, its shifts and residual.
fn every_frame(page: &mut Page, cal: &fpm_physics::calibrate::Calibration) {
    let rows: Vec<Vec<String>> = cal
        .leds
        .iter()
        .map(|l| {
            let pair = |v: Option<[f64; 2]>| {
                v.map(|[x, y]| format!("({x:+.2}, {y:+.2})"))
                    .unwrap_or_else(|| "—".into())
            };
            vec![
                format!("({}, {})", l.led.row, l.led.col),
                status_label(l.status).to_string(),
                format!("{:.3}", l.brightness),
                pair(l.measured_um),
                pair(Some(l.fitted_um)),
                l.residual_um
                    .map(|r| format!("{r:.3}"))
                    .unwrap_or_else(|| "—".into()),
                match (l.offset_mm, l.offset_sigma_mm) {
                    (Some([x, y]), Some(s)) => format!("({x:+.3}, {y:+.3}) ± {s:.3}"),
                    _ => "—".into(),
                },
            ]
        })
        .collect();
    page.grid(
        &[
            "LED (row, col)",
            "status",
            "brightness vs reference",
            "measured shift (µm)",
            "fitted shift (µm)",
            "residual (µm)",
            "LED off the fitted board (mm)",
        ],
        &rows,
    );
}
