//! `fpm simulate …`: datasets from the full wave-optics model, with the ground truth
//! saved beside them.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use fpm_physics::simulate::{acquire_from, CalibrationScene, Camera, ObjectField, SimFrame};
use fpm_physics::{LedGeometry, System};
use rand::{Rng, SeedableRng};
use serde::Serialize;

use fpm_host::dataset::{CameraSection, Dataset, FrameEntry, Manifest};
use fpm_host::truth::{TrueLed, Truth};
use rand_distr::Distribution;

/// Make a simulated dataset.
#[derive(Subcommand, Debug)]
pub enum SimulateCommand {
    /// A pdcFPM calibration set: an in-focus reference and defocused frames of the LEDs
    /// around the centre, of a small square hole.
    Calibration(CalibrationArgs),
    /// A full acquisition: every LED, in focus, of a complex test sample.
    Acquisition(AcquisitionArgs),
}

/// The hidden (true) LED array and the microscope.
#[derive(Args, Debug, Clone)]
pub struct SceneArgs {
    /// Output directory.
    #[arg(long)]
    out: PathBuf,
    /// True Δx of the array, mm.
    #[arg(long, default_value_t = 1.0, allow_hyphen_values = true)]
    dx_mm: f64,
    /// True Δy, mm.
    #[arg(long, default_value_t = 1.0, allow_hyphen_values = true)]
    dy_mm: f64,
    /// True rotation, degrees.
    #[arg(long, default_value_t = 5.0, allow_hyphen_values = true)]
    theta_deg: f64,
    /// True LED-to-sample distance, mm.
    #[arg(long, default_value_t = 92.0)]
    height_mm: f64,
    /// True tilt of the board about its x axis through the centre LED, degrees (LEDs
    /// on the +y side farther from the sample).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    tilt_x_deg: f64,
    /// True tilt about the board's y axis, degrees (LEDs on the +x side farther away).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    tilt_y_deg: f64,
    /// Draw Δx, Δy, θ, h at random from the paper's range instead (±2.5 mm, ±5°, 87–97 mm).
    #[arg(long)]
    random_geometry: bool,
    /// Camera noise: realistic (shot, read, 12-bit) or none.
    #[arg(long, value_enum, default_value_t = Noise::Realistic)]
    noise: Noise,
    /// Sensor size, pixels (square).
    #[arg(long, default_value_t = 256)]
    size: usize,
    /// Random seed (noise and random geometry).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Stray light on every pixel of every frame, as a fraction of a clear sample's
    /// brightness under the on-axis LED (e.g. 0.001): the background that long
    /// dark-field exposures pick up on a real rig.
    #[arg(long, default_value_t = 0.0)]
    stray_light: f64,
    /// Print what was written (frames, size, time, the hidden truth) as JSON instead of
    /// text.
    #[arg(long)]
    json: bool,
}

/// Camera noise.
#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq)]
pub enum Noise {
    /// Shot noise, read noise, offset, 12-bit quantisation.
    Realistic,
    /// Quantisation only.
    None,
}

/// `fpm simulate calibration`.
#[derive(Args, Debug)]
pub struct CalibrationArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Defocus of the sample toward the LEDs, µm.
    #[arg(long, default_value_t = 200.0, allow_hyphen_values = true)]
    defocus_um: f64,
    /// Side of the square hole, µm.
    #[arg(long, default_value_t = 50.0)]
    feature_um: f64,
    /// Feature position x, µm from the optical axis.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    feature_x_um: f64,
    /// Feature position y, µm.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    feature_y_um: f64,
}

/// `fpm simulate acquisition`.
#[derive(Args, Debug)]
pub struct AcquisitionArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Simulation pixels per camera pixel (the ground truth's resolution).
    #[arg(long, default_value_t = 2)]
    upsample: usize,
    /// Record dark-field frames dim, as a camera set up for the bright field does: their
    /// brightest pixel at this many counts above the offset (e.g. 200) instead of 80 %
    /// of full scale.
    #[arg(long)]
    dark_field_peak_dn: Option<f64>,
    /// Put each LED off its grid place by this much (1σ per axis, mm, drawn from the
    /// seed), as hand-soldered boards have them: the dataset states only the grid, and
    /// truth.json lists where every LED really was.
    #[arg(long, default_value_t = 0.0)]
    led_jitter_mm: f64,
}

/// The paper's microscope: λ 0.47 µm, NA 0.1, 4×, 2.4 µm pixels; 21×21 LEDs at 2.5 mm.
fn paper_system() -> System {
    System::paper()
}

fn nominal(height_mm: f64) -> LedGeometry {
    LedGeometry {
        height_mm,
        ..LedGeometry::paper()
    }
}

impl SceneArgs {
    fn truth(&self) -> LedGeometry {
        let placed = if self.random_geometry {
            let mut rng = rand::rngs::StdRng::seed_from_u64(self.seed ^ 0x5EED);
            LedGeometry {
                dx_mm: rng.gen_range(-2.5..2.5),
                dy_mm: rng.gen_range(-2.5..2.5),
                theta_deg: rng.gen_range(-5.0..5.0),
                height_mm: rng.gen_range(87.0..97.0),
                ..nominal(92.0)
            }
        } else {
            LedGeometry {
                dx_mm: self.dx_mm,
                dy_mm: self.dy_mm,
                theta_deg: self.theta_deg,
                height_mm: self.height_mm,
                ..nominal(92.0)
            }
        };
        placed.tilted(self.tilt_x_deg, self.tilt_y_deg)
    }

    fn camera(&self) -> Camera {
        let camera = match self.noise {
            Noise::Realistic => Camera::realistic(),
            Noise::None => Camera::noiseless(),
        };
        Camera {
            stray_light: self.stray_light.max(0.0),
            ..camera
        }
    }
}

/// The manifest for frames of the paper's system, with the nominal (uncalibrated) array.
fn manifest(system: &System, camera: &Camera, frames: Vec<FrameEntry>) -> Manifest {
    let camera = CameraSection {
        dark_level: camera.dark_level_dn,
        bit_depth: Some(camera.bit_depth),
        ..CameraSection::default()
    };
    Manifest::new(system, &nominal(92.0), camera, frames)
}

/// Write simulated frames as a dataset with the nominal (uncalibrated) array.
fn write_frames(out: &Path, system: &System, camera: &Camera, frames: &[SimFrame]) -> Result<()> {
    let entries = frames
        .iter()
        .map(|f| FrameEntry {
            file: String::new(),
            led: f.led,
            defocus_um: f.defocus_um,
            exposure_ms: f.exposure_ms,
        })
        .collect();
    let images: Vec<_> = frames.iter().map(|f| f.counts.clone()).collect();
    Dataset::write(out, &manifest(system, camera, entries), &images)?;
    Ok(())
}

fn write_json(path: &Path, value: &impl Serialize) -> Result<()> {
    std::fs::write(path, serde_json::to_string_pretty(value)?)
        .with_context(|| format!("writing {}", path.display()))
}

/// `--json`: what was written.
fn print_written(s: &SceneArgs, frames: usize, seconds: f64, truth: &Truth) -> Result<()> {
    let written = serde_json::json!({
        "out": s.out,
        "frames": frames,
        "size": [s.size, s.size],
        "seconds": seconds,
        "truth": truth,
    });
    println!("{}", serde_json::to_string_pretty(&written)?);
    Ok(())
}

/// Run `fpm simulate …`.
pub fn run(cmd: SimulateCommand) -> Result<()> {
    match cmd {
        SimulateCommand::Calibration(a) => calibration(a),
        SimulateCommand::Acquisition(a) => acquisition(a),
    }
}

fn calibration(a: CalibrationArgs) -> Result<()> {
    let s = &a.scene;
    let truth = s.truth();
    let mut scene = CalibrationScene::paper(truth, s.seed);
    scene.defocus_um = a.defocus_um;
    scene.feature_um = a.feature_um;
    scene.feature_at_um = (a.feature_x_um, a.feature_y_um);
    scene.camera_px = s.size;
    scene.camera = s.camera();
    let start = Instant::now();
    let frames = scene.acquire();
    write_frames(&s.out, &scene.system, &scene.camera, &frames)?;
    let truth_file = Truth {
        dx_mm: truth.dx_mm,
        dy_mm: truth.dy_mm,
        theta_deg: truth.theta_deg,
        height_mm: truth.height_mm,
        tilt_x_deg: truth.tilt_x_deg,
        tilt_y_deg: truth.tilt_y_deg,
        defocus_um: Some(a.defocus_um),
        feature_um: Some(a.feature_um),
        feature_at_um: Some([a.feature_x_um, a.feature_y_um]),
        object_pixel_um: None,
        seed: Some(s.seed),
        leds: None,
    };
    write_json(&s.out.join("truth.json"), &truth_file)?;
    if s.json {
        return print_written(s, frames.len(), start.elapsed().as_secs_f64(), &truth_file);
    }
    println!(
        "wrote {} frames ({}x{}) to {} in {:.2} s; hidden array Δx {:.3} mm, Δy {:.3} mm, θ {:.2}°, h {:.2} mm (truth.json)",
        frames.len(),
        s.size,
        s.size,
        s.out.display(),
        start.elapsed().as_secs_f64(),
        truth.dx_mm,
        truth.dy_mm,
        truth.theta_deg,
        truth.height_mm
    );
    Ok(())
}

/// Every LED of `truth`'s board, each moved laterally by N(0, σ = `jitter_mm`) per
/// axis (its own stream of the seed).
fn led_positions(truth: &LedGeometry, jitter_mm: f64, seed: u64) -> Result<Vec<TrueLed>> {
    if !(jitter_mm.is_finite() && jitter_mm >= 0.0) {
        anyhow::bail!("--led-jitter-mm {jitter_mm}: give a standard deviation in mm (≥ 0)");
    }
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed ^ 0x1ED5);
    let normal = rand_distr::Normal::new(0.0, jitter_mm)?;
    Ok(truth
        .leds()
        .into_iter()
        .map(|led| {
            let (x, y, h) = truth.led_position_3d_mm(led);
            TrueLed {
                led,
                position_mm: [x + normal.sample(&mut rng), y + normal.sample(&mut rng), h],
            }
        })
        .collect())
}

fn acquisition(a: AcquisitionArgs) -> Result<()> {
    let s = &a.scene;
    let truth = s.truth();
    let system = paper_system();
    let camera = s.camera();
    let object = ObjectField::test_sample(&system, s.size, 48, a.upsample.max(1), s.seed);
    let shots: Vec<(fpm_physics::LedIndex, f64)> =
        truth.leds().into_iter().map(|l| (l, 0.0)).collect();
    let bar = indicatif::ProgressBar::new_spinner()
        .with_message(format!("rendering {} frames", shots.len()));
    bar.enable_steady_tick(std::time::Duration::from_millis(120));
    let start = Instant::now();
    // Auto-exposure as a camera would: the brightest pixel at 80 % of full scale, from
    // 2 ms (bright field) up to 1 s (dark field); or dim dark-field frames.
    let positions = led_positions(&truth, a.led_jitter_mm, s.seed)?;
    let frames = acquire_from(
        &system,
        &|led| {
            positions
                .iter()
                .find(|p| p.led == led)
                .map(|p| (p.position_mm[0], p.position_mm[1], p.position_mm[2]))
                .unwrap_or_else(|| truth.led_position_3d_mm(led))
        },
        &object,
        &shots,
        &camera,
        |img| match a.dark_field_peak_dn {
            Some(peak) => camera.dim_dark_field_exposure(img, peak),
            None => camera.auto_exposure(img),
        },
        s.seed,
    );
    bar.finish_and_clear();
    write_frames(&s.out, &system, &camera, &frames)?;
    fpm_host::truth::write_truth_images(&s.out, &object)?;
    let truth_file = Truth {
        dx_mm: truth.dx_mm,
        dy_mm: truth.dy_mm,
        theta_deg: truth.theta_deg,
        height_mm: truth.height_mm,
        tilt_x_deg: truth.tilt_x_deg,
        tilt_y_deg: truth.tilt_y_deg,
        defocus_um: None,
        feature_um: None,
        feature_at_um: None,
        object_pixel_um: Some(object.pitch_um()),
        seed: Some(s.seed),
        leds: (a.led_jitter_mm > 0.0).then_some(positions),
    };
    write_json(&s.out.join("truth.json"), &truth_file)?;
    if s.json {
        return print_written(s, frames.len(), start.elapsed().as_secs_f64(), &truth_file);
    }
    println!(
        "wrote {} frames ({}x{}) to {} in {:.2} s, with truth_amplitude.tif and truth_phase.tif ({:.3} µm pixels)",
        frames.len(),
        s.size,
        s.size,
        s.out.display(),
        start.elapsed().as_secs_f64(),
        object.pitch_um()
    );
    Ok(())
}
