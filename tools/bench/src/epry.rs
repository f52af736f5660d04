//! `fpm bench epry`: one EPRY update against the two FFTs it needs, a 441-frame pass,
//! and the streaming latency (last frame → final image), all in one run.

use std::time::Instant;

use anyhow::{Context, Result};
use serde::Serialize;

use crate::Percentiles;

#[derive(Serialize)]
struct EpryBench {
    size: usize,
    upsample: usize,
    /// A forward and an inverse 2-D FFT at the floor: rustfft's planned 1-D transforms
    /// over all rows in one call, the `transpose` crate between the passes.
    floor_two_ffts_us: Percentiles,
    /// The same pair through FFTW 3 (`FFTW_MEASURE`, one thread), a second opinion on
    /// the floor; None when FFTW is not installed (`fftw` says why).
    fftw_two_ffts_us: Option<Percentiles>,
    /// FFTW's version, or why it was not measured.
    fftw: String,
    /// The floor pair's p50 over FFTW's.
    floor_over_fftw: Option<f64>,
    /// The same pair through `fpm_physics::fft::Fft2`, the transform EPRY uses.
    two_ffts_us: Percentiles,
    update_us: Percentiles,
    /// The update's p50 over the floor pair's.
    update_over_floor: f64,
    update_over_ffts: f64,
    pass_441_ms: f64,
    /// Measuring one dark-field frame's own background (`fpm_physics::background`),
    /// once per frame as it arrives, on a 16-bit frame of the same size.
    background_estimate_us: Percentiles,
    /// Its p50 over the update's.
    background_over_update: f64,
    /// One pass over 441 frames on 1 and 2 threads (each update spread over both on 2).
    passes: Vec<PassTiming>,
    streaming: StreamingBench,
}

#[derive(Serialize)]
struct PassTiming {
    size: usize,
    threads: usize,
    ms: f64,
}

/// EPRY seeded from a synthetic `size`² frame, with the paper's 441 LEDs' wave vectors
/// at the field centre: what the update timings run on.
struct Updates {
    frame: fpm_physics::Image,
    epry: fpm_physics::reconstruct::Epry,
    frequencies: Vec<(f64, f64)>,
}

impl Updates {
    /// Each update on the calling thread, or spread over rayon's pool (`parallel`).
    fn new(size: usize, upsample: usize, parallel: bool) -> Self {
        use fpm_physics::reconstruct::{Epry, Settings};
        use fpm_physics::{Image, LedGeometry, System};
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
        epry.set_parallel(parallel);
        let frequencies = geometry
            .leds()
            .into_iter()
            .map(|led| geometry.illumination_frequency(led, 0.0, 0.0, system.wavelength_um))
            .collect();
        Self {
            frame,
            epry,
            frequencies,
        }
    }

    /// One update with LED `k` (modulo the LED count).
    fn update(&mut self, k: usize) {
        let f = self.frequencies[k % self.frequencies.len()];
        self.epry.update_amplitude(&self.frame, f, true);
    }

    /// One pass over all LEDs, ms.
    fn pass_ms(&mut self) -> f64 {
        let t = Instant::now();
        for k in 0..self.frequencies.len() {
            self.update(k);
        }
        t.elapsed().as_secs_f64() * 1e3
    }
}

/// One pass over the paper's 441 LEDs on a `size`² field at `upsample`, on a pool of
/// `threads` (on more than one, each update is spread over the pool), after a few
/// updates to warm up.
fn pass_ms(size: usize, upsample: usize, threads: usize) -> Result<f64> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .context("building a thread pool")?;
    Ok(pool.install(|| {
        let mut updates = Updates::new(size, upsample, threads > 1);
        (0..20).for_each(|k| updates.update(k));
        updates.pass_ms()
    }))
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
    let leds = geometry.leds();
    let shots: Vec<(fpm_physics::LedIndex, f64)> = geometry
        .nearest_first(&leds, (0.0, 0.0), &system)
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
            let m = f.measured(&camera);
            m.intensity(fpm_physics::frame::Region::whole(m.dim()))
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
        .map(|(f, image)| Shot {
            led: f.led,
            also: &f.also,
            image,
        })
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
        .map(|s| geometry.illumination_frequency(s.0, 0.0, 0.0, system.wavelength_um))
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

/// The floor for a square 2-D FFT: row transforms in one batch, a transpose, the
/// column transforms as rows, a transpose back. Nothing of `fpm_physics` is used, so
/// the floor stays a reference for `Fft2`.
struct FloorFft {
    n: usize,
    forward: std::sync::Arc<dyn rustfft::Fft<f32>>,
    inverse: std::sync::Arc<dyn rustfft::Fft<f32>>,
    scratch: Vec<rustfft::num_complex::Complex32>,
    transposed: Vec<rustfft::num_complex::Complex32>,
}

impl FloorFft {
    fn new(n: usize) -> Self {
        let mut planner = rustfft::FftPlanner::new();
        let forward = planner.plan_fft_forward(n);
        let inverse = planner.plan_fft_inverse(n);
        let scratch_len = forward
            .get_inplace_scratch_len()
            .max(inverse.get_inplace_scratch_len());
        Self {
            n,
            forward,
            inverse,
            scratch: vec![Default::default(); scratch_len],
            transposed: vec![Default::default(); n * n],
        }
    }

    fn pair(&mut self, data: &mut [rustfft::num_complex::Complex32]) {
        for plan in [self.forward.clone(), self.inverse.clone()] {
            plan.process_with_scratch(data, &mut self.scratch);
            transpose::transpose(data, &mut self.transposed, self.n, self.n);
            plan.process_with_scratch(&mut self.transposed, &mut self.scratch);
            transpose::transpose(&self.transposed, data, self.n, self.n);
        }
    }
}

pub fn run(size: usize, upsample: usize, json: bool) -> Result<()> {
    use fpm_physics::fft::Fft2;
    use rustfft::num_complex::Complex32;
    // One thread, as the report says, whatever the field size's default.
    let mut updates = Updates::new(size, upsample, false);
    // Baseline: the forward and inverse LR FFT an update cannot do without.
    let mut fft = Fft2::new(size, size);
    let mut floor = FloorFft::new(size);
    let mut buf: Vec<Complex32> = updates
        .frame
        .iter()
        .map(|&v| Complex32::new(v, 0.0))
        .collect();
    let rounds = 200;
    let (mut ffts, mut update_us) = (Vec::with_capacity(rounds), Vec::with_capacity(rounds));
    let mut floors = Vec::with_capacity(rounds);
    let unnormalised = 1.0 / (size * size) as f32;
    // A 16-bit dark-field frame: noise about an offset, for the background estimate.
    let counts =
        fpm_physics::frame::Pixels::U16(ndarray::Array2::from_shape_fn((size, size), |(r, c)| {
            (100 + (r * 7919 + c * 104_729) % 13) as u16
        }));
    let dark_field = fpm_physics::frame::Measured {
        counts: counts.view(),
        response: fpm_physics::frame::Response::Linear,
        dark_level: 100.0,
        exposure_ms: 1.0,
        floor: 0.0,
        soft_floor: false,
        band: 0.0,
    };
    let mut background_us = Vec::with_capacity(rounds);
    let mut fftw = crate::fftw::load(size);
    if let Ok(f) = fftw.as_mut() {
        f.buffer().copy_from_slice(&buf);
    }
    let mut fftw_us = Vec::with_capacity(rounds);
    for k in 0..rounds {
        // Interleave all three so machine noise hits them alike.
        let t = Instant::now();
        floor.pair(&mut buf);
        floors.push(t.elapsed().as_secs_f64() * 1e6);
        // Keep the values bounded: the floor pair is unnormalised.
        buf.iter_mut().for_each(|v| *v *= unnormalised);
        if let Ok(f) = fftw.as_mut() {
            let t = Instant::now();
            f.pair();
            fftw_us.push(t.elapsed().as_secs_f64() * 1e6);
            f.buffer().iter_mut().for_each(|v| *v *= unnormalised);
        }
        let t = Instant::now();
        fft.forward(&mut buf);
        fft.inverse(&mut buf);
        ffts.push(t.elapsed().as_secs_f64() * 1e6);
        let t = Instant::now();
        updates.update(k);
        update_us.push(t.elapsed().as_secs_f64() * 1e6);
        let t = Instant::now();
        std::hint::black_box(fpm_physics::background::estimate(&dark_field));
        background_us.push(t.elapsed().as_secs_f64() * 1e6);
    }
    let pass = updates.pass_ms();
    let mut passes = vec![];
    for grid in [size, 2 * size] {
        for threads in [1, 2] {
            passes.push(PassTiming {
                size: grid,
                threads,
                ms: pass_ms(grid, upsample, threads)?,
            });
        }
    }
    let streaming = streaming_latency(size, upsample, 5)?;
    let f = Percentiles::of(&mut ffts);
    let u = Percentiles::of(&mut update_us);
    let fl = Percentiles::of(&mut floors);
    let bg = Percentiles::of(&mut background_us);
    let fftw_pair = (!fftw_us.is_empty()).then(|| Percentiles::of(&mut fftw_us));
    let report = EpryBench {
        floor_over_fftw: fftw_pair.as_ref().map(|p| fl.p50_us / p.p50_us),
        fftw: match &fftw {
            Ok(f) => f.version.clone(),
            Err(why) => why.clone(),
        },
        fftw_two_ffts_us: fftw_pair,
        size,
        upsample,
        update_over_floor: u.p50_us / fl.p50_us,
        floor_two_ffts_us: fl,
        update_over_ffts: u.p50_us / f.p50_us,
        two_ffts_us: f,
        update_us: u,
        pass_441_ms: pass,
        background_over_update: bg.p50_us / u.p50_us,
        background_estimate_us: bg,
        passes,
        streaming,
    };
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!("EPRY on {size}² frames, U = {upsample}, one thread:");
        println!(
            "  FFT pair, floor         p50 {:>8.1} µs   p99 {:>8.1} µs   (rustfft rows in one batch + the transpose crate)",
            fl.p50_us, fl.p99_us
        );
        match (&report.fftw_two_ffts_us, report.floor_over_fftw) {
            (Some(p), Some(ratio)) => println!(
                "  FFT pair, FFTW          p50 {:>8.1} µs   p99 {:>8.1} µs   (second opinion: {}, FFTW_MEASURE; the floor is {:.2}× it)",
                p.p50_us, p.p99_us, report.fftw, ratio
            ),
            _ => println!("  FFT pair, FFTW          not measured: {}", report.fftw),
        }
        println!(
            "  FFT pair, fpm's Fft2    p50 {:>8.1} µs   p99 {:>8.1} µs   ({:.2}× the floor)",
            f.p50_us,
            f.p99_us,
            f.p50_us / fl.p50_us
        );
        println!(
            "  one frame update        p50 {:>8.1} µs   p99 {:>8.1} µs   ({:.2}× the floor pair, {:.2}× Fft2's)",
            u.p50_us, u.p99_us, report.update_over_floor, report.update_over_ffts
        );
        println!(
            "  a dark-field background p50 {:>8.1} µs   p99 {:>8.1} µs   ({:.2}× one update; once per frame)",
            bg.p50_us, bg.p99_us, report.background_over_update
        );
        println!("  one pass over 441 frames {:.0} ms", pass);
        for pair in report.passes.chunks(2) {
            if let [one, two] = pair {
                println!(
                    "  one pass, {0}² frames: {1:.0} ms on 1 thread, {2:.0} ms on 2 ({3:.2}×)",
                    one.size,
                    one.ms,
                    two.ms,
                    one.ms / two.ms
                );
            }
        }
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
