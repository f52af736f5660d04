//! Criterion micro-benchmark of one EPRY frame update against its baseline, the
//! forward + inverse 2-D FFT pair of the same size, measured in the same run:
//! `cargo bench -p fpm-bench --bench epry`. Read the ratio of the two, not the
//! absolute times (these machines are noisy). `fpm bench epry` reports the same ratio
//! with percentiles, plus pass times and the streaming latency.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use fpm_physics::fft::Fft2;
use fpm_physics::reconstruct::{amplitude, Epry, Settings};
use fpm_physics::{Image, LedGeometry, System};
use rustfft::num_complex::Complex32;

fn update_versus_ffts(c: &mut Criterion) {
    let system = System::paper();
    let geometry = LedGeometry::paper();
    let mut group = c.benchmark_group("epry");
    for size in [128usize, 256] {
        let frame = Image::from_shape_fn((size, size), |(r, col)| {
            1.0 + 0.3 * ((r * 7 + col * 3) % 17) as f32 / 17.0
        });
        let measured = amplitude(&frame);
        let mut fft = Fft2::new(size, size);
        let mut buf: Vec<Complex32> = frame.iter().map(|&v| Complex32::new(v, 0.0)).collect();
        group.bench_function(BenchmarkId::new("two_ffts", size), |b| {
            b.iter(|| {
                fft.forward(&mut buf);
                fft.inverse(&mut buf);
            })
        });
        let mut epry = Epry::new(&system, &frame, Settings::default());
        let leds = geometry.leds();
        let mut k = 0;
        group.bench_function(BenchmarkId::new("update", size), |b| {
            b.iter(|| {
                let led = leds[k % leds.len()];
                k += 1;
                let f = geometry.illumination_frequency(led, 0.0, 0.0, system.wavelength_um);
                epry.update_amplitude(&measured, f, true)
            })
        });
    }
    group.finish();
}

criterion_group!(benches, update_versus_ffts);
criterion_main!(benches);
