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

use crate::process::{EmulatorProcess, VirtualCameraProcess, BUILD_FIRMWARE_IMAGE};
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
                    "--firmware {}: no such file ({BUILD_FIRMWARE_IMAGE})",
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
        // Paced to the wall clock, as a board is (unpaced, the emulator runs the
        // sequence several times faster than real time and the camera trails it).
        Some(uf2) => options.extend(["--firmware", uf2.as_str(), "--real-time"]),
        None => options.extend(["--lanes", lanes.as_str()]),
    }
    // Named by its rig: rigs side by side in one process get links of their own.
    let link = std::env::temp_dir().join(format!("fpm-emulator-{rig}.tty"));
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
        geometry: None,
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

/// The whole-slide demo (`fpm demo --scan`): the virtual rig with a slide larger than
/// one field and a stage that misses its positions, a scan of `rows × cols` fields
/// (calibrated at the first, each reconstructed while the next is acquired), stitched,
/// and the mosaic scored against the hidden slide beside the fields' own.
#[derive(Debug, Clone)]
pub struct ScanDemo {
    /// Where to write the scan (None: a new directory under /tmp).
    pub out: Option<PathBuf>,
    pub seed: u64,
    /// Sensor side, pixels.
    pub size: usize,
    pub rows: usize,
    pub cols: usize,
    pub overlap: f64,
    /// The virtual stage's hidden XY error, up to, µm.
    pub stage_error_um: f64,
    /// Light only the central LEDS × LEDS of the array per field (None: all).
    pub leds: Option<usize>,
    /// Reconstruct each field while the next is acquired (false: all fields after the
    /// scan, one after another; the benchmark's baseline).
    pub reconstruct_while_scanning: bool,
    /// The slide's tilt, µm per mm (the focus the scan follows).
    pub tilt_um_per_mm: f64,
    /// Focus each field before acquiring it.
    pub autofocus: bool,
}

impl Default for ScanDemo {
    fn default() -> Self {
        Self {
            out: None,
            seed: 1,
            size: MIN_SIZE,
            rows: 3,
            cols: 3,
            overlap: 0.3,
            stage_error_um: 10.0,
            leds: None,
            reconstruct_while_scanning: true,
            tilt_um_per_mm: 3.0,
            autofocus: true,
        }
    }
}

/// What the scan demo did.
#[derive(Debug, Clone, Serialize)]
pub struct ScanDemoReport {
    pub out: PathBuf,
    pub scan: fpm_acquire::scan::ScanSummary,
    pub stitch: fpm_host::scan::StitchReport,
    /// From the first move to the stitched mosaic (its scoring included), s.
    pub seconds: f64,
}

/// Run the scan demo; `on_field(done, total)` as fields are acquired.
pub fn run_scan(
    demo: &ScanDemo,
    fpm: &Path,
    mut on_field: impl FnMut(usize, usize),
) -> Result<ScanDemoReport> {
    if !(MIN_SIZE..=1024).contains(&demo.size) {
        bail!(
            "--size {}: a scan's fields must be {MIN_SIZE}-1024 px",
            demo.size
        );
    }
    // One rig per scan, also for scans run side by side in one process.
    static SCANS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let n = SCANS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let rig = format!("scan-{}-{n}", std::process::id());
    let out = demo.out.clone().unwrap_or_else(|| {
        std::env::temp_dir().join(format!("fpm-scan-demo-{}", std::process::id()))
    });
    if out.join("scan.json").exists() {
        bail!("{} already holds a scan; pick another --out", out.display());
    }
    let camera_truth = out.join("rig-truth");
    let system = plan(&Demo::default(), &rig, &out).system;
    let field_um = demo.size as f64 * system.sample_pixel_um();
    // The slide: every field and the stage's error either way, and a margin.
    let span = |n: usize| field_um * (1.0 + (n as f64 - 1.0) * (1.0 - demo.overlap));
    let slide_um = span(demo.rows.max(demo.cols)) + 2.0 * demo.stage_error_um + 60.0;
    let emulator = start_emulator(&Demo::default(), fpm, &rig)?;
    let (seed, size, slide, error, tilt) = (
        demo.seed.to_string(),
        demo.size.to_string(),
        format!("{slide_um:.0}"),
        demo.stage_error_um.to_string(),
        demo.tilt_um_per_mm.to_string(),
    );
    let camera = VirtualCameraProcess::start(
        fpm,
        &rig,
        &rig,
        &camera_truth,
        &[
            "--seed",
            &seed,
            "--size",
            &size,
            "--slide-um",
            &slide,
            "--stage-error-um",
            &error,
            "--slide-tilt-um-per-mm",
            &tilt,
        ],
    )?;
    let dev = Controller::open(&emulator.port(), Duration::from_secs(2))?;
    let mut stage = VirtualStage::open(&rig)?;
    // The scan's first field at the slide's centre less half the grid.
    let start = (
        -(span(demo.cols) - field_um) / 2.0,
        -(span(demo.rows) - field_um) / 2.0,
    );
    fpm_stage::Stage::move_to(&mut stage, fpm_stage::Target::xy(start.0, start.1))?;
    let mut field = plan(&Demo::default(), &rig, &out);
    field.reconstruct = demo.reconstruct_while_scanning;
    if let Some(n) = demo.leds {
        let c = 10i32;
        let h = (n / 2) as i32;
        field.leds = Some(
            (c - h..=c + h)
                .flat_map(|r| {
                    (c - h..=c + h).map(move |k| fpm_physics::LedIndex::new(r as u8, k as u8))
                })
                .collect(),
        );
    }
    let job = Job {
        settings: Settings {
            flatten: field.flatten,
            ..Settings::default()
        },
        passes: 10,
        ..Job::default()
    };
    let scan_plan = fpm_acquire::scan::ScanPlan {
        rows: demo.rows,
        cols: demo.cols,
        overlap: demo.overlap,
        field,
        job: job.clone(),
        // Stitched below, once the rig's truth is beside the fields to score it.
        stitch: None,
        autofocus: demo.autofocus,
    };
    let total = demo.rows * demo.cols;
    let started = Instant::now();
    let summary = fpm_acquire::scan::run(
        &dev,
        &mut stage,
        &scan_plan,
        &mut |e| {
            if let fpm_acquire::scan::ScanEvent::Moving { index, .. } = e {
                on_field(index, total)
            }
        },
        &Control::new(),
    )?;
    on_field(total, total);
    drop((camera, dev, emulator));
    let options = fpm_host::scan::StitchOptions {
        job,
        settings: fpm_physics::stitch::Settings {
            stage_sigma_um: demo.stage_error_um.max(1.0) / 2.0,
            ..Default::default()
        },
        redo: false,
        field_memory_bytes: fpm_host::scan::FIELD_MEMORY_BYTES,
    };
    // The rig's truth beside the fields first (its writing not counted), so that one
    // stitch reconstructs what the scan did not and scores it all.
    let truth_started = Instant::now();
    write_scan_truth(&out, &camera_truth)?;
    let truth_took = truth_started.elapsed();
    let reproduce = format!("fpm stitch {}", out.display());
    let (stitched, _page) =
        fpm_report::slide::stitch(&out, &options, &out.join("mosaic"), &reproduce, &mut |_| {})?;
    let seconds = (started.elapsed() - truth_took).as_secs_f64();
    Ok(ScanDemoReport {
        out,
        scan: summary,
        stitch: stitched.report,
        seconds,
    })
}

/// The rig's hidden truth as a simulated scan keeps it: `truth/` (the slide, where
/// each field really was) and each field's own truth (its part of the slide).
fn write_scan_truth(out: &Path, camera_truth: &Path) -> Result<()> {
    use fpm_host::dataset::image_io;
    let manifest = fpm_host::scan::ScanManifest::read(out)?;
    let slide_json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(camera_truth.join("slide.json"))?)?;
    let pixel = slide_json["pixel_um"]
        .as_f64()
        .context("slide.json: pixel_um")?;
    let origin = [
        slide_json["origin_um"][0]
            .as_f64()
            .context("slide.json: origin_um")?,
        slide_json["origin_um"][1]
            .as_f64()
            .context("slide.json: origin_um")?,
    ];
    let moves: Vec<([f64; 2], [f64; 2])> =
        std::fs::read_to_string(camera_truth.join("stage.jsonl"))?
            .lines()
            .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
            .filter_map(|v| {
                let p = |k: &str, i: usize| v[k][i].as_f64();
                Some((
                    [p("commanded_um", 0)?, p("commanded_um", 1)?],
                    [p("true_um", 0)?, p("true_um", 1)?],
                ))
            })
            .collect();
    let slide = image_io::read_complex(
        &camera_truth.join("slide_amplitude.tif"),
        &camera_truth.join("slide_phase.tif"),
    )?;
    let hidden: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(camera_truth.join("truth.json"))?)?;
    let mut true_um = Vec::new();
    for f in &manifest.fields {
        let (_, real) = moves
            .iter()
            .rev()
            .find(|(c, _)| {
                (c[0] - f.stage_um[0]).abs() < 1e-3 && (c[1] - f.stage_um[1]).abs() < 1e-3
            })
            .with_context(|| format!("the rig never rendered field {}", f.dataset))?;
        true_um.push(*real);
        // The field's own truth: its part of the slide, at the simulation's pixel.
        let dir = out.join(&f.dataset);
        let ds = fpm_host::dataset::DatasetOnDisk::open(&dir)?;
        let (h, w) = ds.dim();
        let (th, tw) = (2 * h, 2 * w);
        let c0 = ((real[0] - origin[0]) / pixel).round() as usize - tw / 2;
        let r0 = ((real[1] - origin[1]) / pixel).round() as usize - th / 2;
        let cut = slide
            .slice(ndarray::s![r0..r0 + th, c0..c0 + tw])
            .to_owned();
        fpm_host::truth::write_truth_field(&dir, &cut)?;
        let mut t = hidden.clone();
        t["object_pixel_um"] = serde_json::json!(pixel);
        std::fs::write(dir.join("truth.json"), serde_json::to_string_pretty(&t)?)?;
    }
    let truth_dir = out.join("truth");
    std::fs::create_dir_all(&truth_dir)?;
    std::fs::copy(
        camera_truth.join("slide_amplitude.tif"),
        truth_dir.join("slide_amplitude.tif"),
    )?;
    std::fs::copy(
        camera_truth.join("slide_phase.tif"),
        truth_dir.join("slide_phase.tif"),
    )?;
    let truth = fpm_host::scan::SlideTruth {
        pixel_um: pixel,
        origin_um: origin,
        true_um,
    };
    std::fs::write(
        truth_dir.join("slide.json"),
        serde_json::to_string_pretty(&truth)?,
    )?;
    Ok(())
}
