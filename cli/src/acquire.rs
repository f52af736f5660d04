//! `fpm acquire`: calibrate (pdcFPM) and acquire a full dataset from a live rig, with
//! streaming reconstruction while the frames arrive (`fpm_acquire::pipeline`).

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result};
use clap::Args;
use fpm_acquire::acquisition::defaults;
use fpm_acquire::controller::discover;
use fpm_acquire::pipeline::{self, AcquireSummary, Control, Plan};
use fpm_acquire::{Controller, FocusStage, Progress};
use fpm_frames::ServiceNames;
use fpm_host::calibration::GeometrySource;
use fpm_physics::System;
use fpm_protocol::Rgb;

use crate::flatten::FlattenArgs;
use crate::stage::StageArgs;

/// Acquire an FPM dataset: every LED of the array, one frame each, labelled.
#[derive(Args, Debug, Clone)]
pub struct AcquireArgs {
    /// The LED controller's serial port (a board, or `fpm emulator --link`). Omitted:
    /// the one board connected (see `fpm device list`).
    #[arg(long, env = "FPM_PORT")]
    pub port: Option<String>,
    /// Print the summary (acquisition.json) as JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// The camera whose frames to take (`fpm/camera/<NAME>/frames` on iceoryx2).
    #[arg(long, default_value = "0")]
    pub frames: String,
    /// Output directory: dataset.toml + frames/, acquisition.json, calibration/,
    /// calibration.json, reconstruction/.
    #[arg(long)]
    pub out: PathBuf,
    /// Calibrate the LED array first (pdcFPM: a focused reference, then the bright-field
    /// LEDs with the sample defocused). Without it, the geometry stored on the
    /// controller is used (`fpm device geometry`), else the nominal one.
    #[arg(long)]
    pub calibrate: bool,
    /// Store the calibration on the controller (firmware with protocol ≥ 1.1), so that
    /// later acquisitions without --calibrate start from it.
    #[arg(long, requires = "calibrate")]
    pub store_geometry: bool,
    /// Complete the acquisition an earlier run left in --out (interrupted, cancelled,
    /// failed part-way): its frames are kept and only the LEDs they lack are lit, with
    /// the geometry it used. Give the optics it was acquired with.
    #[arg(long, conflicts_with = "calibrate")]
    pub resume: bool,
    /// Light this many dark-field LEDs together in each frame (multiplexed
    /// illumination, about that many times fewer dark-field frames): every LED once,
    /// bright and dark field apart, LEDs of similar NA at random angles sharing a
    /// frame, through the controller's LED sets (protocol 1.2). Uses the calibration
    /// stored on the board (calibrate first with --calibrate --store-geometry);
    /// reconstructs once the frames are in.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=64))]
    pub multiplex: u16,
    /// Bright-field LEDs per frame (1: one at a time, the default: summed, their
    /// overlapping windows cannot be told apart as well).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=64))]
    pub multiplex_bright: u16,
    /// Reconstruct while the frames arrive (streaming EPRY).
    #[arg(long)]
    pub reconstruct: bool,
    /// The focus stage, moved for calibration.
    #[command(flatten)]
    pub stage: StageArgs,
    /// How long each LED stays lit, ms (the camera exposes within it).
    #[arg(long, default_value_t = defaults::STEP_MS)]
    pub step_ms: f64,
    /// Defocus for calibration, µm toward the LEDs.
    #[arg(long, default_value_t = defaults::DEFOCUS_UM)]
    pub defocus_um: f64,
    /// 1σ of the defocus as the stage sets it, µm: h is proportional to the defocus, so
    /// its uncertainty carries this (`--stage virtual` is exact: give 0).
    #[arg(long, default_value_t = defaults::DEFOCUS_SIGMA_UM)]
    pub defocus_sigma_um: f64,
    /// Acquire in colour: a whole scan per LED colour (red, green, blue: each lit
    /// alone, each with its own wavelength — the WS2812B's 622.5 and 523.5 nm, and
    /// 470 nm for blue as --wavelength-um assumes — or NAME:UM), one after another,
    /// written as a colour dataset (OUT/dataset.toml joining OUT/<colour>/). With
    /// --calibrate each colour is calibrated (its dies sit apart), OUT/calibration.json
    /// holding them all; with --reconstruct the colour image goes to
    /// OUT/reconstruction/
    #[arg(long, value_delimiter = ',', value_name = "COLOUR[:UM]")]
    pub colors: Vec<String>,
    /// With --colors: the colour the sample was focused in (the stage's zero): each
    /// other colour's focus is measured from it (the objective's chromatic focal
    /// shift, which would otherwise bias its calibrated LED height) and its image
    /// registered to it
    #[arg(long, default_value = "green", requires = "colors")]
    pub focus_color: String,
    /// LED colour: a name, `#rrggbb` or `r,g,b` (0–255).
    #[arg(long, default_value = "0,0,255", value_parser = crate::color::parse)]
    pub color: Rgb,
    /// The camera's dark level, counts.
    #[arg(long, default_value_t = defaults::DARK_LEVEL)]
    pub dark_level: f64,
    /// Illumination wavelength, µm.
    #[arg(long, default_value_t = defaults::WAVELENGTH_UM)]
    pub wavelength_um: f64,
    /// Objective NA.
    #[arg(long, default_value_t = defaults::NA)]
    pub na: f64,
    /// Objective magnification.
    #[arg(long, default_value_t = defaults::MAGNIFICATION)]
    pub magnification: f64,
    /// Camera pixel, µm.
    #[arg(long, default_value_t = defaults::PIXEL_UM)]
    pub pixel_um: f64,
    /// The objective's entrance pupil distance above the sample, mm, for objectives
    /// that are not telecentric (see `fpm reconstruct --entrance-pupil-mm`): the
    /// acquisition order and the streamed reconstruction read every frame where its
    /// LED falls in the pupil of each tile. Default: telecentric
    #[arg(long, value_parser = crate::units::positive_mm)]
    pub entrance_pupil_mm: Option<f64>,
    /// EPRY passes after the last frame.
    #[arg(long, default_value_t = defaults::PASSES)]
    pub passes: usize,
    /// Tile side of the reconstruction, camera pixels (default: from the physics, the
    /// largest over which one illumination curvature holds; see `fpm reconstruct`).
    #[arg(long)]
    pub tile: Option<usize>,
    #[command(flatten)]
    pub flatten: FlattenArgs,
}

/// Run `fpm acquire`.
pub fn run(a: AcquireArgs) -> Result<()> {
    if !a.colors.is_empty() {
        return colors(&a);
    }
    let summary = acquire(&a)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        print_summary(&summary, &a.out);
    }
    Ok(())
}

/// The acquisition, returning its summary.
pub fn acquire(a: &AcquireArgs) -> Result<AcquireSummary> {
    let (dev, mut stage) = open_rig(a)?;
    run_plan(&dev, stage.as_mut(), &plan(a), a.resume)
}

/// The LED controller and the focus stage `a` names.
fn open_rig(a: &AcquireArgs) -> Result<(Controller, Box<dyn FocusStage>)> {
    Ok((open_controller(a)?, a.stage.open_focus()?))
}

/// The LED controller `a` names (or the one board connected).
pub fn open_controller(a: &AcquireArgs) -> Result<Controller> {
    let timeout = Duration::from_secs(2);
    let port = match &a.port {
        Some(port) => port.clone(),
        None => discover::the_only_board(timeout).map_err(anyhow::Error::msg)?,
    };
    let dev = Controller::open(&port, timeout)
        .with_context(|| format!("connecting to the LED controller on {port}"))?;
    // Shared memory of crashed runs (ours or a camera's) is removed before we start.
    match fpm_frames::cleanup_stale() {
        Ok(0) => {}
        Ok(n) => tracing::info!("removed the shared memory of {n} crashed process(es)"),
        Err(e) => tracing::warn!("could not check for stale shared memory: {e}"),
    }
    Ok(dev)
}

/// The plan `a` describes.
pub fn plan(a: &AcquireArgs) -> Plan {
    Plan {
        camera: ServiceNames::for_camera(&a.frames),
        out: a.out.clone(),
        calibrate: a.calibrate,
        capture: true,
        store_geometry: a.store_geometry,
        reconstruct: a.reconstruct,
        step_ms: a.step_ms,
        defocus_um: a.defocus_um,
        defocus_sigma_um: a.defocus_sigma_um,
        color: a.color,
        dark_level: a.dark_level,
        system: System {
            wavelength_um: a.wavelength_um,
            na: a.na,
            magnification: a.magnification,
            pixel_size_um: a.pixel_um,
            entrance_pupil_mm: a.entrance_pupil_mm,
        },
        passes: a.passes,
        tile: a.tile,
        flatten: a.flatten.flatten(),
        snapshot_every: 0,
        geometry: None,
        leds: None,
        multiplex: fpm_physics::multiplex::Multiplex {
            dark_field: a.multiplex.into(),
            bright_field: a.multiplex_bright.into(),
        },
    }
}

/// Run `plan` on the rig, with a progress bar; Ctrl-C cancels it.
fn run_plan(
    dev: &Controller,
    stage: &mut dyn FocusStage,
    plan: &Plan,
    resume: bool,
) -> Result<AcquireSummary> {
    let cancel = cancel_on_signal()?;
    let bar = crate::progress::frames("acquiring");
    let on_progress = |p: &Progress| {
        bar.set_length(p.of as u64);
        bar.set_position(p.frames as u64);
        // Why frames wait for their labels, while they do.
        bar.set_message(p.labelling.map(|w| w.to_string()).unwrap_or_default());
    };
    let control = Control::cancelled_by(cancel);
    let summary = match resume {
        false => pipeline::acquire(dev, stage, plan, on_progress, &control),
        true => pipeline::resume(dev, stage, plan, on_progress, &control),
    };
    bar.finish_and_clear();
    summary
}

/// A flag Ctrl-C (or SIGTERM) sets: the acquisition aborts its sequence and writes
/// what it captured. A second Ctrl-C ends the process at once.
pub fn cancel_on_signal() -> Result<Arc<AtomicBool>> {
    let flag = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register_conditional_shutdown(signal, 130, Arc::clone(&flag))?;
        signal_hook::flag::register(signal, Arc::clone(&flag))?;
    }
    Ok(flag)
}

fn print_summary(s: &AcquireSummary, out: &Path) {
    let c = &s.capture;
    println!(
        "acquired {}/{} frames in {:.1} s ({:.1} frames/s); missing {}, extra {}, ambiguous {}",
        c.labelled,
        c.requested,
        c.seconds,
        c.frames_per_s,
        c.missing.len(),
        c.extra_frames,
        c.ambiguous_frames
    );
    if let Some(r) = &s.retake {
        println!(
            "  re-acquired {}/{} missing frame(s)",
            r.labelled, r.requested
        );
    }
    if !s.still_missing.is_empty() {
        println!("  missing LEDs (not in the dataset): {:?}", s.still_missing);
    }
    let g = &s.geometry;
    println!(
        "geometry used ({}): Δx {:.3} mm, Δy {:.3} mm, θ {:.3}°, h {:.2} mm",
        match s.geometry_source {
            GeometrySource::Board => "stored on the board",
            GeometrySource::CalibratedNow => "calibrated now",
            _ => "nominal: not calibrated",
        },
        g.dx_mm,
        g.dy_mm,
        g.theta_deg,
        g.height_mm
    );
    if let Some(p) = s.entrance_pupil_mm {
        println!(
            "objective's entrance pupil {p} mm above the sample (not telecentric): dataset.toml cannot state it, so reconstruct the dataset again with --entrance-pupil-mm {p}"
        );
    }
    if let Some(ms) = s.last_frame_to_final_ms {
        println!("last frame → final image: {ms:.0} ms");
    }
    println!(
        "wrote the dataset and acquisition.json to {}",
        out.display()
    );
}

/// `fpm acquire --colors`: a scan per colour ([`fpm_acquire::color`]), then the colour
/// image when asked for; prints what each colour did.
fn colors(a: &AcquireArgs) -> Result<()> {
    use fpm_acquire::color::{self, ColorPlan};
    let colors = ColorPlan::parse(&a.colors, &a.focus_color, "--colors")?;
    if a.resume {
        anyhow::bail!("--resume with --colors: a colour acquisition is not resumable yet; acquire the colours again");
    }
    let (dev, mut stage) = open_rig(a)?;
    let cancel = cancel_on_signal()?;
    let control = Control::cancelled_by(cancel);
    let bar = crate::progress::frames("acquiring");
    let done = color::acquire(
        &dev,
        stage.as_mut(),
        &plan(a),
        &colors,
        |name| {
            bar.set_message(format!("acquiring {name}"));
            let bar = bar.clone();
            move |p: &Progress| {
                bar.set_length(p.of as u64);
                bar.set_position(p.frames as u64);
            }
        },
        &control,
        &fpm_report::html::command_line(),
    );
    bar.finish_and_clear();
    let done = done?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&done)?);
        return Ok(());
    }
    for c in &done.channels {
        print!("{} ({:.1} nm): ", c.name, c.wavelength_um * 1e3);
        print_summary(&c.summary, &a.out.join(&c.name));
    }
    println!(
        "acquired {} colours in {:.1} s; wrote the colour dataset to {}{}",
        done.channels.len(),
        done.seconds,
        a.out.display(),
        done.calibration.as_ref().map_or(String::new(), |p| format!(
            " and each colour's calibration to {}",
            p.display()
        ))
    );
    if let Some(r) = &done.reconstruction {
        for c in &r.channels {
            println!(
                "  {}: shifted {} to {}{}",
                c.name,
                c.shift_um
                    .map_or("—".to_string(), |[x, y]| format!("({x:+.2}, {y:+.2}) µm")),
                r.reference,
                c.versus_truth.map_or(String::new(), |s| format!(
                    ", complex NRMSE {:.3} against its truth",
                    s.complex_nrmse
                ))
            );
        }
        println!(
            "wrote the colour image to {}",
            a.out.join("reconstruction").display()
        );
        for w in r
            .warnings
            .iter()
            .chain(r.channels.iter().flat_map(|c| c.warnings.iter()))
        {
            eprintln!("warning: {}", w.message);
        }
    }
    Ok(())
}
