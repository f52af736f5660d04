//! `fpm bench dpc`: one DPC update (four half-circle frames in, phase and absorption
//! out) on one core, against the floor of the six 2-D FFTs it cannot avoid (four
//! forward, two inverse), both measured in the same run.

use std::time::Instant;

use anyhow::Result;
use fpm_physics::dpc::{self, Dpc, Half, Regularisation, Transfer};
use fpm_physics::fft::Fft2;
use fpm_physics::{Complex32, Image, LedGeometry, System};
use serde::Serialize;

use crate::stats::Percentiles;

/// What `fpm bench dpc` measured.
#[derive(Debug, Serialize)]
pub struct DpcBench {
    /// Frame side, pixels.
    pub size: usize,
    /// Planning (transfer functions and the per-bin inverse), ms, once.
    pub plan_ms: f64,
    /// One update, µs.
    pub update_us: Percentiles,
    /// Four forward and two inverse FFTs, µs.
    pub floor_us: Percentiles,
    /// Median update over median floor.
    pub update_over_floor: f64,
}

pub fn run(size: usize, rounds: usize, json: bool) -> Result<()> {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let bench = pool.install(|| measure(size, rounds.max(5)));
    if json {
        println!("{}", serde_json::to_string_pretty(&bench)?);
        return Ok(());
    }
    println!(
        "DPC update, {size}² frames, one core: median {:.2} ms (p99 {:.2} ms); the six FFTs alone {:.2} ms: {:.2}x the floor; planned once in {:.0} ms",
        bench.update_us.p50_us / 1e3,
        bench.update_us.p99_us / 1e3,
        bench.floor_us.p50_us / 1e3,
        bench.update_over_floor,
        bench.plan_ms
    );
    Ok(())
}

fn measure(size: usize, rounds: usize) -> DpcBench {
    let (system, geometry) = (System::paper(), LedGeometry::paper());
    let leds = geometry.leds();
    let start = Instant::now();
    let transfers: Vec<Transfer> = Half::ALL
        .iter()
        .map(|&half| {
            let lit: Vec<(f64, f64)> = dpc::half_circle(&geometry, &system, &leds, half)
                .iter()
                .map(|&led| geometry.pupil_frequency(led, 0.0, 0.0, &system))
                .collect();
            Transfer::new(
                &lit,
                system.cutoff(),
                (size, size),
                system.sample_pixel_um(),
            )
        })
        .collect();
    let mut solver = Dpc::new(&transfers, (size, size), Regularisation::default());
    let plan_ms = start.elapsed().as_secs_f64() * 1e3;
    // Frames of a slowly varying brightness: the update's work does not depend on them.
    let frames: Vec<Image> = (0..4)
        .map(|k| {
            Image::from_shape_fn((size, size), |(r, c)| {
                1000.0 + ((r * 7 + c * 13 + k * 31) % 97) as f32
            })
        })
        .collect();
    let refs: Vec<&Image> = frames.iter().collect();
    let mut fft = Fft2::new(size, size);
    let mut data = vec![Complex32::new(1.0, 0.0); size * size];
    let (mut update, mut floor) = (Vec::new(), Vec::new());
    for _ in 0..rounds {
        let t = Instant::now();
        std::hint::black_box(solver.solve(&refs));
        update.push(t.elapsed().as_secs_f64() * 1e6);
        let t = Instant::now();
        for _ in 0..4 {
            fft.forward(&mut data);
        }
        for _ in 0..2 {
            fft.inverse(&mut data);
        }
        std::hint::black_box(&data);
        floor.push(t.elapsed().as_secs_f64() * 1e6);
    }
    let (update_us, floor_us) = (Percentiles::of(&mut update), Percentiles::of(&mut floor));
    DpcBench {
        size,
        plan_ms,
        update_over_floor: update_us.p50_us / floor_us.p50_us,
        update_us,
        floor_us,
    }
}
