//! The virtual microscope (`fpm demo`), as a library: the emulated LED controller (a
//! process on a pseudo-terminal, the host-compiled logic or the real firmware image in
//! an emulated RP2040) and the virtual camera (a process rendering with the wave-optics
//! model, frames over iceoryx2) on one virtual rig with a hidden, misplaced LED array;
//! an acquisition [`Plan`] run against them (pdcFPM calibration, every LED labelled,
//! streaming reconstruction); the result scored against the hidden truth. Front ends
//! print the [`DemoEvent`]s as they come and the [`DemoReport`] at the end.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use fpm_acquire::controller::Controller;
use fpm_acquire::pipeline::{acquire, AcquireSummary, Control, Plan};
use fpm_acquire::Progress;
use fpm_frames::ServiceNames;
use fpm_host::dataset::Dataset;
use fpm_host::reconstruction::{GeometryChoice, Job};
use fpm_host::truth::Truth;
use fpm_physics::reconstruct::{Flatten, Settings};
use fpm_physics::{LedGeometry, System};
use fpm_protocol::{DeviceInfo, Half, LinkStats, Lit, Pattern, Rgb};
use serde::Serialize;

use crate::process::{EmulatorProcess, VirtualCameraProcess};
use crate::stage::VirtualStage;

/// What the demo runs.
#[derive(Debug, Clone)]
pub struct Demo {
    /// Where to write the dataset and results (None: a new directory under /tmp).
    pub out: Option<PathBuf>,
    /// Seed of the hidden LED array misplacement, the sample and the noise.
    pub seed: u64,
    /// Sensor side of the virtual camera, pixels.
    pub size: usize,
    /// How long each LED stays lit, ms.
    pub step_ms: f64,
    /// Emulated camera exposure on the trigger-in line, µs.
    pub exposure_us: u32,
    /// WS2812 data lanes on the emulated board.
    pub lanes: u8,
    /// The firmware image (UF2) to run in an emulated RP2040 as the controller (None:
    /// the host-compiled controller logic).
    pub firmware: Option<PathBuf>,
}

impl Default for Demo {
    fn default() -> Self {
        Self {
            out: None,
            seed: 1,
            size: 256,
            step_ms: 40.0,
            exposure_us: 2_000,
            lanes: 1,
            firmware: None,
        }
    }
}

/// The smallest sensor the demo's calibration works on: the defocused feature must
/// stay inside the field under every bright-field LED.
pub const MIN_SIZE: usize = 192;
/// The largest: a 4096² sensor's frames are 32 MiB each, 441 of them.
pub const MAX_SIZE: usize = 4096;

impl Demo {
    /// Every setting in its range, or an error naming it.
    pub fn validate(&self) -> Result<()> {
        if !(MIN_SIZE..=MAX_SIZE).contains(&self.size) {
            bail!(
                "--size {}: the virtual camera's sensor must be {MIN_SIZE}-{MAX_SIZE} px (the calibration's defocused feature leaves a smaller field)",
                self.size
            );
        }
        if !(self.step_ms.is_finite() && (5.0..=10_000.0).contains(&self.step_ms)) {
            bail!("--step-ms {}: must be 5-10000 ms", self.step_ms);
        }
        if self.exposure_us == 0 || f64::from(self.exposure_us) / 1e3 >= self.step_ms {
            bail!(
                "--exposure-us {}: must be above 0 and shorter than a step ({} ms)",
                self.exposure_us,
                self.step_ms
            );
        }
        if !matches!(self.lanes, 1 | 2 | 4) {
            bail!(
                "--lanes {}: the board wires 1, 2 or 4 data lanes",
                self.lanes
            );
        }
        if let Some(uf2) = &self.firmware {
            if !uf2.is_file() {
                bail!(
                    "--firmware {}: no such file (build the image with `cargo build --release` in firmware/rp2040, then `cargo run -p fpm-fwtool -- uf2 ELF UF2`; docs/hardware.md)",
                    uf2.display()
                );
            }
        }
        Ok(())
    }
}

/// The controller as the demo found it.
#[derive(Debug, Clone, Serialize)]
pub struct ControllerReport {
    /// What the controller says it is.
    pub info: DeviceInfo,
    /// Its serial port (the emulator's link).
    pub port: String,
    /// The real firmware image in an emulated RP2040 (else the host-compiled logic).
    pub firmware_image: bool,
    /// Objective NA the patterns were computed for.
    pub na: f32,
    /// Patterns computed on the device: bright-field, dark-field, a DPC half.
    pub bright_field: Lit,
    /// See [`ControllerReport::bright_field`].
    pub dark_field: Lit,
    /// See [`ControllerReport::bright_field`].
    pub dpc_half: Lit,
    /// Request round trips over the link, µs: median and 99th percentile of 500.
    pub round_trip_p50_us: f64,
    /// See [`ControllerReport::round_trip_p50_us`].
    pub round_trip_p99_us: f64,
    /// The link's counters after the pings.
    pub link: LinkStats,
}

/// Complex NRMSE of reconstructions against the hidden sample.
#[derive(Debug, Clone, Serialize)]
pub struct Quality {
    /// With the nominal (uncalibrated) array.
    pub nominal: Option<f64>,
    /// With the array pdcFPM recovered.
    pub calibrated: Option<f64>,
    /// The image streamed while acquiring (report.json's versus_truth).
    pub streamed: Option<f64>,
}

/// What the demo did.
#[derive(Debug, Clone, Serialize)]
pub struct DemoReport {
    /// The controller.
    pub controller: ControllerReport,
    /// Where everything was written.
    pub out: PathBuf,
    /// The array as the virtual camera hid it.
    pub hidden_array: Truth,
    /// The array the acquisition used (pdcFPM's).
    pub recovered_array: LedGeometry,
    /// The acquisition.
    pub acquisition: AcquireSummary,
    /// Seconds the acquisition took (calibration, capture, streaming).
    pub acquisition_seconds: f64,
    /// Against the hidden sample.
    pub complex_nrmse: Quality,
    /// truth | nominal | calibrated, amplitude above phase (None: it could not be drawn).
    pub picture: Option<PathBuf>,
    /// The HTML reports written.
    pub reports: Vec<PathBuf>,
}

/// What the demo tells a front end as it goes.
#[derive(Debug)]
pub enum DemoEvent<'a> {
    /// The controller answered.
    Controller(&'a ControllerReport),
    /// The virtual camera runs, `size`² pixels.
    Camera {
        /// Sensor side, pixels.
        size: usize,
    },
    /// Frames of the acquisition so far.
    Frames {
        /// Done.
        done: usize,
        /// In all.
        total: usize,
    },
}

/// Run the demo; `fpm` is the `fpm` executable (the rig's processes are its
/// subcommands).
pub fn run(demo: &Demo, fpm: &Path, mut on_event: impl FnMut(DemoEvent<'_>)) -> Result<DemoReport> {
    demo.validate()?;
    let rig = format!("demo-{}", std::process::id());
    let out = demo
        .out
        .clone()
        .unwrap_or_else(|| std::env::temp_dir().join(format!("fpm-demo-{}", std::process::id())));
    if out.join("dataset.toml").exists() || out.join("truth.json").exists() {
        bail!(
            "{} already holds a dataset; pick another --out",
            out.display()
        );
    }
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let emulator = start_emulator(demo, fpm, &rig)?;
    let controller = probe_controller(demo, &emulator)?;
    on_event(DemoEvent::Controller(&controller));
    let (seed, size) = (demo.seed.to_string(), demo.size.to_string());
    let camera =
        VirtualCameraProcess::start(fpm, &rig, &rig, &out, &["--seed", &seed, "--size", &size])?;
    on_event(DemoEvent::Camera { size: demo.size });
    let plan = plan(demo, &rig, &out);
    let dev = Controller::open(&controller.port, Duration::from_secs(2))?;
    let mut stage = VirtualStage::open(&rig)?;
    let start = Instant::now();
    let on_progress = |p: &Progress| {
        on_event(DemoEvent::Frames {
            done: p.frames,
            total: p.of,
        })
    };
    let acquisition = acquire(&dev, &mut stage, &plan, on_progress, &Control::new())?;
    let acquisition_seconds = start.elapsed().as_secs_f64();
    drop((camera, dev, emulator));
    let hidden_array = Truth::find(&out)?.context("the virtual camera wrote no truth.json")?;
    let (complex_nrmse, picture) = score(&out, &acquisition.geometry, plan.flatten)?;
    let reports = [
        "acquisition.html",
        "calibration.html",
        "reconstruction/report.html",
    ]
    .iter()
    .map(|p| out.join(p))
    .filter(|p| p.is_file())
    .collect();
    Ok(DemoReport {
        controller,
        out,
        hidden_array,
        recovered_array: acquisition.geometry,
        acquisition,
        acquisition_seconds,
        complex_nrmse,
        picture,
        reports,
    })
}

/// The emulated controller on the rig `rig`.
fn start_emulator(demo: &Demo, fpm: &Path, rig: &str) -> Result<EmulatorProcess> {
    let exposure = demo.exposure_us.to_string();
    let lanes = demo.lanes.to_string();
    let firmware = demo
        .firmware
        .as_ref()
        .map(|p| p.to_string_lossy().into_owned());
    let mut options = vec!["--camera-exposure-us", &exposure, "--rig", rig];
    match &firmware {
        Some(uf2) => options.extend(["--firmware", uf2.as_str()]),
        None => options.extend(["--lanes", lanes.as_str()]),
    }
    let link = std::env::temp_dir().join(format!("fpm-emulator-{}.tty", std::process::id()));
    EmulatorProcess::start_at(fpm, &link, &options, std::process::Stdio::null())
}

/// What the controller says, the patterns a microscopist uses computed on the device
/// from its geometry, and the link's round trips.
fn probe_controller(demo: &Demo, emulator: &EmulatorProcess) -> Result<ControllerReport> {
    let port = emulator.port();
    let dev = Controller::open(&port, Duration::from_secs(2))?;
    let na = 0.1;
    let bright_field = dev.pattern(Pattern::BrightField { na }, Rgb::WHITE)?;
    let dark_field = dev.pattern(Pattern::DarkField { na }, Rgb::new(2, 2, 2))?;
    let dpc_half = dev.pattern(
        Pattern::HalfCircle {
            na,
            half: Half::Left,
        },
        Rgb::WHITE,
    )?;
    dev.clear()?;
    let mut rtt = dev.ping_round_trips(50, 500)?;
    let [p50, p99] = fpm_physics::stats::quantiles(&mut rtt, [0.5, 0.99]).unwrap_or([f64::NAN; 2]);
    Ok(ControllerReport {
        info: dev.info().clone(),
        port,
        firmware_image: demo.firmware.is_some(),
        na,
        bright_field,
        dark_field,
        dpc_half,
        round_trip_p50_us: p50,
        round_trip_p99_us: p99,
        link: dev.status()?.link,
    })
}

/// The acquisition the demo runs: calibrate, acquire, reconstruct while acquiring.
fn plan(demo: &Demo, rig: &str, out: &Path) -> Plan {
    Plan {
        camera: ServiceNames::for_camera(rig),
        out: out.to_path_buf(),
        capture: true,
        calibrate: true,
        store_geometry: false,
        reconstruct: true,
        step_ms: demo.step_ms,
        defocus_um: 200.0,
        // The virtual stage moves exactly.
        defocus_sigma_um: 0.0,
        color: Rgb::new(0, 0, 255),
        dark_level: 100.0,
        system: System {
            wavelength_um: 0.47,
            na: 0.1,
            magnification: 4.0,
            pixel_size_um: 2.4,
            entrance_pupil_mm: None,
        },
        passes: 5,
        tile: None,
        // The hidden sample is cells and bars on clear glass.
        flatten: Flatten::Auto,
        snapshot_every: 0,
        leds: None,
        multiplex: fpm_physics::multiplex::Multiplex::ONE,
    }
}

/// The dataset reconstructed with the nominal and with the calibrated array (same
/// passes), both scored against the hidden sample, and the comparison picture.
fn score(
    out: &Path,
    calibrated: &LedGeometry,
    flatten: Flatten,
) -> Result<(Quality, Option<PathBuf>)> {
    let ds = Dataset::load(out)?;
    let nominal = ds.manifest.geometry();
    let settings = Settings {
        flatten,
        ..Settings::default()
    };
    let run = |geometry: &LedGeometry, name: &str| {
        let job = Job {
            geometry: GeometryChoice::Given(*geometry, name.into()),
            settings,
            passes: 10,
            ..Job::default()
        };
        job.run_in_memory(&ds, &|_, _| {})
    };
    let (with_nominal, with_calibrated) =
        (run(&nominal, "nominal")?, run(calibrated, "calibrated")?);
    let nrmse = |r: &fpm_host::reconstruction::Reconstruction| {
        r.report.versus_truth.as_ref().map(|s| s.complex_nrmse)
    };
    // The acquisition scored its streamed image already (report.json, versus_truth).
    let streamed = std::fs::read_to_string(out.join("reconstruction").join("report.json"))
        .ok()
        .and_then(|text| serde_json::from_str::<serde_json::Value>(&text).ok())
        .and_then(|report| report["versus_truth"]["complex_nrmse"].as_f64());
    let quality = Quality {
        nominal: nrmse(&with_nominal),
        calibrated: nrmse(&with_calibrated),
        streamed,
    };
    // The picture is an extra: a failure to draw it is a warning.
    let picture = out.join("comparison.png");
    let drawn = fpm_report::comparison::write_comparison(
        &ds,
        &[
            ("Nominal", &with_nominal.object),
            ("Calibrated", &with_calibrated.object),
        ],
        settings.upsample,
        &picture,
    );
    if let Err(e) = &drawn {
        tracing::warn!("no comparison picture: {e:#}");
    }
    Ok((quality, drawn.is_ok().then_some(picture)))
}
