//! `fpm demo`: the virtual microscope, with no hardware ([`fpm_rig::demo`]): printed as
//! it goes, or as one JSON object at the end.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use fpm_rig::demo::{ControllerReport, Demo, DemoEvent, DemoReport};
use fpm_serve::client::VirtualService;

/// Run the virtual microscope.
#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Where to write the dataset and results [default: a new directory under /tmp].
    #[arg(long)]
    out: Option<PathBuf>,
    /// Seed of the hidden LED array misplacement, the sample and the noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Sensor size of the virtual camera, pixels (192-4096).
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
    /// Run the demo through the acquisition service: start `fpm serve --virtual`, print
    /// its page's address to watch the reconstruction grow, queue the demo's job
    /// (calibrate, acquire, reconstruct) and follow it; the service stays up until
    /// Ctrl-C (with --json it stops when the job ends and the job's record is printed).
    #[arg(long, conflicts_with_all = ["firmware", "lanes", "exposure_us", "seed"])]
    serve: bool,
    /// Scan a slide instead of one field: 3 × 3 fields (--size each, 30 % overlap) on
    /// a virtual stage that misses its positions by up to 10 µm, calibrated at the
    /// first field, each field reconstructed while the next is acquired, stitched into
    /// one OME-Zarr; the mosaic scored against the hidden slide beside the fields' own.
    #[arg(long, conflicts_with_all = ["serve", "firmware", "lanes"])]
    scan: bool,
}

/// Run the demo.
pub fn run(a: DemoArgs) -> Result<()> {
    if a.serve {
        return through_the_service(&a);
    }
    if a.scan {
        return scan(&a);
    }
    let demo = Demo {
        out: a.out,
        seed: a.seed,
        size: a.size,
        step_ms: a.step_ms,
        exposure_us: a.exposure_us,
        lanes: a.lanes,
        firmware: a.firmware,
    };
    demo.validate()?;
    let fpm = std::env::current_exe().context("locating the fpm executable")?;
    if a.json {
        let report = fpm_rig::demo::run(&demo, &fpm, |_| {})?;
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    println!("fpm demo: a virtual FPM microscope, no hardware needed\n");
    let bar = crate::progress::frames("acquiring");
    let report = fpm_rig::demo::run(&demo, &fpm, |event| {
        match event {
        DemoEvent::Controller(c) => print_controller(c),
        DemoEvent::Camera { size } => println!(
            "virtual camera  {size}² frames, wave-optics model, realistic noise (separate process, iceoryx2 shared memory)"
        ),
        DemoEvent::Frames { done, total } => {
            bar.set_length(total as u64);
            bar.set_position(done as u64);
        }
    }
    })?;
    bar.finish_and_clear();
    print_result(&report);
    Ok(())
}

fn print_controller(c: &ControllerReport) {
    let g = c.info.geometry;
    println!(
        "LED controller  {} ({}, separate process) on {}\n                firmware {}, protocol {}, {}x{} LEDs at {:.1} mm pitch, {} lane(s)",
        c.info.board,
        if c.firmware_image {
            "the real firmware image in an emulated RP2040"
        } else {
            "host-compiled emulator"
        },
        c.port,
        c.info.firmware,
        c.info.protocol,
        g.rows,
        g.cols,
        g.pitch_um as f64 / 1000.0,
        g.lanes
    );
    println!(
        "patterns        objective NA {}: bright-field {} LEDs ({} mA), dark-field {} LEDs, DPC half {} LEDs",
        c.na, c.bright_field.leds_on, c.bright_field.current_ma, c.dark_field.leds_on, c.dpc_half.leds_on
    );
    println!(
        "link            request round-trip p50 {:.0} µs, p99 {:.0} µs (500 pings)",
        c.round_trip_p50_us, c.round_trip_p99_us
    );
    let l = &c.link;
    println!(
        "                {} frames, {} dropped, {} unknown keys, {} decode errors",
        l.frames_ok, l.frames_dropped, l.unknown_keys, l.decode_errors
    );
}

/// The hidden array beside the recovered one.
fn print_arrays(t: &fpm_host::truth::Truth, g: &fpm_physics::LedGeometry) {
    println!("\nLED array       hidden truth                 recovered by pdcFPM");
    println!(
        "  Δx            {:>8.3} mm                 {:>8.3} mm",
        t.placement.dx_mm, g.dx_mm
    );
    println!(
        "  Δy            {:>8.3} mm                 {:>8.3} mm",
        t.placement.dy_mm, g.dy_mm
    );
    println!(
        "  θ             {:>8.3}°                   {:>8.3}°",
        t.placement.theta_deg, g.theta_deg
    );
    println!(
        "  h             {:>8.2} mm                 {:>8.2} mm",
        t.placement.height_mm, g.height_mm
    );
}

fn print_result(r: &DemoReport) {
    print_arrays(&r.hidden_array, &r.recovered_array);
    let s = &r.acquisition;
    let c = &s.capture;
    let cal_frames: usize = s.calibration.iter().map(|r| r.labelled).sum();
    println!(
        "\nacquisition     {cal_frames} calibration frames, then {}/{} LEDs labelled in {:.1} s ({:.1} frames/s); missing {}, extra {}, ambiguous {}",
        c.labelled, c.requested, c.seconds, c.frames_per_s, c.missing.len(), c.extra_frames, c.ambiguous_frames
    );
    if let (Some(ms), Some(us)) = (s.last_frame_to_final_ms, s.update_us_mean) {
        println!("streaming EPRY  {us:.0} µs per frame as it arrived; last frame → final image {ms:.0} ms");
    }
    // How live the labelling was: a frame is streamed only once it is labelled.
    // Both shares: of all frames, and of those that had arrived (the camera's lateness
    // against the labeller's).
    println!(
        "labelling       {:.0} % of the frames labelled while the sequence ran ({:.0} % of the {} that had arrived); frame → label {:.0} ms median, {:.0} ms p99",
        100.0 * c.labelled_live as f64 / c.labelled.max(1) as f64,
        100.0 * c.labelled_live as f64 / c.arrived_live.max(1) as f64,
        c.arrived_live,
        c.label_lag_p50_ms,
        c.label_lag_p99_ms
    );
    let q = &r.complex_nrmse;
    if let (Some(n), Some(k)) = (q.nominal, q.calibrated) {
        println!(
            "quality         complex NRMSE vs the hidden sample: nominal geometry {n:.3}, calibrated {k:.3}{}",
            q.streamed
                .map(|s| format!(", streamed while acquiring {s:.3}"))
                .unwrap_or_default()
        );
    }
    if let Some(p) = &r.picture {
        println!(
            "picture         {} (truth | nominal geometry | calibrated; amplitude above phase)",
            p.display()
        );
    }
    for (k, page) in r.reports.iter().enumerate() {
        let label = if k == 0 {
            "reports         "
        } else {
            "                "
        };
        println!("{label}{}", page.display());
    }
    let out = r.out.display();
    println!(
        "\nwrote the dataset, calibration/, calibration.json, reconstruction/ and acquisition.json to {out} ({:.0} s)",
        r.acquisition_seconds
    );
    println!(
        "re-run offline: fpm reconstruct {out} --out /tmp/rec --calibration {out}/calibration.json --flatten-background"
    );
}

/// `fpm demo --serve`: the demo's acquisition as a job of a service started for it.
fn through_the_service(a: &DemoArgs) -> Result<()> {
    if !(192..=4096).contains(&a.size) {
        anyhow::bail!("--size {}: give 192-4096 pixels", a.size);
    }
    let root = match &a.out {
        Some(out) => out.clone(),
        None => tempfile::Builder::new()
            .prefix("fpm-demo-serve-")
            .tempdir()?
            .keep(),
    };
    let fpm = std::env::current_exe().context("locating the fpm executable")?;
    let mut service = VirtualService::start(
        &fpm,
        &root.join("service"),
        a.size,
        std::process::Stdio::null(),
    )?;
    let outcome = follow_the_job(a, &service, &root);
    if outcome.is_ok() && !a.json {
        let page = &service.page;
        println!("\nthe service keeps running so you can look: {page}\nCtrl-C stops it");
        let stopped = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
            signal_hook::flag::register(signal, stopped.clone())?;
        }
        while !stopped.load(std::sync::atomic::Ordering::SeqCst) && service.running() {
            std::thread::sleep(std::time::Duration::from_millis(100));
        }
    }
    // Dropping the service stops it.
    outcome
}

/// Queue the demo's job on `service`, follow it to its end, print it.
fn follow_the_job(a: &DemoArgs, service: &VirtualService, root: &std::path::Path) -> Result<()> {
    if !a.json {
        println!(
            "fpm demo --serve: the virtual microscope driven through the acquisition service\n"
        );
        println!("watch it         {}", service.page);
    }
    let events = fpm_serve::client::event_lines(service.address, None)?;
    let out = root.join("acquisition");
    let job = service.submit(&serde_json::json!({"kind": "acquire", "out": out,
        "calibrate": true, "reconstruct": true, "flatten_background": true,
        "defocus_sigma_um": 0.0, "step_ms": a.step_ms, "snapshot_every": 25}))?;
    let bar = (!a.json).then(|| crate::progress::frames("acquiring"));
    for line in events {
        let Some(data) = line.strip_prefix("data:") else {
            continue;
        };
        let event: serde_json::Value = serde_json::from_str(data.trim())?;
        if event["job"] != job {
            continue;
        }
        match event["event"].as_str() {
            Some("progress") => {
                if let Some(bar) = &bar {
                    let p = &event["progress"];
                    bar.set_message(p["phase"].as_str().unwrap_or("").to_string());
                    bar.set_length(p["of"].as_u64().unwrap_or(0));
                    bar.set_position(p["frames"].as_u64().unwrap_or(0));
                }
            }
            Some("state") if !matches!(event["state"].as_str(), Some("queued" | "running")) => {
                break
            }
            _ => {}
        }
    }
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
    let record = service.get(&format!("/api/jobs/{job}"))?.json()?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&record)?);
    } else {
        let s = &record["summary"];
        println!(
            "{:<17}{}{}",
            format!("job {job}"),
            record["state"].as_str().unwrap_or("?"),
            record["error"]
                .as_str()
                .map(|e| format!(": {e}"))
                .unwrap_or_default()
        );
        println!(
            "acquisition      {} of {} LEDs in the dataset, in {}",
            s["frames_in_dataset"],
            s["capture"]["requested"],
            out.display()
        );
        for report in record["reports"].as_array().into_iter().flatten() {
            if let Some(r) = report.as_str() {
                println!("report           {}", out.join(r).display());
            }
        }
    }
    match record["state"].as_str() {
        Some("done") => Ok(()),
        state => anyhow::bail!("the demo's job ended {}", state.unwrap_or("?")),
    }
}

/// `fpm demo --scan`.
fn scan(a: &DemoArgs) -> Result<()> {
    let demo = fpm_rig::demo::ScanDemo {
        out: a.out.clone(),
        seed: a.seed,
        size: if a.size == 256 {
            fpm_rig::demo::MIN_SIZE
        } else {
            a.size
        },
        ..fpm_rig::demo::ScanDemo::default()
    };
    let fpm = std::env::current_exe().context("locating the fpm executable")?;
    let bar = crate::progress::counter("scanning", "fields");
    let report = fpm_rig::demo::run_scan(&demo, &fpm, |done, total| {
        crate::progress::advance(&bar, done, total)
    })?;
    bar.finish_and_clear();
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    let s = &report.stitch;
    println!(
        "scanned {} fields of {}² in {:.0} s ({:.0} fields per hour, each reconstructed while the next was acquired) into {}",
        report.scan.fields,
        demo.size,
        report.scan.seconds,
        report.scan.fields_per_hour,
        report.out.display()
    );
    println!(
        "stitched {}×{} px ({:.2} µm pixels): {}",
        s.canvas.width,
        s.canvas.height,
        s.canvas.pitch_um,
        report.out.join("mosaic/mosaic.zarr").display()
    );
    match &s.versus_truth {
        Some(t) => println!(
            "against the hidden slide: mosaic complex NRMSE {:.3}, the fields' own {:.3} ({:.2}×); fields placed within {:.2} µm of where the stage really put them (it missed by {:.1} µm rms)",
            t.complex_nrmse, t.fields_complex_nrmse, t.ratio, t.max_position_error_um, t.rms_stage_error_um
        ),
        None => println!("not scored against the hidden slide (see the log)"),
    }
    for w in &s.warnings {
        println!("warning: {w}");
    }
    Ok(())
}
