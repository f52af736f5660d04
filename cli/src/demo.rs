//! `fpm demo`: the virtual microscope, with no hardware: the emulated LED controller
//! (a process on a pseudo-terminal) and the virtual camera (a process rendering with
//! the wave-optics model, frames over iceoryx2), a hidden misplaced LED array, then
//! `fpm acquire --calibrate --reconstruct` against them and the result against the
//! hidden truth.

use std::time::{Duration, Instant};

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Args;
use fpm_physics::reconstruct::Settings;
use fpm_physics::LedGeometry;
use fpm_protocol::*;

use crate::acquire::{acquire, AcquireArgs, StageKind};
use crate::flatten::FlattenArgs;
use fpm_acquire::controller::Controller;
use fpm_host::dataset::Dataset;
use fpm_host::reconstruction::reconstruct;
use fpm_host::truth::score_reconstruction;
use fpm_rig::process::{ChildProcess, EmulatorProcess, Ready};

/// Run the virtual microscope.
#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Where to write the dataset and results [default: a new directory under /tmp].
    #[arg(long)]
    out: Option<PathBuf>,
    /// Seed of the hidden LED array misplacement, the sample and the noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Sensor size of the virtual camera, pixels.
    #[arg(long, default_value_t = 256)]
    size: usize,
    /// How long each LED stays lit, ms.
    #[arg(long, default_value_t = 40.0)]
    step_ms: f64,
    /// Emulated camera exposure on the trigger-in line, µs.
    #[arg(long, default_value_t = 2_000)]
    exposure_us: u32,
    /// WS2812 data lanes on the emulated board (more lanes switch LEDs faster).
    #[arg(long, default_value_t = 1)]
    lanes: u8,
    /// Run the real firmware image (the UF2 users flash) in an emulated RP2040 as the
    /// LED controller, instead of the host-compiled controller logic.
    #[arg(long)]
    firmware: Option<PathBuf>,
    /// Print one JSON object at the end (the controller, the hidden and recovered
    /// arrays, the acquisition summary, the quality, the output paths) instead of text.
    #[arg(long)]
    json: bool,
}

/// `println!` unless the demo prints JSON.
macro_rules! say {
    ($json:expr, $($arg:tt)*) => {
        if !$json {
            println!($($arg)*);
        }
    };
}

/// Run the demo.
pub fn run(a: DemoArgs) -> Result<()> {
    say!(
        a.json,
        "fpm demo: a virtual FPM microscope, no hardware needed\n"
    );
    let exposure = a.exposure_us.to_string();
    let lanes = a.lanes.to_string();
    let rig = format!("demo-{}", std::process::id());
    let firmware = a
        .firmware
        .as_ref()
        .map(|p| p.to_string_lossy().into_owned());
    let mut options = vec!["--camera-exposure-us", &exposure, "--rig", &rig];
    match &firmware {
        Some(uf2) => options.extend(["--firmware", uf2.as_str()]),
        None => options.extend(["--lanes", lanes.as_str()]),
    }
    let emulator = EmulatorProcess::start(&options)?;
    let port = emulator.link.to_string_lossy().into_owned();
    let dev = Controller::open(&port, Duration::from_secs(2))?;
    let info = dev.info().clone();
    let g = info.geometry;
    say!(a.json,
        "LED controller  {} ({}, separate process) on {port}\n                firmware {}, protocol {}, {}x{} LEDs at {:.1} mm pitch, {} lane(s)",
        info.board,
        if a.firmware.is_some() {
            "the real firmware image in an emulated RP2040"
        } else {
            "host-compiled emulator"
        },
        info.firmware,
        info.protocol,
        g.rows,
        g.cols,
        g.pitch_um as f64 / 1000.0,
        g.lanes
    );

    // Patterns a microscopist uses, computed on the device from its geometry.
    let na = 0.1;
    let bf = dev.pattern(Pattern::BrightField { na }, Rgb::WHITE)?;
    let df = dev.pattern(Pattern::DarkField { na }, Rgb::new(2, 2, 2))?;
    let dpc = dev.pattern(
        Pattern::HalfCircle {
            na,
            half: Half::Left,
        },
        Rgb::WHITE,
    )?;
    dev.clear()?;
    say!(a.json,
        "patterns        objective NA {na}: bright-field {} LEDs ({} mA), dark-field {} LEDs, DPC half {} LEDs",
        bf.leds_on, bf.current_ma, df.leds_on, dpc.leds_on
    );

    let rtt = fpm_bench::Percentiles::of(&mut dev.ping_round_trips(50, 500)?);
    say!(
        a.json,
        "link            request round-trip p50 {:.0} µs, p99 {:.0} µs (500 pings)",
        rtt.p50_us,
        rtt.p99_us
    );
    let link = dev.status()?.link;
    say!(
        a.json,
        "                {} frames, {} dropped, {} unknown keys, {} decode errors",
        link.frames_ok,
        link.frames_dropped,
        link.unknown_keys,
        link.decode_errors
    );
    drop(dev);
    let microscope = virtual_microscope(&a, &emulator)?;
    drop(emulator);
    if a.json {
        let mut all = microscope;
        all["controller"] = serde_json::json!(info);
        all["link_round_trip_us"] = serde_json::json!({"p50": rtt.p50_us, "p99": rtt.p99_us});
        println!("{}", serde_json::to_string_pretty(&all)?);
    }
    Ok(())
}

/// The full virtual microscope: the virtual camera as a second process on the rig the
/// emulator publishes, `fpm acquire --calibrate --reconstruct` against both, and the
/// result compared with the hidden truth.
fn virtual_microscope(a: &DemoArgs, emulator: &EmulatorProcess) -> Result<serde_json::Value> {
    let id = format!("demo-{}", std::process::id());
    let out = a
        .out
        .clone()
        .unwrap_or_else(|| std::env::temp_dir().join(format!("fpm-demo-{}", std::process::id())));
    if out.join("dataset.toml").exists() || out.join("truth.json").exists() {
        bail!(
            "{} already holds a dataset; pick another --out",
            out.display()
        );
    }
    std::fs::create_dir_all(&out)?;
    let seed = a.seed.to_string();
    let size = a.size.to_string();
    let out_s = out.to_string_lossy().into_owned();
    let fpm = std::env::current_exe().context("locating the fpm executable")?;
    let camera = ChildProcess::fpm(
        &fpm,
        &[
            "virtual-camera",
            "--rig",
            &id,
            "--camera",
            &id,
            "--seed",
            &seed,
            "--size",
            &size,
            "--truth-dir",
            &out_s,
        ],
        "virtual camera",
        Ready::FileExists(&out.join("truth.json"), Duration::from_secs(30)),
    )?;
    say!(a.json,
        "virtual camera  {}² frames, wave-optics model, realistic noise (separate process, iceoryx2 shared memory)",
        a.size
    );
    let args = AcquireArgs {
        port: Some(emulator.link.to_string_lossy().into_owned()),
        json: false,
        frames: id.clone(),
        out: out.clone(),
        calibrate: true,
        store_geometry: false,
        reconstruct: true,
        stage: StageKind::Virtual,
        rig: Some(id.clone()),
        step_ms: a.step_ms,
        defocus_um: 200.0,
        // The virtual stage moves exactly.
        defocus_sigma_um: 0.0,
        color: Rgb::new(0, 0, 255),
        dark_level: 100.0,
        wavelength_um: 0.47,
        na: 0.1,
        magnification: 4.0,
        pixel_um: 2.4,
        entrance_pupil_mm: None,
        passes: 5,
        tile: None,
        // The hidden sample is cells and bars on clear glass.
        flatten: FlattenArgs {
            flatten_background: true,
            background_block_um: None,
        },
    };
    let start = Instant::now();
    let summary = acquire(&args)?;
    let acquired = start.elapsed();
    drop(camera);

    let truth =
        fpm_host::truth::Truth::find(&out)?.context("the virtual camera wrote no truth.json")?;
    let g = summary.geometry;
    say!(
        a.json,
        "\nLED array       hidden truth                 recovered by pdcFPM"
    );
    say!(
        a.json,
        "  Δx            {:>8.3} mm                 {:>8.3} mm",
        truth.dx_mm,
        g.dx_mm
    );
    say!(
        a.json,
        "  Δy            {:>8.3} mm                 {:>8.3} mm",
        truth.dy_mm,
        g.dy_mm
    );
    say!(
        a.json,
        "  θ             {:>8.3}°                   {:>8.3}°",
        truth.theta_deg,
        g.theta_deg
    );
    say!(
        a.json,
        "  h             {:>8.2} mm                 {:>8.2} mm",
        truth.height_mm,
        g.height_mm
    );
    let c = &summary.capture;
    let cal_frames: usize = summary.calibration.iter().map(|r| r.labelled).sum();
    say!(a.json,
        "\nacquisition     {} calibration frames, then {}/{} LEDs labelled in {:.1} s ({:.1} frames/s); missing {}, extra {}, ambiguous {}",
        cal_frames, c.labelled, c.requested, c.seconds, c.frames_per_s, c.missing.len(), c.extra_frames, c.ambiguous_frames
    );
    if let (Some(ms), Some(us)) = (summary.last_frame_to_final_ms, summary.update_us_mean) {
        say!(a.json, "streaming EPRY  {us:.0} µs per frame as it arrived; last frame → final image {ms:.0} ms");
    }

    // Quality against the hidden sample: nominal vs calibrated geometry, same passes.
    let ds = Dataset::load(&out)?;
    let nominal = ds.manifest.geometry();
    let settings = Settings {
        flatten: args.flatten.flatten(),
        ..Settings::default()
    };
    let run =
        |geometry: &LedGeometry| reconstruct(&ds, geometry, "demo", settings, 10, None, &|_, _| {});
    let (with_nominal, with_calibrated) = (run(&nominal)?, run(&g)?);
    let score =
        |object| score_reconstruction(&ds, object, settings.upsample).map(|s| s.complex_nrmse);
    let (n, k) = (score(&with_nominal.object), score(&with_calibrated.object));
    // The acquisition scored its streamed image already (report.json, versus_truth).
    let streamed = std::fs::read_to_string(out.join("reconstruction").join("report.json"))
        .ok()
        .and_then(|text| serde_json::from_str::<serde_json::Value>(&text).ok())
        .and_then(|report| report["versus_truth"]["complex_nrmse"].as_f64());
    if let (Some(n), Some(k)) = (n, k) {
        say!(a.json,
            "quality         complex NRMSE vs the hidden sample: nominal geometry {n:.3}, calibrated {k:.3}{}",
            streamed.map(|s| format!(", streamed while acquiring {s:.3}")).unwrap_or_default()
        );
    }
    // The picture is an extra: a failure to draw it is a warning.
    let picture = out.join("comparison.png");
    let drawn = fpm_host::truth::write_comparison(
        &ds,
        &[
            ("NOMINAL", &with_nominal.object),
            ("CALIBRATED", &with_calibrated.object),
        ],
        settings.upsample,
        &picture,
    );
    match &drawn {
        Ok(()) => say!(
            a.json,
            "picture         {} (truth | nominal geometry | calibrated; amplitude above phase)",
            picture.display()
        ),
        Err(e) => tracing::warn!("no comparison picture: {e:#}"),
    }
    let reports: Vec<PathBuf> = [
        "acquisition.html",
        "calibration.html",
        "reconstruction/report.html",
    ]
    .iter()
    .map(|p| out.join(p))
    .filter(|p| p.is_file())
    .collect();
    for (k, page) in reports.iter().enumerate() {
        say!(
            a.json,
            "{}{}",
            if k == 0 {
                "reports         "
            } else {
                "                "
            },
            page.display()
        );
    }
    say!(a.json,
        "\nwrote the dataset, calibration/, calibration.json, reconstruction/ and acquisition.json to {} ({:.0} s)",
        out.display(),
        acquired.as_secs_f64()
    );
    say!(
        a.json,
        "re-run offline: fpm reconstruct {} --out /tmp/rec --calibration {}/calibration.json --flatten-background",
        out.display(),
        out.display()
    );
    Ok(serde_json::json!({
        "out": out,
        "hidden_array": truth,
        "recovered_array": g,
        "acquisition": summary,
        "complex_nrmse": {"nominal": n, "calibrated": k, "streamed": streamed},
        "picture": drawn.is_ok().then_some(picture),
        "reports": reports,
    }))
}
