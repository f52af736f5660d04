//! The acquisition's HTML reports: `acquisition.html` beside `acquisition.json`, and
//! the calibration's and reconstruction's pages beside theirs. Reports are extras: a
//! failure to write one is logged, never fails the acquisition.

use std::path::Path;

use fpm_host::calibration::CalibrationFile;
use fpm_host::reconstruction::Reconstruction;
use fpm_physics::calibrate::Options;
use fpm_physics::{LedGeometry, System};
use fpm_report::charts::acquisition::Coverage;
use fpm_report::html::{command_line, Page, Row};
use fpm_report::pages::{self, embed_chart};

use crate::summary::AcquireSummary;

/// `out/calibration.html` for the calibration the acquisition ran.
pub fn calibration(cal: &CalibrationFile, system: &System, options: &Options, out: &Path) {
    let context = pages::calibration::Context {
        file: cal,
        system,
        bias_correction: options.bias_correction,
        reproduce: &format!(
            "fpm calibrate {} --out {}",
            fpm_report::html::shell_quote(&out.join("calibration").to_string_lossy()),
            fpm_report::html::shell_quote(&out.join("calibration.json").to_string_lossy())
        ),
        outputs: vec![
            (
                "calibration.json".into(),
                "the calibration, machine-readable".into(),
            ),
            (
                "calibration/".into(),
                "the calibration frames (a dataset)".into(),
            ),
        ],
    };
    if let Err(e) = pages::calibration::write(&context, &out.join("calibration.html")) {
        tracing::warn!("no calibration report: {e:#}");
    }
}

/// `out/reconstruction/report.html` for the streamed reconstruction.
pub fn reconstruction(r: &Reconstruction, system: &System, nominal: &LedGeometry, out: &Path) {
    let offline = format!(
        "{}\n# the same frames offline:\nfpm reconstruct {} --calibration {} --out rec",
        command_line(),
        fpm_report::html::shell_quote(&out.to_string_lossy()),
        fpm_report::html::shell_quote(&out.join("calibration.json").to_string_lossy())
    );
    let context = pages::reconstruction::Context {
        system,
        nominal,
        reproduce: &offline,
    };
    if let Err(e) = pages::reconstruction::write(r, &out.join("reconstruction"), &context) {
        tracing::warn!("no reconstruction report: {e:#}");
    }
}

/// What a user must know about the acquisition `s` (`failure`: why the run failed).
pub fn warnings(s: &AcquireSummary, failure: Option<&str>) -> Vec<String> {
    let mut out: Vec<String> = failure.map(str::to_string).into_iter().collect();
    if !s.still_missing.is_empty() {
        out.push(format!(
            "{} LED(s) have no frame in the dataset: {:?}",
            s.still_missing.len(),
            s.still_missing
                .iter()
                .map(|l| (l.row, l.col))
                .collect::<Vec<_>>()
        ));
    }
    if s.geometry_source.is_nominal() {
        out.push(
            "the LED positions are nominal (no calibration given, none stored on the board): run with --calibrate"
                .into(),
        );
    }
    let relabelled = s.capture.relabelled + s.retake.as_ref().map_or(0, |r| r.relabelled);
    if relabelled > 0 {
        out.push(format!(
            "{relabelled} frame(s) changed label after streaming: the final image was rebuilt from the dataset"
        ));
    }
    if let Some(p) = &s.capture.clock_problem {
        out.push(format!("camera clock: {p}"));
    }
    match encoding_gamma(s.camera_settings.as_ref()) {
        Encoding::Gamma(g) => out.push(format!(
            "the camera encoded its frames with its gamma on (decoded with {g:.3}, as dataset.toml states): decoding undoes the curve but not its rounding of the dim dark-field light; set the camera's Gamma to 1 (or GammaEnable to false) for raw counts"
        )),
        Encoding::Lut => out.push(
            "the camera's lookup table is on (LUTEnable): its frames may not be linear in the light and the dataset cannot say how (`fpm reconstruct` reads a gamma from the frames); set LUTEnable to false for raw counts"
                .into(),
        ),
        Encoding::Linear | Encoding::Unreported => {}
    }
    out
}

/// How the camera's frames stand for light, as its driver reported (`encoding_gamma`
/// in its settings document).
enum Encoding {
    Linear,
    Gamma(f64),
    /// A lookup table is on: the driver cannot say.
    Lut,
    /// No settings document, or one without the field (an older publisher).
    Unreported,
}

fn encoding_gamma(settings: Option<&serde_json::Value>) -> Encoding {
    match settings.and_then(|s| s.get("encoding_gamma")) {
        None => Encoding::Unreported,
        Some(serde_json::Value::Null) => Encoding::Lut,
        Some(v) => match v.as_f64() {
            Some(g) if (g - 1.0).abs() <= 1e-6 => Encoding::Linear,
            // As `acquisition::camera_section` states it in dataset.toml.
            Some(g) if fpm_host::dataset::CameraSection::is_valid_gamma(g) => Encoding::Gamma(g),
            _ => Encoding::Unreported,
        },
    }
}

/// The "frames" row of the acquisition page.
fn encoding_row(settings: Option<&serde_json::Value>) -> String {
    match encoding_gamma(settings) {
        Encoding::Linear => "raw counts, linear in the light (the camera's gamma off; dataset.toml states gamma = 1)".into(),
        Encoding::Gamma(g) => format!("encoded by the camera's gamma; dataset.toml states gamma = {g:.3}, which `fpm reconstruct` decodes"),
        Encoding::Lut => "through the camera's lookup table: not stated in dataset.toml".into(),
        Encoding::Unreported => "not reported by the camera: dataset.toml states no gamma, and `fpm reconstruct` screens frames of more than 8 bits for one".into(),
    }
}

/// `out/acquisition.html`.
pub fn acquisition(s: &AcquireSummary, system: &System, failure: Option<&str>, out: &Path) {
    if let Err(e) = write_acquisition(s, system, failure, out) {
        tracing::warn!("no acquisition report: {e:#}");
    }
}

/// `out/acquisition.html`, one section after another.
fn write_acquisition(
    s: &AcquireSummary,
    system: &System,
    failure: Option<&str>,
    out: &Path,
) -> anyhow::Result<()> {
    let mut page = Page::new("fpm acquire: a labelled FPM dataset");
    page.paragraph(&format!("Output directory {}.", out.display()));
    page.heading("Result");
    page.table(&result_rows(s));
    page.heading("Warnings");
    page.warnings(&warnings(s, failure));

    let preview = out.join("reconstruction").join("amplitude.png");
    if let Ok(png) = std::fs::read(&preview) {
        page.heading("Reconstruction");
        page.figure(
            &png,
            "reconstructed amplitude",
            "Reconstructed amplitude (streamed while acquiring); the full report is reconstruction/report.html.",
            &["reconstruction/report.html"],
        );
    }
    page.heading("Charts");
    let plots = out.join("plots");
    embed_chart(
        &mut page,
        &Coverage {
            geometry: &s.geometry,
            missing: &s.still_missing,
            system,
        },
        (&plots, "plots"),
        "acquisition_coverage",
        "Every LED of the array at its position: filled where its frame is in the dataset.",
    );
    if !s.calibration.is_empty() {
        page.heading("Calibration captures");
        calibration_captures(&mut page, s);
    }
    if let Some(settings) = &s.camera_settings {
        page.heading("Camera settings (as its driver reported them)");
        page.command(&serde_json::to_string_pretty(settings)?);
    }
    page.heading("Outputs");
    page.files(&output_files(out));
    page.heading("Reproduce");
    page.command(&command_line());
    page.write(&out.join("acquisition.html"))
}

/// What the capture labelled, how fast, the camera's clock, the geometry used and the
/// streaming reconstruction.
fn result_rows(s: &AcquireSummary) -> Vec<Row> {
    let c = &s.capture;
    let mut rows = vec![
        Row::with_id(
            "labelled",
            "frames labelled with their LED",
            format!("{} of {} requested", c.labelled, c.requested),
        ),
        Row::new(
            "speed",
            format!("{:.1} s, {:.1} frames/s", c.seconds, c.frames_per_s),
        ),
        Row::with_id(
            "labelled_live",
            "labelled as they arrived",
            format!(
                "{} of the {} frames that arrived while the sequence ran ({} in all); arrival → label {:.0} ms median, {:.0} ms p99",
                c.labelled_live, c.arrived_live, c.labelled, c.label_lag_p50_ms, c.label_lag_p99_ms
            ),
        ),
        Row::with_id(
            "missing",
            "missing / extra / ambiguous",
            format!(
                "{} / {} / {}",
                c.missing.len(),
                c.extra_frames,
                c.ambiguous_frames
            ),
        ),
        Row::new(
            "camera clock",
            format!(
                "offset {} ns, drift {:+.2} ppm, stamp spread {:.3} ms",
                c.clock_offset_ns, c.clock_drift_ppm, c.stamp_spread_ms
            ),
        ),
        Row::new("frames in the dataset", s.frames_in_dataset.to_string()),
        Row::with_id(
            "encoding",
            "frames' encoding",
            encoding_row(s.camera_settings.as_ref()),
        ),
    ];
    if let Some(r) = &s.retake {
        rows.push(Row::new(
            "retake",
            format!(
                "{} of {} missing frame(s) taken again",
                r.labelled, r.requested
            ),
        ));
    }
    let g = &s.geometry;
    rows.push(Row::with_id(
        "geometry",
        "LED array used",
        format!(
            "{}: Δx {:+.4} mm, Δy {:+.4} mm, θ {:+.4}°, h {:.3} mm",
            s.geometry_source.short_name(),
            g.dx_mm,
            g.dy_mm,
            g.theta_deg,
            g.height_mm
        ),
    ));
    if let (Some(ms), Some(us)) = (s.last_frame_to_final_ms, s.update_us_mean) {
        rows.push(Row::new(
            "streaming reconstruction",
            format!(
                "{us:.0} µs per frame as it arrived, {} tile(s); last frame → final image {ms:.0} ms ({})",
                s.tiles.unwrap_or(1),
                s.reconstruction.unwrap_or("—")
            ),
        ));
    }
    rows
}

/// A row per calibration capture.
fn calibration_captures(page: &mut Page, s: &AcquireSummary) {
    let rows: Vec<Vec<String>> = s
        .calibration
        .iter()
        .map(|r| {
            vec![
                format!("{}/{}", r.labelled, r.requested),
                r.missing.len().to_string(),
                format!("{:.2}", r.seconds),
                r.outcome.clone(),
            ]
        })
        .collect();
    page.grid(&["labelled", "missing", "seconds", "sequence"], &rows);
}

/// The files the acquisition wrote (the calibration's and reconstruction's when made).
fn output_files(out: &Path) -> Vec<(String, String)> {
    let mut files = vec![
        (
            "dataset.toml".to_string(),
            "the dataset (frames/ beside it)".to_string(),
        ),
        (
            "acquisition.json".into(),
            "everything on this page, machine-readable".into(),
        ),
    ];
    for (path, what) in [
        ("calibration.html", "the calibration's report"),
        ("calibration.json", "the calibration"),
        ("reconstruction/report.html", "the reconstruction's report"),
    ] {
        if out.join(path).exists() {
            files.push((path.into(), what.into()));
        }
    }
    files
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_frames_encoding_follows_the_cameras_settings_document() {
        let of = |v: serde_json::Value| encoding_gamma(Some(&v));
        assert!(matches!(
            of(serde_json::json!({"encoding_gamma": 1.0})),
            Encoding::Linear
        ));
        assert!(
            matches!(of(serde_json::json!({"encoding_gamma": 2.2})), Encoding::Gamma(g) if g == 2.2)
        );
        assert!(matches!(
            of(serde_json::json!({"encoding_gamma": null})),
            Encoding::Lut
        ));
        assert!(matches!(
            of(serde_json::json!({"exposure_us": 10.0})),
            Encoding::Unreported
        ));
        // A gamma no dataset can state is not claimed as stated.
        assert!(matches!(
            of(serde_json::json!({"encoding_gamma": 9.0})),
            Encoding::Unreported
        ));
        assert!(matches!(encoding_gamma(None), Encoding::Unreported));
    }
}
