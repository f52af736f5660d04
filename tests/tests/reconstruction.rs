//! `fpm reconstruct` on real measured data from another lab (shared/data): the result
//! must carry detail the camera cannot even sample, and only where the target has it.

use std::path::{Path, PathBuf};
use std::process::Command;

use fpm_host::dataset::image_io;
use fpm_physics::fft::{bin_frequency, Fft2};
use fpm_tests::{fpm_bin, TempDir};
use ndarray::{s, Array2};
use rustfft::num_complex::Complex32;

fn usaf() -> PathBuf {
    fpm_tests::shared_data().join("zuo-usaf-11x11")
}

/// Spectral energy per pixel of a Hann-windowed region between `lo` and `hi` cycles/µm.
fn band_energy(region: Array2<f32>, pixel_um: f64, lo: f64, hi: f64) -> f64 {
    let (h, w) = region.dim();
    let mean = region.mean().unwrap_or(0.0);
    let hann = |k: usize, n: usize| {
        0.5 - 0.5 * (2.0 * std::f32::consts::PI * k as f32 / (n - 1) as f32).cos()
    };
    let mut data: Vec<Complex32> = region
        .indexed_iter()
        .map(|((r, c), &v)| Complex32::new((v - mean) * hann(r, h) * hann(c, w), 0.0))
        .collect();
    Fft2::new(w, h).forward(&mut data);
    let mut e = 0.0;
    for r in 0..h {
        for c in 0..w {
            let f = bin_frequency(c, w, pixel_um).hypot(bin_frequency(r, h, pixel_um));
            if f >= lo && f < hi {
                e += data[r * w + c].norm_sqr() as f64;
            }
        }
    }
    e / (w * h) as f64
}

fn read_f32(path: &Path) -> Array2<f32> {
    match image_io::read(path).unwrap() {
        image_io::Pixels::F32(a) => a,
        other => panic!("{} is not float32: {} bits", path.display(), other.bits()),
    }
}

#[test]
fn the_usaf_target_gains_resolution_beyond_what_the_camera_samples() {
    let out = TempDir::new("usaf");
    let run = Command::new(fpm_bin())
        .args([
            "reconstruct",
            &usaf().to_string_lossy(),
            "--out",
            &out.0.to_string_lossy(),
            "--passes",
            "15",
        ])
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    for f in [
        "amplitude.tif",
        "phase.tif",
        "pupil_amplitude.tif",
        "pupil_phase.tif",
        "amplitude.png",
        "phase.png",
        "report.json",
    ] {
        assert!(out.0.join(f).is_file(), "{f} missing");
    }
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.0.join("report.json")).unwrap()).unwrap();
    let errs: Vec<f64> = report["error_per_pass"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert!(errs.last() < errs.first(), "{errs:?}");

    let amp = read_f32(&out.0.join("amplitude.tif"));
    assert_eq!(amp.dim(), (512, 512));
    // 6.5 µm pixels at 4×, reconstructed at 4×: 0.406 µm. The camera samples up to
    // 1/(2·1.625 µm) = 0.31 cycles/µm; the band 0.33–0.55 holds groups 8.5–9.2.
    let pixel = 6.5 / 4.0 / 4.0;
    // Groups 8–9 (bars) against the interior of the flat square of group 7.
    let bars = band_energy(
        amp.slice(s![165..310, 188..348]).to_owned(),
        pixel,
        0.33,
        0.55,
    );
    let flat = band_energy(
        amp.slice(s![30..90, 228..288]).to_owned(),
        pixel,
        0.33,
        0.55,
    );
    eprintln!("energy beyond the camera's Nyquist: bars {bars:.4}, flat square {flat:.4}");
    assert!(
        bars > 10.0 * flat,
        "bars {bars} vs flat {flat}: no resolved detail beyond the camera's sampling"
    );
}
