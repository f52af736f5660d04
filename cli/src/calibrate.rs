//! `fpm calibrate DIR`: pdcFPM calibration of the LED array from a defocus dataset.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use fpm_physics::calibrate::feature::Roi;
use fpm_physics::calibrate::{LedStatus, Options};

use fpm_host::calibration::{calibrate_dataset, warnings};
use fpm_host::dataset::Dataset;
use fpm_report::charts::calibration::write_residual_plot;

/// Calibrate the LED array (Δx, Δy, θ, h) from how a defocused feature moves.
///
/// The dataset holds one in-focus frame under the nominal centre LED and frames of the
/// LEDs around it with the sample defocused by the same `defocus_um`.
#[derive(Args, Debug)]
pub struct CalibrateArgs {
    /// Dataset directory (with dataset.toml).
    dir: PathBuf,
    /// Where to write the result [default: DIR/calibration.json].
    #[arg(long)]
    out: Option<PathBuf>,
    /// Look for the feature only in this rectangle: X,Y,W,H in pixels.
    #[arg(long, value_parser = parse_roi)]
    roi: Option<Roi>,
    /// Also write the residual chart here (measured × vs fitted ○ shifts at the sample,
    /// residuals magnified; SVG for a `.svg` name, else PNG). The report
    /// (`calibration.html` beside the JSON) and `plots/` beside it always have it.
    #[arg(long)]
    plot: Option<PathBuf>,
    /// 1σ of the defocus as the stage set it, µm: h is proportional to the defocus, so
    /// its uncertainty carries this (a focus knob read to its finest graduation: ~1 µm).
    #[arg(long, default_value_t = fpm_physics::calibrate::DEFAULT_DEFOCUS_SIGMA_UM)]
    defocus_sigma_um: f64,
    /// Skip the model-based correction of the first-moment bias (for comparison).
    #[arg(long)]
    no_bias_correction: bool,
    /// Take the board as flat: do not fit its tilt about x and y (for comparison).
    #[arg(long)]
    no_tilt: bool,
    /// Print the result as JSON on stdout as well.
    #[arg(long)]
    json: bool,
}

fn parse_roi(s: &str) -> Result<Roi, String> {
    let v: Vec<usize> = s
        .split(',')
        .map(|p| {
            p.trim()
                .parse::<usize>()
                .map_err(|_| format!("'{p}' is not a pixel count"))
        })
        .collect::<Result<_, _>>()?;
    match v.as_slice() {
        [x, y, w, h] if *w > 0 && *h > 0 => Ok(Roi {
            x: *x,
            y: *y,
            w: *w,
            h: *h,
        }),
        _ => Err(format!(
            "'{s}' is not X,Y,W,H with a positive width and height"
        )),
    }
}

/// Run `fpm calibrate`.
pub fn run(a: CalibrateArgs) -> Result<()> {
    let options = Options {
        roi: a.roi,
        bias_correction: !a.no_bias_correction,
        defocus_sigma_um: a.defocus_sigma_um.abs(),
        fit_tilt: !a.no_tilt,
        ..Options::default()
    };
    if fpm_host::color::is_color(&a.dir) {
        return color(&a, &options);
    }
    let ds = Dataset::load(&a.dir)?;
    let file = calibrate_dataset(&ds, &options)?;
    let c = &file.calibration;
    let out = a.out.unwrap_or_else(|| a.dir.join("calibration.json"));
    std::fs::write(&out, serde_json::to_string_pretty(&file)?)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&file)?);
    } else {
        print_calibration(&file, a.no_tilt);
        println!("wrote {}", out.display());
    }
    if let Some(plot) = &a.plot {
        let gain = write_residual_plot(c, &ds.manifest.system(), plot)?;
        println!("wrote {} (residuals magnified {gain:.0}×)", plot.display());
    }
    for w in warnings(c) {
        eprintln!("warning: {w}");
    }
    // The report is an extra: failing to write it is a warning, not a failed run.
    let page = out.with_extension("html");
    match write_page(&file, &ds, &options, &out, a.plot.as_deref(), &page) {
        Ok(()) if !a.json => println!(
            "wrote {} (the report: open it in a browser)",
            page.display()
        ),
        Ok(()) => {}
        Err(e) => tracing::warn!("no HTML report: {e:#}"),
    }
    Ok(())
}

/// The calibration as text.
fn print_calibration(file: &fpm_host::calibration::CalibrationFile, no_tilt: bool) {
    let c = &file.calibration;
    let u = &c.uncertainty;
    println!(
        "LED array from {} frames at {} µm defocus ({:.1} ms):",
        c.leds.len(),
        c.defocus_um,
        file.time_ms
    );
    println!("  Δx = {:+.4} ± {:.4} mm", c.placement.dx_mm, u.dx_mm);
    println!("  Δy = {:+.4} ± {:.4} mm", c.placement.dy_mm, u.dy_mm);
    println!(
        "  θ  = {:+.4} ± {:.4} °",
        c.placement.theta_deg, u.theta_deg
    );
    println!(
        "  h  = {:.3} ± {:.3} mm  (with the defocus known to ±{} µm; h moves {:.3} mm per µm of defocus error)",
        c.placement.height_mm, u.height_mm, c.defocus_sigma_um, c.height_per_defocus_um
    );
    if no_tilt {
        println!("  tilt not fitted (--no-tilt): board taken as flat");
    } else if c.tilt_observable {
        println!(
            "  tilt {:+.2} ± {:.2} ° about x, {:+.2} ± {:.2} ° about y",
            c.placement.tilt_x_deg, u.tilt_x_deg, c.placement.tilt_y_deg, u.tilt_y_deg
        );
    } else {
        println!(
            "  tilt not observable (1σ {:.2}° / {:.2}°): board taken as flat",
            u.tilt_x_deg, u.tilt_y_deg
        );
    }
    println!(
        "  feature at ({:.1}, {:.1}) µm, {} px; rms residual {:.4} µm",
        c.feature.x_um, c.feature.y_um, c.feature.area_px, c.rms_residual_um
    );
    if let Some(o) = c.led_offsets() {
        println!(
            "  each LED off the fitted board: {:.3} mm RMS (1σ of each ≈ {:.3} mm), farthest ({}, {}) {:.3} ± {:.3} mm",
            o.rms_mm,
            o.median_sigma_mm,
            o.farthest.row,
            o.farthest.col,
            o.farthest_mm,
            o.farthest_sigma_mm
        );
    }
    let count = |s: LedStatus| c.leds.iter().filter(|l| l.status == s).count();
    let cut = c
        .leds
        .iter()
        .filter(|l| l.status == LedStatus::Used && l.cut_by_edge)
        .count();
    println!(
        "  LEDs: {} used{}, {} dark-field, {} near the pupil edge, {} lost the feature, {} saturated, {} outliers",
        count(LedStatus::Used),
        if cut > 0 {
            format!(" ({cut} of them cut by the frame's edge, the cut modelled)")
        } else {
            String::new()
        },
        count(LedStatus::NotBrightField),
        count(LedStatus::NearPupilEdge),
        count(LedStatus::FeatureLost),
        count(LedStatus::Saturated),
        count(LedStatus::Outlier)
    );
}

/// calibration.html beside `out`.
fn write_page(
    file: &fpm_host::calibration::CalibrationFile,
    ds: &Dataset,
    options: &Options,
    out: &std::path::Path,
    plot: Option<&std::path::Path>,
    page: &std::path::Path,
) -> Result<()> {
    let name = |p: &std::path::Path| {
        p.file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default()
    };
    let mut outputs = vec![(name(out), "the calibration, machine-readable".to_string())];
    outputs.push(("plots/".into(), "the charts as PNG and SVG".into()));
    if let Some(plot) = plot {
        let at = std::fs::canonicalize(plot).unwrap_or_else(|_| plot.to_path_buf());
        outputs.push((
            at.display().to_string(),
            "the residual chart asked for with --plot".into(),
        ));
    }
    let context = fpm_report::pages::calibration::Context {
        file,
        system: &ds.manifest.system(),
        bias_correction: options.bias_correction,
        reproduce: &fpm_report::html::command_line(),
        outputs,
    };
    fpm_report::pages::calibration::write(&context, page)
}

/// Calibrate a colour calibration set: each channel as its own set (its
/// calibration.json and report beside its frames, as `fpm calibrate CHANNEL_DIR`
/// writes them), and one colour calibration.json holding them all with the dies'
/// offsets they imply.
fn color(a: &CalibrateArgs, options: &Options) -> Result<()> {
    use fpm_host::color::{ColorCalibration, ColorDataset};
    if a.plot.is_some() {
        anyhow::bail!("--plot: a colour set writes each channel's chart into its own report (CHANNEL/calibration.html)");
    }
    let ds = ColorDataset::open(&a.dir)?;
    let cal = ColorCalibration::calibrate(&ds, options)?;
    let out = a
        .out
        .clone()
        .unwrap_or_else(|| a.dir.join("calibration.json"));
    let json = serde_json::to_string_pretty(&cal.to_json()?)?;
    std::fs::write(&out, &json)?;
    for ((name, file), channel) in cal.channels.iter().zip(&ds.channels) {
        let own = channel.dir.join("calibration.json");
        std::fs::write(&own, serde_json::to_string_pretty(file)?)?;
        if let Ok(data) = Dataset::load(&channel.dir) {
            let page = own.with_extension("html");
            if let Err(e) = write_page(file, &data, options, &own, None, &page) {
                tracing::warn!("no HTML report for channel {name}: {e:#}");
            }
        }
    }
    if a.json {
        println!("{json}");
    } else {
        for (((name, file), die), focus) in cal
            .channels
            .iter()
            .zip(&cal.die_offsets)
            .zip(&cal.focal_shifts)
        {
            println!("{name}:");
            print_calibration(file, a.no_tilt);
            if *name != cal.reference {
                println!(
                    "  its dies sit ({:+.3}, {:+.3}) ± {:.3} mm from the {} dies (board axes)",
                    die.offset_mm[0], die.offset_mm[1], die.sigma_mm[0], cal.reference
                );
                println!(
                    "  its focus lies {:+.1} ± {:.1} µm from {}'s (its own fit put the LEDs at {:.2} mm; the board's h, {}'s, is kept)",
                    focus.shift_um, focus.sigma_um, cal.reference, focus.height_fitted_mm, cal.reference
                );
            }
        }
        println!(
            "wrote {} (give it to `fpm reconstruct --calibration` with the colour acquisition)",
            out.display()
        );
    }
    for (name, file) in &cal.channels {
        for w in warnings(&file.calibration) {
            eprintln!("warning: {name}: {w}");
        }
    }
    Ok(())
}
