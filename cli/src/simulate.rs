//! `fpm simulate …`: datasets from the full wave-optics model, with the ground truth
//! saved beside them.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;
use clap::{Args, Subcommand};

use fpm_host::simulation::{self, AcquisitionSet, CalibrationSet, Scene};
use fpm_host::truth::Truth;
use fpm_physics::simulate::SampleKind;

/// Make a simulated dataset.
#[derive(Subcommand, Debug)]
pub enum SimulateCommand {
    /// A pdcFPM calibration set: an in-focus reference and defocused frames of the LEDs
    /// around the centre, of a small square hole.
    Calibration(CalibrationArgs),
    /// A full acquisition: every LED, in focus, of a complex test sample.
    Acquisition(AcquisitionArgs),
    /// A whole-slide scan: a grid of fields of one larger slide, each a full
    /// acquisition, the stage off its commanded positions; the slide's truth kept.
    Scan(crate::scan::SimulateScanArgs),
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
    /// Camera noise: realistic (shot, read, 12-bit), eight-bit (a home-built rig's
    /// 8-bit camera) or none.
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
    #[command(flatten)]
    color: ColorArgs,
}

/// Colour: a scan per LED colour.
#[derive(Args, Debug, Clone)]
pub struct ColorArgs {
    /// Simulate a colour acquisition: a whole scan per colour, written as a colour
    /// dataset (OUT/dataset.toml joining OUT/<colour>/). Colours: red, green, blue (the
    /// WS2812B's 622.5, 523.5, 470 nm, FWHM 18, 33, 25 nm, dies 0.7 mm apart along the
    /// board's x, focal shift +4/0/-4 µm), each optionally NAME:WAVELENGTH_UM
    #[arg(long, value_delimiter = ',', value_name = "COLOUR[:UM]")]
    colors: Vec<String>,
    /// With --colors: where a colour's die sits in the LED package, board x,y in mm
    /// (repeat per colour, e.g. red=-0.8,0); `--die-offset-mm all=0,0` puts every die
    /// at the package's centre
    #[arg(long, value_name = "COLOUR=X,Y", allow_hyphen_values = true)]
    die_offset_mm: Vec<String>,
    /// With --colors: the objective's focal shift at a colour, µm (repeat, e.g.
    /// blue=-6)
    #[arg(long, value_name = "COLOUR=UM", allow_hyphen_values = true)]
    focal_shift_um: Vec<String>,
    /// With --colors: wavelengths rendered per colour for its LED's spectrum (1: the
    /// centre line only)
    #[arg(long, default_value_t = 5)]
    spectral_samples: usize,
}

impl ColorArgs {
    /// The colour set asked for, if any.
    fn color_set(&self) -> Result<Option<simulation::ColorSet>> {
        if self.colors.is_empty() {
            if !self.die_offset_mm.is_empty() || !self.focal_shift_um.is_empty() {
                anyhow::bail!("--die-offset-mm and --focal-shift-um apply with --colors");
            }
            return Ok(None);
        }
        let mut channels = fpm_physics::color::parse_channels(&self.colors, "--colors")?;
        let mut set_per =
            |flag: &str,
             items: &[String],
             apply: &mut dyn FnMut(&mut fpm_physics::color::Channel, &str) -> Result<()>|
             -> Result<()> {
                for item in items {
                    let (name, value) = item
                        .split_once('=')
                        .ok_or_else(|| anyhow::anyhow!("{flag} {item}: give COLOUR=VALUE"))?;
                    let mut hit = false;
                    for c in channels
                        .iter_mut()
                        .filter(|c| name == "all" || c.name == name)
                    {
                        apply(c, value).map_err(|e| anyhow::anyhow!("{flag} {item}: {e}"))?;
                        hit = true;
                    }
                    if !hit {
                        anyhow::bail!("{flag} {item}: {name:?} is not one of --colors (or all)");
                    }
                }
                Ok(())
            };
        set_per("--die-offset-mm", &self.die_offset_mm, &mut |c, v| {
            let xy: Vec<f64> = v
                .split(',')
                .map(|p| p.trim().parse::<f64>())
                .collect::<Result<_, _>>()
                .map_err(|_| anyhow::anyhow!("{v:?} is not X,Y in mm"))?;
            match xy.as_slice() {
                [x, y] => {
                    c.die_offset_mm = [*x, *y];
                    Ok(())
                }
                _ => anyhow::bail!("{v:?} is not X,Y in mm"),
            }
        })?;
        set_per("--focal-shift-um", &self.focal_shift_um, &mut |c, v| {
            c.focal_shift_um = v
                .trim()
                .parse()
                .map_err(|_| anyhow::anyhow!("{v:?} is not a distance in µm"))?;
            Ok(())
        })?;
        Ok(Some(simulation::ColorSet {
            channels,
            spectral_samples: self.spectral_samples,
        }))
    }
}

/// Print what a colour simulation wrote.
fn print_color_written(
    s: &SceneArgs,
    written: &[(String, simulation::Written)],
    seconds: f64,
) -> Result<()> {
    if s.json {
        let channels: Vec<_> = written
            .iter()
            .map(
                |(name, w)| serde_json::json!({"name": name, "frames": w.frames, "truth": w.truth}),
            )
            .collect();
        let json = serde_json::json!({
            "out": s.out,
            "size": [s.size, s.size],
            "seconds": seconds,
            "channels": channels,
        });
        println!("{}", serde_json::to_string_pretty(&json)?);
        return Ok(());
    }
    println!(
        "wrote a colour dataset to {} in {seconds:.2} s ({}x{} frames):",
        s.out.display(),
        s.size,
        s.size
    );
    for (name, w) in written {
        let p = &w.truth.placement;
        println!(
            "  {name}: {} frames in {}/ (its LEDs, the {name} dies: Δx {:.3} mm, Δy {:.3} mm, θ {:.2}°, h {:.2} mm; truth.json)",
            w.frames,
            name,
            p.dx_mm,
            p.dy_mm,
            p.theta_deg,
            p.height_mm
        );
    }
    Ok(())
}

/// Camera noise.
#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq)]
pub enum Noise {
    /// Shot noise, read noise, offset, 12-bit quantisation.
    Realistic,
    /// An 8-bit camera as on home-built rigs: read noise of 3.5 DN about an offset of
    /// 2 DN, clipped at zero (dark frames skewed like the vendored USAF set's); with
    /// --dark-field-peak-dn 25, dark-field frames as dim as that set's.
    EightBit,
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
    /// Put each LED off its grid place by its own move (1σ per axis, mm, drawn from the
    /// seed and the LED), as hand-soldered boards have them: `fpm calibrate` reports
    /// each one's offset, and truth.json lists where the calibration's LEDs really were.
    #[arg(long, default_value_t = 0.0)]
    led_jitter_mm: f64,
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
    /// Image through an objective that is not telecentric, its entrance pupil this
    /// many mm above the sample (a camera lens, a simple low-power objective): the
    /// exit field is propagated to the pupil and cut there (Fresnel), so each point
    /// sees the pupil centred on its own chief ray. The dataset cannot state it:
    /// truth.json does, and `fpm reconstruct --entrance-pupil-mm` takes it
    #[arg(long, value_parser = crate::units::positive_mm)]
    entrance_pupil_mm: Option<f64>,
    /// Store the frames for display with this gamma (e.g. 2.2), as camera software
    /// exporting 8-bit images for viewing does; the dataset states it as
    /// `[camera] gamma`, which `fpm reconstruct` decodes.
    #[arg(long)]
    display_gamma: Option<f64>,
    /// What the sample is made of: cells (absorbing and phase cells with bar groups),
    /// weak-phase (unstained cells, a few % contrast) or stained (dense, strongly
    /// absorbing).
    #[arg(long, value_enum, default_value_t = Sample::Cells)]
    sample: Sample,
    /// Light this many dark-field LEDs together in each frame (multiplexed
    /// illumination): every LED once, bright and dark field apart, LEDs of similar NA
    /// at random angles sharing a frame; each frame exposed for the sum of its LEDs'
    /// single-LED exposures, or less where that would saturate. The dataset lists each
    /// frame's LEDs (`leds = [...]`).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=64))]
    multiplex: u16,
    /// Bright-field LEDs per frame (1: one at a time, the default: summed, their
    /// overlapping windows cannot be told apart as well).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=64))]
    multiplex_bright: u16,
}

/// `--sample`.
#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq)]
pub enum Sample {
    /// Soft cells of moderate absorption and thickness, with bar groups.
    Cells,
    /// Unstained cells: phase only (0.05–0.3 rad), no bars.
    WeakPhase,
    /// Stained tissue: dense, strongly absorbing cells, with bar groups.
    Stained,
}

impl From<Sample> for SampleKind {
    fn from(s: Sample) -> Self {
        match s {
            Sample::Cells => SampleKind::Cells,
            Sample::WeakPhase => SampleKind::WeakPhase,
            Sample::Stained => SampleKind::Stained,
        }
    }
}

impl SceneArgs {
    fn scene(&self) -> Scene {
        let placed = if self.random_geometry {
            Scene::random_placement(self.seed)
        } else {
            Scene::placed(self.dx_mm, self.dy_mm, self.theta_deg, self.height_mm)
        };
        Scene {
            truth: placed.tilted(self.tilt_x_deg, self.tilt_y_deg),
            noise: match self.noise {
                Noise::Realistic => simulation::Noise::Realistic,
                Noise::EightBit => simulation::Noise::EightBit,
                Noise::None => simulation::Noise::None,
            },
            size: self.size,
            seed: self.seed,
            stray_light: self.stray_light,
        }
    }
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
        SimulateCommand::Scan(a) => crate::scan::simulate(a),
    }
}

fn calibration(a: CalibrationArgs) -> Result<()> {
    let s = &a.scene;
    let scene = s.scene();
    let set = CalibrationSet {
        defocus_um: a.defocus_um,
        feature_um: a.feature_um,
        feature_at_um: (a.feature_x_um, a.feature_y_um),
        led_jitter_mm: a.led_jitter_mm,
    };
    let start = Instant::now();
    if let Some(color) = s.color.color_set()? {
        let written = simulation::write_color_calibration(&scene, &set, &color, &s.out)?;
        return print_color_written(s, &written, start.elapsed().as_secs_f64());
    }
    let written = simulation::write_calibration_set(&scene, &set, &s.out)?;
    let truth = &written.truth;
    if s.json {
        return print_written(s, written.frames, start.elapsed().as_secs_f64(), truth);
    }
    println!(
        "wrote {} frames ({}x{}) to {} in {:.2} s; hidden array Δx {:.3} mm, Δy {:.3} mm, θ {:.2}°, h {:.2} mm (truth.json)",
        written.frames,
        s.size,
        s.size,
        s.out.display(),
        start.elapsed().as_secs_f64(),
        truth.placement.dx_mm,
        truth.placement.dy_mm,
        truth.placement.theta_deg,
        truth.placement.height_mm
    );
    Ok(())
}

fn acquisition(a: AcquisitionArgs) -> Result<()> {
    let s = &a.scene;
    let set = AcquisitionSet {
        upsample: a.upsample.max(1),
        dark_field_peak_dn: a.dark_field_peak_dn,
        led_jitter_mm: a.led_jitter_mm,
        entrance_pupil_mm: a.entrance_pupil_mm,
        display_gamma: a.display_gamma,
        sample: a.sample.into(),
        multiplex: fpm_physics::multiplex::Multiplex {
            dark_field: a.multiplex.into(),
            bright_field: a.multiplex_bright.into(),
        },
    };
    let color = s.color.color_set()?;
    let frames = s.scene().truth.leds().len() * color.as_ref().map_or(1, |c| c.channels.len());
    let bar =
        indicatif::ProgressBar::new_spinner().with_message(format!("rendering {frames} frames"));
    bar.enable_steady_tick(std::time::Duration::from_millis(120));
    let start = Instant::now();
    if let Some(color) = color {
        let written = simulation::write_color_acquisition(&s.scene(), &set, &color, &s.out);
        bar.finish_and_clear();
        return print_color_written(s, &written?, start.elapsed().as_secs_f64());
    }
    let written = simulation::write_acquisition(&s.scene(), &set, &s.out);
    bar.finish_and_clear();
    let written = written?;
    if s.json {
        return print_written(
            s,
            written.frames,
            start.elapsed().as_secs_f64(),
            &written.truth,
        );
    }
    println!(
        "wrote {} frames ({}x{}) to {} in {:.2} s, with truth_amplitude.tif and truth_phase.tif ({:.3} µm pixels)",
        written.frames,
        s.size,
        s.size,
        s.out.display(),
        start.elapsed().as_secs_f64(),
        written.truth.object_pixel_um.unwrap_or(f64::NAN)
    );
    Ok(())
}
