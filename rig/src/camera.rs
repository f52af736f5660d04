//! The virtual camera: listens to the virtual rig (trigger pulses with the LEDs lit,
//! the stage position), renders each exposure with the full wave-optics model for a
//! hidden, misplaced LED array, and publishes the frame on the iceoryx2 frame service
//! like a camera driver would. It knows the hidden geometry; nothing downstream does.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use fpm_camera::settings::AppliedSettings;
use fpm_frames::{FrameHeader, FramePublisher, ServiceNames, SettingsPublisher};
use fpm_host::truth::{write_truth_field, Truth};
use fpm_physics::simulate::{Camera, ObjectField, Renderer};
use fpm_physics::{LedGeometry, System};
use fpm_rig_bus::{RigListener, Stage};
use rand::{Rng, SeedableRng};
use serde::Serialize;

/// Run a simulated camera on a virtual rig.
#[derive(Debug, Clone)]
pub struct VirtualCamera {
    /// The virtual rig to watch (`fpm emulator --rig NAME`).
    pub rig: String,
    /// Publish frames as this camera (`fpm/camera/<NAME>/frames`).
    pub camera: String,
    /// Sensor width, pixels (and height, unless `--height` is given).
    pub size: usize,
    /// Sensor height, pixels, for a non-square sensor (the scene is rendered on a
    /// square field and the sensor's rows are cut from its middle, optical axis kept at
    /// (width/2, height/2)).
    pub height: Option<usize>,
    /// Seed of the hidden geometry, the sample and the noise.
    pub seed: u64,
    /// Hidden array offset Δx, mm (default: random up to ±2 mm by seed).
    pub dx_mm: Option<f64>,
    /// Hidden Δy, mm.
    pub dy_mm: Option<f64>,
    /// Hidden rotation, degrees (default: random up to ±5° by seed).
    pub theta_deg: Option<f64>,
    /// Hidden LED-to-sample distance, mm (default: random 87–97 mm by seed).
    pub height_mm: Option<f64>,
    /// Image through an objective that is not telecentric, its entrance pupil this
    /// many mm above the focal plane (a camera lens, a simple low-power objective):
    /// each point sees the pupil centred on its own chief ray. Hidden like the array:
    /// only truth.json states it.
    pub entrance_pupil_mm: Option<f64>,
    /// Write the hidden truth here once listening (truth.json, virtual-camera.json,
    /// truth_amplitude.tif, truth_phase.tif), for scoring; truth.json appears last.
    pub truth_dir: Option<PathBuf>,
    /// A slide this wide, µm: each exposure shows the part under the stage.
    pub slide_um: Option<f64>,
    /// The stage's hidden, repeatable XY error: up to this far off, µm.
    pub stage_error_um: f64,
    /// The slide's surface tilt, µm of height per mm (its direction random): the
    /// focus a scan must follow.
    pub slide_tilt_um_per_mm: f64,
    /// Encode the frames for display with this gamma, as a camera with its Gamma
    /// feature on does (reported with the camera's settings).
    pub display_gamma: Option<f64>,
    /// Sensor readout time added after each exposure, ms.
    pub readout_ms: f64,
    /// Fault injection: never publish the frame with this number (repeatable).
    pub drop_frame: Vec<u64>,
    /// Fault injection: deliver every frame this much later, ms (a slow driver).
    pub late_ms: f64,
    /// The camera's own clock: this many seconds ahead of the controller's (a real
    /// camera counts from its own power-up).
    pub clock_offset_s: f64,
    /// The camera's clock runs this many ppm fast (negative: slow).
    pub clock_drift_ppm: f64,
    /// Random jitter of each frame's stamp, ms (uniform, this wide).
    pub clock_jitter_ms: f64,
}

/// The hidden state, written to `truth_dir/virtual-camera.json`.
#[derive(Debug, Clone, Serialize)]
pub struct Hidden {
    /// The real array.
    pub geometry: LedGeometry,
    /// Seed.
    pub seed: u64,
    /// Sensor size.
    pub size: usize,
}

impl VirtualCamera {
    /// A frame's stamp on the camera's clock, for a trigger at `controller_us`.
    fn camera_clock_ns(&self, controller_us: u64, rng: &mut impl Rng) -> u64 {
        let t = controller_us as f64 * 1e3;
        let jitter = if self.clock_jitter_ms > 0.0 {
            (rng.gen::<f64>() - 0.5) * self.clock_jitter_ms * 1e6
        } else {
            0.0
        };
        let stamp = self.clock_offset_s * 1e9 + t * (1.0 + self.clock_drift_ppm * 1e-6) + jitter;
        stamp.max(0.0) as u64
    }

    /// `truth.json` for a sample seen under the array `geometry`.
    fn truth(&self, geometry: &LedGeometry, sample: &ObjectField) -> Truth {
        Truth {
            placement: geometry.placement(),
            defocus_um: None,
            feature_um: None,
            feature_at_um: None,
            object_pixel_um: Some(sample.pitch_um()),
            seed: Some(self.seed),
            leds: None,
            entrance_pupil_mm: self.entrance_pupil_mm,
            sample: None,
        }
    }

    /// The hidden array: given values, or drawn from the seed.
    pub fn hidden_geometry(&self) -> LedGeometry {
        let mut rng = rand::rngs::StdRng::seed_from_u64(self.seed ^ 0x05EE_D0FA_77A7);
        let dx = rng.gen_range(-2.0..2.0);
        let dy = rng.gen_range(-2.0..2.0);
        let th = rng.gen_range(-5.0..5.0);
        let h = rng.gen_range(87.0..97.0);
        LedGeometry::paper().placed(
            self.dx_mm.unwrap_or(dx),
            self.dy_mm.unwrap_or(dy),
            self.theta_deg.unwrap_or(th),
            self.height_mm.unwrap_or(h),
        )
    }
}

/// Run until SIGINT/SIGTERM.
pub fn run(a: VirtualCamera) -> Result<()> {
    fpm_rig_bus::stop::install().context("installing signal handlers")?;
    let system = System {
        entrance_pupil_mm: a.entrance_pupil_mm,
        ..System::paper()
    };
    let hidden = a.hidden_geometry();
    let width = a.size.max(16);
    let height = a.height.unwrap_or(width).max(16);
    // The scene is rendered square (the simulator's grid), then cropped to the sensor.
    let size = width.max(height);
    let sensor = Sensor::centred(size, width, height);
    let sample = ObjectField::test_sample(&system, size, 32, 2, a.seed);
    // The calibration slide: one square hole, 50 µm (the paper's) or a third of a
    // smaller field, with room around it for a 200 µm defocus.
    let feature_um = (size as f64 * system.sample_pixel_um() / 3.0).min(50.0);
    let pad = ((200.0 * (0.25 + system.na) + 10.0) / system.sample_pixel_um()).ceil() as usize + 24;
    let target = ObjectField::square_hole(
        &system,
        size,
        pad.next_multiple_of(8),
        2,
        feature_um,
        (0.0, 0.0),
        0.0,
    );
    let camera = Camera {
        display_gamma: a.display_gamma,
        ..Camera::realistic()
    };
    let mut rng = rand::rngs::StdRng::seed_from_u64(a.seed ^ 0x00CA_3E7A);
    let mut renderers = (Renderer::new(&sample), Renderer::new(&target));
    let mut slide = match a.slide_um {
        Some(um) => Some(SlideScene::new(&system, &a, um, size)?),
        None => None,
    };
    let mut dies = Dies::new(&hidden);
    let mut rig = RigListener::create(&a.rig)?;
    let names = ServiceNames::for_camera(&a.camera);
    let publisher = FramePublisher::create(&names, width * height)?;
    // What the camera applied, as a GenICam camera's driver reports it.
    let settings = SettingsPublisher::create(
        &names,
        &serde_json::to_string(&applied_settings(&a, &camera, &system, width, height))?,
    )?;
    if let Some(dir) = &a.truth_dir {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        std::fs::write(
            dir.join("virtual-camera.json"),
            serde_json::to_string_pretty(&Hidden {
                geometry: hidden,
                seed: a.seed,
                size,
            })?,
        )?;
        write_truth_field(dir, &sensor.crop_truth(&sample))?;
        // Last: its presence tells a launcher that the camera is listening.
        std::fs::write(
            dir.join("truth.json"),
            serde_json::to_string_pretty(&a.truth(&hidden, &sample))?,
        )?;
    }
    tracing::info!(
        "virtual camera {} on rig {}: {width}x{height} frames; hidden array Δx {:.3} mm, Δy {:.3} mm, θ {:.2}°, h {:.2} mm; {}",
        a.camera,
        a.rig,
        hidden.dx_mm,
        hidden.dy_mm,
        hidden.theta_deg,
        hidden.height_mm,
        a.entrance_pupil_mm.map_or("telecentric objective".to_string(), |p| {
            format!("entrance pupil {p} mm above the sample")
        })
    );
    let mut frame_number = 0u64;
    let mut clock_rng = rand::rngs::StdRng::seed_from_u64(a.seed ^ 0xC10C);
    let mut pace = Pace::default();
    while !fpm_rig_bus::stop::requested() {
        settings.serve();
        let Some(pulse) = rig.next_pulse(Duration::from_millis(100))? else {
            continue;
        };
        pace.triggered(pulse.time_us, Instant::now());
        let stage = rig.stage()?;
        // On a slide the field under the stage, and the slide's surface height there.
        let (object, renderer, surface_um) = if stage.slide == Stage::CALIBRATION_TARGET {
            (&target, &mut renderers.1, 0.0)
        } else if let Some(slide) = slide.as_mut() {
            let (field, renderer, surface) =
                slide.field_at(stage.x_um, stage.y_um, size, a.truth_dir.as_deref())?;
            (field, renderer, surface)
        } else {
            (&sample, &mut renderers.0, 0.0)
        };
        let stage = fpm_rig_bus::Stage {
            defocus_um: stage.defocus_um + surface_um,
            ..stage
        };
        // Lit LEDs add incoherently. White (or grey) light is taken at the system's
        // wavelength from the LED's place, as blue is; red and green come from their
        // own dies, at their own wavelengths and focus.
        let mut intensity = fpm_physics::Image::zeros((size, size));
        let on_target = stage.slide == Stage::CALIBRATION_TARGET;
        for led in pulse.lit() {
            let index = fpm_physics::LedIndex::new(led.row, led.col);
            let [r, g, b] = led.rgb;
            let (blue, dies_lit) = if r == g && g == b {
                (r, [0, 0])
            } else {
                (b, [r, g])
            };
            let mut add = |value: u8,
                           at: &System,
                           geometry: &LedGeometry,
                           object: &ObjectField,
                           defocus_um: f64| {
                let i = renderer.render(at, geometry, object, index, defocus_um);
                let weight = value as f32 / 255.0;
                intensity.zip_mut_with(&i, |acc, v| *acc += weight * v);
            };
            if blue > 0 {
                add(blue, &system, &hidden, object, stage.defocus_um);
            }
            for (k, value) in dies_lit.into_iter().enumerate().filter(|(_, v)| *v > 0) {
                let die = dies.lit(k, &system, &a, &sensor, size)?;
                let at = System {
                    wavelength_um: die.channel.wavelength_um,
                    ..system
                };
                let sample_here = if on_target { object } else { die.sample() };
                add(
                    value,
                    &at,
                    &die.geometry,
                    sample_here,
                    stage.defocus_um + die.channel.focal_shift_um,
                );
            }
        }
        let exposure_ms = if stage.slide == Stage::CALIBRATION_TARGET {
            // One exposure for the whole calibration set, as a user would set it.
            camera.exposure_for(2.5, 0.85, 1.0, 1000.0)
        } else {
            // Several LEDs at once (a DPC half-circle, a multiplexed set) can outshine
            // the 2 ms floor of one LED's auto-exposure: a camera goes shorter.
            camera
                .auto_exposure(&intensity)
                .min(camera.unsaturated_exposure(&intensity))
        };
        let counts = camera.record(&sensor.crop(&intensity), exposure_ms, &mut rng);
        std::thread::sleep(Duration::from_secs_f64(a.readout_ms.max(0.0) / 1e3));
        let pixels = counts.as_slice().context("frame layout")?;
        std::thread::sleep(Duration::from_secs_f64(a.late_ms.max(0.0) / 1e3));
        if a.drop_frame.contains(&frame_number) {
            tracing::warn!("dropping frame {frame_number} on purpose (--drop-frame)");
            frame_number += 1;
            continue;
        }
        publisher.publish(
            FrameHeader {
                frame_number,
                timestamp_ns: a.camera_clock_ns(pulse.time_us, &mut clock_rng),
                exposure_us: (exposure_ms * 1e3).round() as u32,
                width: width as u32,
                height: height as u32,
                bit_depth: camera.bit_depth,
                camera_id: 0,
                ..FrameHeader::default()
            },
            pixels,
        )?;
        if let Some(late_ms) = pace.published(pulse.time_us, Instant::now()) {
            tracing::warn!(
                "the virtual camera renders slower than the controller triggers it: frame {frame_number} left {late_ms:.0} ms after its trigger, and later frames fall further behind (they are labelled all the same, but arrive late). Run a release build (cargo run --release), a smaller --virtual-size, or longer steps"
            );
        }
        tracing::debug!(
            "frame {frame_number}: pulse {} at {} µs, {} LED(s), z {} µm, {:.1} ms",
            pulse.pulse_number,
            pulse.time_us,
            pulse.lit().len(),
            stage.defocus_um,
            exposure_ms
        );
        frame_number += 1;
    }
    tracing::info!(
        "virtual camera stopped after {frame_number} frames{}",
        pace.summary()
    );
    Ok(())
}

/// How far behind its triggers the virtual camera publishes: it renders each frame with
/// the full wave-optics model, and on a slow or busy machine that can take longer than
/// a step. A real camera exposes at the trigger whatever its host does and hands the
/// frame over late (or drops it when its buffer is full); this one stamps the trigger's
/// time, so its frames keep their labels, and says that they are late.
#[derive(Debug, Default)]
struct Pace {
    /// The earliest a trigger was seen, as (this host's instant − the trigger's
    /// controller µs): a trigger's host time is this plus its own µs.
    reference: Option<(Instant, u64)>,
    /// The step between the last two triggers, µs.
    step_us: u64,
    last_trigger_us: Option<u64>,
    late: u64,
    /// Late frames in a row (one late frame is a hiccup: the first frame's warm-up).
    in_a_row: u32,
    worst_ms: f64,
    warned: bool,
}

impl Pace {
    /// A trigger at `time_us` (controller clock) reached the camera at `now`.
    fn triggered(&mut self, time_us: u64, now: Instant) {
        if let Some(last) = self.last_trigger_us {
            self.step_us = time_us.saturating_sub(last);
        }
        self.last_trigger_us = Some(time_us);
        let earlier = self.reference.is_none_or(|(at, us)| {
            // This trigger's arrival implies an earlier host time for trigger 0.
            let implied = now.checked_sub(Duration::from_micros(time_us.saturating_sub(us)));
            implied.is_some_and(|i| i < at)
        });
        if earlier {
            self.reference = Some((now, time_us));
        }
    }

    /// The frame of the trigger at `time_us` is published at `now`: how late, ms, the
    /// first time three frames in a row are each later than a step (and 50 ms) after
    /// their trigger; None otherwise.
    fn published(&mut self, time_us: u64, now: Instant) -> Option<f64> {
        let (at, us) = self.reference?;
        let due = at + Duration::from_micros(time_us.saturating_sub(us));
        let late_ms = now.saturating_duration_since(due).as_secs_f64() * 1e3;
        if late_ms <= (self.step_us as f64 / 1e3).max(50.0) {
            self.in_a_row = 0;
            return None;
        }
        self.late += 1;
        self.in_a_row += 1;
        self.worst_ms = self.worst_ms.max(late_ms);
        (self.in_a_row >= 3 && !std::mem::replace(&mut self.warned, true)).then_some(late_ms)
    }

    /// What the log says at the end: the frames that were late, if any.
    fn summary(&self) -> String {
        match self.late {
            0 => String::new(),
            n => format!(
                "; {n} published more than a step after their trigger (the latest {:.0} ms)",
                self.worst_ms
            ),
        }
    }
}

/// The settings the virtual camera works with, in the document a GenICam camera's
/// driver publishes (`fpm camera run`).
fn applied_settings(
    a: &VirtualCamera,
    camera: &Camera,
    system: &System,
    width: usize,
    height: usize,
) -> AppliedSettings {
    let (w, h) = (width as i32, height as i32);
    AppliedSettings {
        vendor: "fpm".into(),
        model: "virtual camera".into(),
        serial: format!("seed {}", a.seed),
        pixel_format: format!("Mono{}", camera.bit_depth),
        bit_depth: Some(camera.bit_depth),
        bayer: None,
        roi: [0, 0, w, h],
        binning: [1, 1],
        // Auto-exposed frame by frame: each frame's header says.
        exposure_us: None,
        encoding_gamma: Some(camera.display_gamma.unwrap_or(1.0)),
        gain: None,
        trigger_mode: Some("On".into()),
        trigger_source: Some("Line0".into()),
        trigger_activation: Some("RisingEdge".into()),
        pixel_size_um: Some(system.pixel_size_um),
        channel: None,
        published_size: [w, h],
        published_pixel_factor: 1,
    }
}

/// A slide larger than one field, the stage's hidden error and the slide's tilt.
struct SlideScene {
    slide: ObjectField,
    seed: u64,
    stage_error_um: f64,
    /// The surface's height change per µm in x and y (toward the LEDs), µm/µm.
    tilt: (f64, f64),
    /// The field last rendered: its commanded position, the field, its renderer.
    current: Option<((i64, i64), ObjectField, Renderer)>,
}

impl SlideScene {
    fn new(system: &System, a: &VirtualCamera, slide_um: f64, size: usize) -> Result<Self> {
        let pixel = system.sample_pixel_um();
        let side = (slide_um / pixel).ceil() as usize;
        if !(size..=16_384).contains(&side) {
            anyhow::bail!("--slide-um {slide_um}: give a slide at least one field ({:.0} µm) and at most 16384 pixels wide", size as f64 * pixel);
        }
        let pad = 32;
        let slide = ObjectField::slide(
            system,
            side,
            pad,
            2,
            a.seed,
            fpm_physics::simulate::SampleKind::Cells,
        );
        let mut rng = rand::rngs::StdRng::seed_from_u64(a.seed ^ 0x0005_11DE);
        // A slide lies a little tilted.
        let angle = rng.gen_range(0.0..std::f64::consts::TAU);
        let t = a.slide_tilt_um_per_mm * 1e-3;
        let tilt = (t * angle.cos(), t * angle.sin());
        if let Some(dir) = &a.truth_dir {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
            let n = slide.n;
            let half = (n / 2) as f64 * slide.pitch_um();
            let region = slide
                .region(-half, -half, n, n)
                .context("the slide's own grid")?;
            fpm_host::dataset::image_io::write_tiff_f32(
                &dir.join("slide_amplitude.tif"),
                &region.mapv(|c| c.norm()),
            )?;
            fpm_host::dataset::image_io::write_tiff_f32(
                &dir.join("slide_phase.tif"),
                &region.mapv(|c| c.arg()),
            )?;
            std::fs::write(
                dir.join("slide.json"),
                serde_json::to_string_pretty(&serde_json::json!({
                    "pixel_um": slide.pitch_um(),
                    "origin_um": [-half, -half],
                    "tilt_um_per_mm": [tilt.0 * 1e3, tilt.1 * 1e3],
                    "stage_error_um": a.stage_error_um,
                }))?,
            )?;
            let _ = std::fs::remove_file(dir.join("stage.jsonl"));
        }
        Ok(Self {
            slide,
            seed: a.seed,
            stage_error_um: a.stage_error_um,
            tilt,
            current: None,
        })
    }

    /// Where the stage really goes when told (x, y): the same error each time it is
    /// told the same place (to the µm), up to `stage_error_um`.
    fn true_position(&self, x: f64, y: f64) -> (f64, f64) {
        let key = ((x.round() as i64) as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ ((y.round() as i64) as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
            ^ self.seed;
        let mut rng = rand::rngs::StdRng::seed_from_u64(key);
        let r = self.stage_error_um * rng.gen::<f64>().sqrt();
        let a = rng.gen_range(0.0..std::f64::consts::TAU);
        (x + r * a.cos(), y + r * a.sin())
    }

    /// The slide's surface height at slide position `at`, µm toward the LEDs.
    fn surface_at(&self, at: (f64, f64)) -> f64 {
        self.tilt.0 * at.0 + self.tilt.1 * at.1
    }

    /// The field under the stage told (x, y), its renderer, and the surface height
    /// there (µm toward the LEDs); a new position is logged to `truth_dir/stage.jsonl`.
    fn field_at(
        &mut self,
        x: f64,
        y: f64,
        size: usize,
        truth_dir: Option<&std::path::Path>,
    ) -> Result<(&ObjectField, &mut Renderer, f64)> {
        let key = ((x * 1e3).round() as i64, (y * 1e3).round() as i64);
        if self.current.as_ref().is_none_or(|c| c.0 != key) {
            let real = self.true_position(x, y);
            let (field, used) = self
                .slide
                .window(real, size, 32)
                .with_context(|| format!("the stage at ({x:.0}, {y:.0}) µm shows no slide (the virtual slide is {:.0} µm wide)", self.slide.camera as f64 * self.slide.camera_pixel_um))?;
            if let Some(dir) = truth_dir {
                use std::io::Write;
                let surface = self.surface_at(real);
                let mut f = std::fs::OpenOptions::new()
                    .create(true)
                    .append(true)
                    .open(dir.join("stage.jsonl"))?;
                writeln!(
                    f,
                    "{}",
                    serde_json::json!({"commanded_um": [x, y], "true_um": [used.0, used.1], "surface_um": surface})
                )?;
            }
            let renderer = Renderer::new(&field);
            self.current = Some((key, field, renderer));
        }
        let surface = self.surface_at(self.true_position(x, y));
        let (_, field, renderer) = self.current.as_mut().context("the field just made")?;
        Ok((field, renderer, surface))
    }
}

/// The virtual board's red and green dies, beside its blue one (which the board's grid
/// places, as single-colour runs have always taken it): the WS2812B's wavelengths,
/// die offsets and focal shifts ([`fpm_physics::color::ws2812b`]) relative to blue's.
/// A colour's sample is made (and its truth written) when it is first lit, so that a
/// run in one colour pays for none of it.
struct Dies {
    /// Red, then green.
    colors: Vec<Die>,
}

struct Die {
    /// The colour, its die offset and focal shift relative to blue's.
    channel: fpm_physics::color::Channel,
    /// The hidden array as this colour's dies sit.
    geometry: LedGeometry,
    /// The sample in this colour's light, once lit.
    sample: Option<ObjectField>,
}

impl Die {
    fn sample(&self) -> &ObjectField {
        self.sample.as_ref().expect("made by Dies::lit")
    }
}

impl Dies {
    fn new(hidden: &LedGeometry) -> Self {
        let table = fpm_physics::color::ws2812b();
        let blue = table.iter().find(|c| c.name == "blue").cloned();
        let colors = table
            .into_iter()
            .filter(|c| c.name != "blue")
            .map(|mut channel| {
                if let Some(blue) = &blue {
                    channel.die_offset_mm = [
                        channel.die_offset_mm[0] - blue.die_offset_mm[0],
                        channel.die_offset_mm[1] - blue.die_offset_mm[1],
                    ];
                    channel.focal_shift_um -= blue.focal_shift_um;
                }
                Die {
                    geometry: channel.geometry(hidden),
                    channel,
                    sample: None,
                }
            })
            .collect();
        Self { colors }
    }

    /// Colour `k` (0 red, 1 green), its sample made on first use and its truth (its
    /// dies' placement, the sample in its light) written into `truth_dir/<colour>/`.
    fn lit(
        &mut self,
        k: usize,
        system: &System,
        a: &VirtualCamera,
        sensor: &Sensor,
        size: usize,
    ) -> Result<&Die> {
        let die = &mut self.colors[k];
        if die.sample.is_none() {
            let sample = ObjectField::sample_in_light(
                system,
                size,
                32,
                2,
                a.seed,
                fpm_physics::simulate::SampleKind::Cells,
                die.channel.wavelength_um,
            );
            if let Some(dir) = &a.truth_dir {
                let sub = dir.join(&die.channel.name);
                std::fs::create_dir_all(&sub)
                    .with_context(|| format!("creating {}", sub.display()))?;
                write_truth_field(&sub, &sensor.crop_truth(&sample))?;
                std::fs::write(
                    sub.join("truth.json"),
                    serde_json::to_string_pretty(&a.truth(&die.geometry, &sample))?,
                )?;
            }
            die.sample = Some(sample);
        }
        Ok(die)
    }
}

/// Where a `width × height` sensor sits on the square `size²` rendered field: centred,
/// so that its optical axis (width/2, height/2) is the field's (size/2, size/2).
#[derive(Debug, Clone, Copy)]
struct Sensor {
    x0: usize,
    y0: usize,
    width: usize,
    height: usize,
}

impl Sensor {
    fn centred(size: usize, width: usize, height: usize) -> Self {
        Self {
            x0: size / 2 - width / 2,
            y0: size / 2 - height / 2,
            width,
            height,
        }
    }

    /// The sample's truth under the sensor, at the simulation's finer pixel.
    fn crop_truth(&self, object: &ObjectField) -> ndarray::Array2<rustfft::num_complex::Complex32> {
        let u = object.upsample;
        object
            .crop_to_camera()
            .slice(ndarray::s![
                self.y0 * u..(self.y0 + self.height) * u,
                self.x0 * u..(self.x0 + self.width) * u
            ])
            .to_owned()
    }

    fn crop(&self, field: &fpm_physics::Image) -> fpm_physics::Image {
        field
            .slice(ndarray::s![
                self.y0..self.y0 + self.height,
                self.x0..self.x0 + self.width
            ])
            .to_owned()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_falling_behind_their_triggers_are_said_once_and_every_late_one_counted() {
        let start = Instant::now();
        let at = |ms: u64| start + Duration::from_millis(ms);
        let mut pace = Pace::default();
        // Triggers 40 ms apart on the controller's clock, seen 1 ms after they fire;
        // the first frame rendered in 60 ms (a warm-up: late once, not said), the next
        // two in 10 ms.
        pace.triggered(5_000_000, at(1));
        assert_eq!(pace.published(5_000_000, at(61)), None);
        for k in 1..3u64 {
            pace.triggered(5_000_000 + k * 40_000, at(1 + k * 40));
            let published = pace.published(5_000_000 + k * 40_000, at(11 + k * 40));
            assert_eq!(published, None);
        }
        // Then rendering takes 70 ms a frame: the camera falls behind, by 30 ms more
        // each frame; the third frame in a row more than 50 ms late is said, once.
        let mut said = vec![];
        let mut done = 81;
        for k in 3..10u64 {
            let trigger = 5_000_000 + k * 40_000;
            pace.triggered(trigger, at(1 + k * 40).max(at(done)));
            done += 70;
            if let Some(ms) = pace.published(trigger, at(done)) {
                said.push((k, ms.round()));
            }
        }
        assert_eq!(said, vec![(6, 120.0)]);
        assert_eq!(pace.late, 7);
        assert!(pace.summary().contains("7 published more than a step"));
    }
}
