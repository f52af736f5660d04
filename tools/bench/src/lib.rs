//! # fpm-bench
//!
//! `fpm bench …`: fpm's measurements, reported as percentiles with the conditions
//! they were measured under and, where speed is the question, as ratios against a
//! baseline measured in the same run (these machines are noisy). The criterion
//! micro-benchmark of the EPRY update is `benches/epry.rs`.

mod frames;

use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use fpm_protocol::{Pattern, Rgb};
use serde::Serialize;

use fpm_acquire::controller::scan::{scan_steps, Order, Selection};
use fpm_acquire::controller::Controller;
use fpm_rig::process::EmulatorProcess;

#[derive(Subcommand, Debug)]
pub enum BenchCommand {
    /// Request round-trip over the serial link: ping and a 441-LED pattern.
    Link(LinkArgs),
    /// pdcFPM calibration accuracy and speed on simulated data: the paper's Table 1, an
    /// off-axis feature, and a random sweep of the paper's range.
    Calibration {
        /// Random cases in the sweep.
        #[arg(long, default_value_t = 30)]
        random: usize,
        /// Seed of the sweep.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Reconstruction quality with a misplaced LED array: nominal vs pdcFPM-calibrated vs
    /// true geometry (the paper's Fig. 1 and 5 trends).
    Geometry {
        /// Camera field, pixels.
        #[arg(long, default_value_t = 128)]
        size: usize,
        /// EPRY passes.
        #[arg(long, default_value_t = 10)]
        passes: usize,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Camera-frame hand-off through iceoryx2 shared memory versus a Unix socket, for
    /// 2048² and 5472×3648 (20 MP) frames.
    Frames {
        /// Frames per size.
        #[arg(long, default_value_t = 200)]
        rounds: usize,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// EPRY speed: one frame update against the two FFTs it needs, one pass over 441
    /// frames, and the streaming latency (last frame → final image), in the same run.
    Epry {
        /// Camera field, pixels.
        #[arg(long, default_value_t = 256)]
        size: usize,
        /// HR pixels per camera pixel.
        #[arg(long, default_value_t = 4)]
        upsample: usize,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// LED switch time of single-LED scans (the firmware's chain model): full chain
    /// versus partial shifts, for 1, 2 and 4 data lanes.
    LedSwitch {
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
}

#[derive(Args, Debug)]
pub struct LinkArgs {
    /// Controller port; without it an emulator is started on a pseudo-terminal.
    #[arg(long)]
    port: Option<String>,
    /// Requests per measurement.
    #[arg(long, default_value_t = 2000)]
    count: usize,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

/// Latency percentiles of a set of samples.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Percentiles {
    /// Number of samples.
    pub count: usize,
    /// Median, µs.
    pub p50_us: f64,
    /// 99th percentile, µs.
    pub p99_us: f64,
    /// Largest, µs.
    pub max_us: f64,
    /// Mean, µs.
    pub mean_us: f64,
}

impl Percentiles {
    /// Summarise samples in µs (sorts them).
    pub fn of(samples: &mut [f64]) -> Self {
        samples.sort_by(|a, b| a.total_cmp(b));
        let n = samples.len();
        let at = |q: f64| -> f64 {
            if n == 0 {
                return f64::NAN;
            }
            samples[((q * n as f64).ceil() as usize).clamp(1, n) - 1]
        };
        Self {
            count: n,
            p50_us: at(0.5),
            p99_us: at(0.99),
            max_us: at(1.0),
            mean_us: if n == 0 {
                f64::NAN
            } else {
                samples.iter().sum::<f64>() / n as f64
            },
        }
    }
}

#[derive(Serialize)]
struct LinkReport {
    port: String,
    emulated: bool,
    ping: Percentiles,
    pattern_all_441: Percentiles,
    pattern_leds_on: u16,
}

/// Run one benchmark.
pub fn run(cmd: BenchCommand) -> Result<()> {
    match cmd {
        BenchCommand::Link(a) => link(a),
        BenchCommand::LedSwitch { json } => led_switch(json),
        BenchCommand::Calibration { random, seed, json } => calibration(random, seed, json),
        BenchCommand::Geometry { size, passes, json } => geometry(size, passes, json),
        BenchCommand::Frames { rounds, json } => frames::run(rounds, json),
        BenchCommand::Epry {
            size,
            upsample,
            json,
        } => epry_speed(size, upsample, json),
    }
}

fn link(a: LinkArgs) -> Result<()> {
    let emulator = match &a.port {
        Some(_) => None,
        None => Some(EmulatorProcess::start(&[])?),
    };
    let port = match (&a.port, &emulator) {
        (Some(p), _) => p.clone(),
        (None, Some(e)) => e.link.to_string_lossy().into_owned(),
        (None, None) => unreachable!("an emulator is started when no port is given"),
    };
    let dev = Controller::open(&port, Duration::from_secs(2))?;
    let count = a.count.max(10);

    // Warm up both paths, then measure.
    let mut ping = dev.ping_round_trips(50, count as u32)?;
    // Every LED lit, dim enough to stay within any budget the board may have.
    let all = Pattern::All;
    let dim = Rgb::new(4, 4, 4);
    let mut pattern = Vec::with_capacity(count);
    let mut leds_on = 0;
    for i in 0..count {
        // Alternate colours so every request really changes all 441 LEDs.
        let color = if i % 2 == 0 { dim } else { Rgb::new(5, 5, 5) };
        let t = Instant::now();
        leds_on = dev.pattern(all, color)?.leds_on;
        pattern.push(t.elapsed().as_secs_f64() * 1e6);
    }
    dev.clear()?;
    let report = LinkReport {
        port,
        emulated: emulator.is_some(),
        ping: Percentiles::of(&mut ping),
        pattern_all_441: Percentiles::of(&mut pattern),
        pattern_leds_on: leds_on,
    };
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!(
            "request round-trip over {} ({}), {} requests each:",
            report.port,
            if report.emulated {
                "emulator on a pseudo-terminal"
            } else {
                "device"
            },
            count
        );
        for (name, p) in [
            ("ping", &report.ping),
            ("pattern, all LEDs", &report.pattern_all_441),
        ] {
            println!(
                "  {name:<18} p50 {:>7.1} µs   p99 {:>7.1} µs   max {:>8.1} µs   mean {:>7.1} µs",
                p.p50_us, p.p99_us, p.max_us, p.mean_us
            );
        }
        println!(
            "  (the pattern lit {} LEDs each time)",
            report.pattern_leds_on
        );
    }
    Ok(())
}

#[derive(Serialize)]
struct SwitchRow {
    order: Order,
    lanes: u8,
    full_chain_ms: f64,
    partial_mean_ms: f64,
    partial_p50_ms: f64,
    partial_max_ms: f64,
    scan_shift_s: f64,
}

/// Shift time of every step of a single-LED scan, computed with the firmware's own
/// partial-shift rule (up to the furthest changed LED per lane).
fn led_switch(json: bool) -> Result<()> {
    use fpm_firmware::chain::{chain_index, lane_len, shift_lengths, update_time_us};
    use fpm_protocol::Illumination;
    let board = fpm_firmware::BoardConfig::PICO_21X21;
    let mut rows = vec![];
    for order in [Order::Nearest, Order::Raster] {
        for lanes in [1u8, 2, 4] {
            let mut g = board.geometry;
            g.lanes = lanes;
            let n = g.led_count() as usize;
            let full =
                update_time_us(&[lane_len(&g) as u16], board.led_shift_ns, board.latch_us) as f64;
            let mut shown = vec![Rgb::OFF; n];
            let mut times = vec![];
            for step in scan_steps(&g, Selection::All, order, Rgb::WHITE) {
                let mut next = vec![Rgb::OFF; n];
                if let Illumination::Led(led) = step.illumination {
                    if let Some(i) = chain_index(&g, led) {
                        next[i as usize] = Rgb::WHITE;
                    }
                }
                let shift = shift_lengths(&g, &shown, &next);
                times.push(update_time_us(&shift, board.led_shift_ns, board.latch_us) as f64);
                shown = next;
            }
            let total: f64 = times.iter().sum();
            let p = Percentiles::of(&mut times);
            rows.push(SwitchRow {
                order,
                lanes,
                full_chain_ms: full / 1e3,
                partial_mean_ms: p.mean_us / 1e3,
                partial_p50_ms: p.p50_us / 1e3,
                partial_max_ms: p.max_us / 1e3,
                scan_shift_s: total / 1e6,
            });
        }
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
        return Ok(());
    }
    println!("LED switch time per step of a 441-LED single-LED scan (30 µs per LED per lane, 280 µs latch):");
    println!("  order    lanes  full chain   partial mean   partial p50   partial max   441 steps (shift only)");
    for r in &rows {
        println!(
            "  {:<8} {:>5}  {:>8.2} ms   {:>9.2} ms   {:>8.2} ms   {:>8.2} ms   {:>8.2} s",
            format!("{:?}", r.order).to_lowercase(),
            r.lanes,
            r.full_chain_ms,
            r.partial_mean_ms,
            r.partial_p50_ms,
            r.partial_max_ms,
            r.scan_shift_s
        );
    }
    Ok(())
}

#[derive(Serialize, Clone)]
struct CalibrationCase {
    name: String,
    truth: [f64; 4],
    found: [f64; 4],
    /// |Δx| µm, |Δy| µm, |θ| °, |h| mm
    error: [f64; 4],
    used_leds: usize,
    calibrate_ms: f64,
}

#[derive(Serialize)]
struct CalibrationBench {
    cases: Vec<CalibrationCase>,
    max_error: [f64; 4],
    median_error: [f64; 4],
    paper_table1_max_error: [f64; 4],
    calibrate_ms_median: f64,
    calibrate_ms_max: f64,
}

fn calibration(random: usize, seed: u64, json: bool) -> Result<()> {
    use fpm_physics::calibrate::{LedStatus, Options};
    use fpm_physics::simulate::CalibrationScene;
    use fpm_physics::study::calibrate_simulated;
    use fpm_physics::LedGeometry;
    use rand::{Rng, SeedableRng};

    let nominal = LedGeometry::paper();
    let geometry = |dx, dy, th, h| LedGeometry {
        dx_mm: dx,
        dy_mm: dy,
        theta_deg: th,
        height_mm: h,
        ..nominal
    };
    // (name, truth, feature side µm, feature position µm)
    let mut cases: Vec<(String, LedGeometry, f64, (f64, f64))> = vec![
        (
            "table 1: 1.5, 1.5, 5°, 92".into(),
            geometry(1.5, 1.5, 5.0, 92.0),
            50.0,
            (0.0, 0.0),
        ),
        (
            "table 1: 2.0, 2.0, 5°, 92".into(),
            geometry(2.0, 2.0, 5.0, 92.0),
            50.0,
            (0.0, 0.0),
        ),
        (
            "table 1: 2.5, 2.5, 5°, 92".into(),
            geometry(2.5, 2.5, 5.0, 92.0),
            50.0,
            (0.0, 0.0),
        ),
        (
            "off-axis 30 µm feature at (30, -20) µm".into(),
            geometry(-1.7, 0.8, -3.5, 88.0),
            30.0,
            (30.0, -20.0),
        ),
    ];
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    for k in 0..random {
        let g = geometry(
            rng.gen_range(-2.5..2.5),
            rng.gen_range(-2.5..2.5),
            rng.gen_range(-5.0..5.0),
            rng.gen_range(87.0..97.0),
        );
        cases.push((format!("random {k}"), g, 50.0, (0.0, 0.0)));
    }
    let bar = if json {
        indicatif::ProgressBar::hidden()
    } else {
        indicatif::ProgressBar::new(cases.len() as u64)
    };
    let mut out = vec![];
    for (k, (name, truth, side, at)) in cases.iter().enumerate() {
        let mut scene = CalibrationScene::paper(*truth, seed.wrapping_mul(1000) + k as u64);
        scene.feature_um = *side;
        scene.feature_at_um = *at;
        let frames = scene.acquire();
        let (cal, took) = calibrate_simulated(&scene, &frames, &nominal, &Options::default())?;
        let ms = took.as_secs_f64() * 1e3;
        let found = [cal.dx_mm, cal.dy_mm, cal.theta_deg, cal.height_mm];
        let tr = [truth.dx_mm, truth.dy_mm, truth.theta_deg, truth.height_mm];
        out.push(CalibrationCase {
            name: name.clone(),
            truth: tr,
            found,
            error: [
                (found[0] - tr[0]).abs() * 1e3,
                (found[1] - tr[1]).abs() * 1e3,
                (found[2] - tr[2]).abs(),
                (found[3] - tr[3]).abs(),
            ],
            used_leds: cal
                .leds
                .iter()
                .filter(|l| l.status == LedStatus::Used)
                .count(),
            calibrate_ms: ms,
        });
        bar.inc(1);
    }
    bar.finish_and_clear();
    let column = |i: usize| -> Vec<f64> { out.iter().map(|c| c.error[i]).collect() };
    let stat = |f: fn(&mut [f64]) -> f64| [0, 1, 2, 3].map(|i| f(&mut column(i)));
    let max = |v: &mut [f64]| v.iter().copied().fold(0.0, f64::max);
    let median = |v: &mut [f64]| {
        v.sort_by(|a, b| a.total_cmp(b));
        v[v.len() / 2]
    };
    let mut times: Vec<f64> = out.iter().map(|c| c.calibrate_ms).collect();
    let t = Percentiles::of(&mut times);
    let report = CalibrationBench {
        max_error: stat(max),
        median_error: stat(median),
        paper_table1_max_error: [6.0, 12.0, 0.200, 0.92],
        calibrate_ms_median: t.p50_us,
        calibrate_ms_max: t.max_us,
        cases: out,
    };
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    println!("pdcFPM calibration on simulated 256x256 frames (full wave optics, realistic noise), 26 frames per case:");
    println!(
        "  {:<40} {:>9} {:>9} {:>9} {:>9} {:>5} {:>8}",
        "case", "Δx µm", "Δy µm", "θ °", "h mm", "LEDs", "ms"
    );
    for c in &report.cases {
        println!(
            "  {:<40} {:>9.2} {:>9.2} {:>9.4} {:>9.3} {:>5} {:>8.1}",
            c.name, c.error[0], c.error[1], c.error[2], c.error[3], c.used_leds, c.calibrate_ms
        );
    }
    let e = &report;
    println!(
        "  {:<40} {:>9.2} {:>9.2} {:>9.4} {:>9.3}",
        "max error (all cases)", e.max_error[0], e.max_error[1], e.max_error[2], e.max_error[3]
    );
    println!(
        "  {:<40} {:>9.2} {:>9.2} {:>9.4} {:>9.3}",
        "median error", e.median_error[0], e.median_error[1], e.median_error[2], e.median_error[3]
    );
    println!(
        "  {:<40} {:>9.2} {:>9.2} {:>9.4} {:>9.3}",
        "paper, Table 1 worst", 6.0, 12.0, 0.200, 0.92
    );
    println!(
        "  calibration time (one core, frames in memory): median {:.1} ms, max {:.1} ms",
        e.calibrate_ms_median, e.calibrate_ms_max
    );
    Ok(())
}

fn geometry(size: usize, passes: usize, json: bool) -> Result<()> {
    use fpm_physics::study::geometry_case;
    use fpm_physics::{LedGeometry, System};
    let system = System::paper();
    let nominal = LedGeometry::paper();
    let cases = [
        (0.0, 0.0, 0.0),
        (0.2, 0.0, 0.0),
        (0.8, 0.0, 0.0),
        (2.0, 0.0, 0.0),
        (1.0, 1.0, 5.0),
        (2.0, 2.0, 5.0),
    ];
    let bar = if json {
        indicatif::ProgressBar::hidden()
    } else {
        indicatif::ProgressBar::new(cases.len() as u64)
    };
    let mut rows = vec![];
    for (k, &(dx, dy, th)) in cases.iter().enumerate() {
        let truth = LedGeometry {
            dx_mm: dx,
            dy_mm: dy,
            theta_deg: th,
            ..nominal
        };
        let case = geometry_case(&system, &nominal, &truth, size, passes, 40 + k as u64)
            .ok_or_else(|| {
                anyhow::anyhow!(
                    "case Δx {dx}, Δy {dy}, θ {th}: calibration or reconstruction failed"
                )
            })?;
        rows.push(case);
        bar.inc(1);
    }
    bar.finish_and_clear();
    if json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
        return Ok(());
    }
    println!("complex NRMSE vs the band-limited truth ({size}² frames, 441 LEDs, {passes} EPRY passes, U = 4):");
    println!(
        "  {:<22} {:>9} {:>11} {:>9} {:>13} {:>12}",
        "array (Δx, Δy, θ)", "nominal", "calibrated", "true", "calib/true", "centre frame"
    );
    for r in &rows {
        let t = &r.truth;
        println!(
            "  {:<22} {:>9.3} {:>11.3} {:>9.3} {:>13.3} {:>12.3}",
            format!("{:.1}, {:.1} mm, {:.0}°", t.dx_mm, t.dy_mm, t.theta_deg),
            r.nrmse_nominal,
            r.nrmse_calibrated,
            r.nrmse_true,
            r.nrmse_calibrated / r.nrmse_true,
            r.nrmse_centre_frame
        );
    }
    Ok(())
}

#[derive(Serialize)]
struct EpryBench {
    size: usize,
    upsample: usize,
    two_ffts_us: Percentiles,
    update_us: Percentiles,
    update_over_ffts: f64,
    pass_441_ms: f64,
    streaming: StreamingBench,
}

#[derive(Serialize)]
struct StreamingBench {
    frames: usize,
    push_us: Percentiles,
    finish_passes: usize,
    last_frame_to_final_ms: f64,
    nrmse_streamed: f64,
    nrmse_offline: f64,
    offline_passes: usize,
    offline_ms: f64,
}

/// Streaming on a simulated acquisition (full wave-optics model, 441 frames): frames
/// pushed as they would arrive (nearest-first, the acquisition's order), then the time
/// from the last frame to the final image, against the offline run.
fn streaming_latency(size: usize, upsample: usize, finish_passes: usize) -> Result<StreamingBench> {
    use fpm_physics::metrics::{score, synthetic_aperture};
    use fpm_physics::reconstruct::{run, Field, Settings, Shot, Streaming};
    use fpm_physics::simulate::{acquire, Camera, ObjectField};
    use fpm_physics::{LedGeometry, System};
    let system = System::paper();
    let geometry = LedGeometry::paper();
    let camera = Camera::realistic();
    let object = ObjectField::test_sample(&system, size, 32, 2, 9);
    let leds: Vec<(usize, usize)> = (0..21).flat_map(|r| (0..21).map(move |c| (r, c))).collect();
    let shots: Vec<((usize, usize), f64)> = geometry
        .nearest_first(&leds, (0.0, 0.0), system.wavelength_um)
        .into_iter()
        .map(|k| (leds[k], 0.0))
        .collect();
    eprintln!("simulating {} frames of {size}² …", shots.len());
    let frames = acquire(
        &system,
        &geometry,
        &object,
        &shots,
        &camera,
        |i| camera.auto_exposure(i),
        5,
    );
    let images: Vec<fpm_physics::Image> = frames
        .iter()
        .map(|f| {
            camera
                .dark_subtracted(&f.counts)
                .mapv(|v| v.max(0.0) / f.exposure_ms as f32)
        })
        .collect();
    let settings = Settings {
        upsample,
        ..Settings::default()
    };
    let mut streaming = Streaming::new(system, geometry, settings);
    let mut push = vec![];
    for (f, img) in frames.iter().zip(&images) {
        let t = Instant::now();
        streaming.push(f.led, img.clone());
        push.push(t.elapsed().as_secs_f64() * 1e6);
    }
    let shot_refs: Vec<Shot> = frames
        .iter()
        .zip(&images)
        .map(|(f, image)| Shot { led: f.led, image })
        .collect();
    let t = Instant::now();
    let mut done = streaming
        .finish(&shot_refs, finish_passes)
        .context("no bright-field frame")?;
    let streamed = done.sample();
    let latency = t.elapsed().as_secs_f64() * 1e3;
    let offline_passes = 10;
    let t = Instant::now();
    let mut offline = run(
        &system,
        &geometry,
        Field::default(),
        &shot_refs,
        settings,
        offline_passes,
        |_, _| {},
    )
    .context("no bright-field frame")?;
    let offline_obj = offline.sample();
    let offline_ms = t.elapsed().as_secs_f64() * 1e3;
    let discs: Vec<(f64, f64)> = shots
        .iter()
        .map(|s| geometry.illumination_frequency(s.0 .0, s.0 .1, 0.0, 0.0, system.wavelength_um))
        .collect();
    let truth = object.crop_to_camera();
    let pitch = system.sample_pixel_um() / upsample as f64;
    let aperture = synthetic_aperture(&discs, system.cutoff());
    Ok(StreamingBench {
        frames: frames.len(),
        push_us: Percentiles::of(&mut push),
        finish_passes,
        last_frame_to_final_ms: latency,
        nrmse_streamed: score(&streamed, pitch, &truth, object.pitch_um(), &aperture).complex_nrmse,
        nrmse_offline: score(&offline_obj, pitch, &truth, object.pitch_um(), &aperture)
            .complex_nrmse,
        offline_passes,
        offline_ms,
    })
}

fn epry_speed(size: usize, upsample: usize, json: bool) -> Result<()> {
    use fpm_physics::fft::Fft2;
    use fpm_physics::reconstruct::{Epry, Settings};
    use fpm_physics::{Image, LedGeometry, System};
    use rustfft::num_complex::Complex32;
    let system = System::paper();
    let geometry = LedGeometry::paper();
    let frame = Image::from_shape_fn((size, size), |(r, c)| {
        1.0 + 0.3 * ((r * 7 + c * 3) % 17) as f32 / 17.0
    });
    let mut epry = Epry::new(
        &system,
        &frame,
        Settings {
            upsample,
            ..Settings::default()
        },
    );
    let leds: Vec<(usize, usize)> = (0..21).flat_map(|r| (0..21).map(move |c| (r, c))).collect();
    let freq = |led: (usize, usize)| {
        geometry.illumination_frequency(led.0, led.1, 0.0, 0.0, system.wavelength_um)
    };
    // Baseline: the forward and inverse LR FFT an update cannot do without.
    let mut fft = Fft2::new(size, size);
    let mut buf: Vec<Complex32> = frame.iter().map(|&v| Complex32::new(v, 0.0)).collect();
    let rounds = 200;
    let (mut ffts, mut updates) = (Vec::with_capacity(rounds), Vec::with_capacity(rounds));
    for k in 0..rounds {
        // Interleave both so machine noise hits them alike.
        let t = Instant::now();
        fft.forward(&mut buf);
        fft.inverse(&mut buf);
        ffts.push(t.elapsed().as_secs_f64() * 1e6);
        let t = Instant::now();
        epry.update_amplitude(&frame, freq(leds[k % leds.len()]), true);
        updates.push(t.elapsed().as_secs_f64() * 1e6);
    }
    let t = Instant::now();
    for &led in &leds {
        epry.update_amplitude(&frame, freq(led), true);
    }
    let pass = t.elapsed().as_secs_f64() * 1e3;
    let streaming = streaming_latency(size, upsample, 5)?;
    let f = Percentiles::of(&mut ffts);
    let u = Percentiles::of(&mut updates);
    let report = EpryBench {
        size,
        upsample,
        update_over_ffts: u.p50_us / f.p50_us,
        two_ffts_us: f,
        update_us: u,
        pass_441_ms: pass,
        streaming,
    };
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!("EPRY on {size}² frames, U = {upsample}, one thread:");
        println!(
            "  forward + inverse FFT   p50 {:>8.1} µs   p99 {:>8.1} µs",
            f.p50_us, f.p99_us
        );
        println!(
            "  one frame update        p50 {:>8.1} µs   p99 {:>8.1} µs   ({:.2}× the two FFTs)",
            u.p50_us, u.p99_us, report.update_over_ffts
        );
        println!("  one pass over 441 frames {:.0} ms", pass);
        let st = &report.streaming;
        println!(
            "streaming {} simulated frames: push p50 {:.0} µs p99 {:.0} µs (one update each, as they arrive);",
            st.frames, st.push_us.p50_us, st.push_us.p99_us
        );
        println!(
            "  last frame → final image ({} more passes): {:.0} ms, NRMSE {:.3}; offline {} passes: {:.0} ms, NRMSE {:.3}",
            st.finish_passes,
            st.last_frame_to_final_ms,
            st.nrmse_streamed,
            st.offline_passes,
            st.offline_ms,
            st.nrmse_offline
        );
    }
    Ok(())
}
