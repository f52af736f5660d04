//! `fpm bench calibration`: pdcFPM accuracy and speed on simulated data against the
//! hidden truth (the paper's Table 1, an off-axis feature, a random sweep).

use crate::Percentiles;

use anyhow::Result;
use serde::Serialize;

#[derive(Serialize, Clone)]
struct CalibrationCase {
    name: String,
    truth: [f64; 4],
    found: [f64; 4],
    /// |Δx| µm, |Δy| µm, |θ| °, |h| mm
    error: [f64; 4],
    used_leds: usize,
    calibrate_ms: f64,
    /// Calibration time over the floor's (forward transforms of as many 256² frames),
    /// timed right after it: the machine's speed divides out.
    floor_ratio: f64,
}

#[derive(Serialize)]
struct CalibrationBench {
    cases: Vec<CalibrationCase>,
    /// The hard cases for the uncertainty coverage, and their summary.
    coverage_cases: Vec<fpm_physics::coverage::Outcome>,
    coverage: Option<fpm_physics::coverage::Coverage>,
    max_error: [f64; 4],
    median_error: [f64; 4],
    paper_table1_max_error: [f64; 4],
    calibrate_ms_median: f64,
    calibrate_ms_max: f64,
    /// Median over the cases of the calibration time over the floor's.
    floor_ratio_median: f64,
    /// Median time of the floor (forward FFTs of 26 frames of 256²), ms.
    floor_ms_median: f64,
}

/// The same-run baseline: the forward 2-D FFTs of as many 256² frames as a
/// calibration gets (what merely looking at each frame in Fourier space costs).
struct Floor {
    fft: fpm_physics::fft::Fft2,
    frame: Vec<rustfft::num_complex::Complex32>,
}

impl Floor {
    fn new() -> Self {
        let n = 256;
        let frame = (0..n * n)
            .map(|i| rustfft::num_complex::Complex32::new((i % 251) as f32, 0.0))
            .collect();
        Self {
            fft: fpm_physics::fft::Fft2::new(n, n),
            frame,
        }
    }

    /// Seconds for `frames` forward transforms.
    fn time(&mut self, frames: usize) -> f64 {
        let mut buf = self.frame.clone();
        let start = std::time::Instant::now();
        for _ in 0..frames {
            buf.copy_from_slice(&self.frame);
            self.fft.forward(&mut buf);
        }
        let took = start.elapsed().as_secs_f64();
        std::hint::black_box(&buf);
        took
    }
}

fn median(v: &mut [f64]) -> f64 {
    fpm_physics::stats::median(v).unwrap_or(f64::NAN)
}

pub fn run(random: usize, coverage: usize, seed: u64, repeat: usize, json: bool) -> Result<()> {
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
    let (mut floor, mut floors) = (Floor::new(), vec![]);
    for (k, (name, truth, side, at)) in cases.iter().enumerate() {
        let mut scene = CalibrationScene::paper(*truth, seed.wrapping_mul(1000) + k as u64);
        scene.feature_um = *side;
        scene.feature_at_um = *at;
        let frames = scene.acquire();
        let mut cal = None;
        let (mut times, mut ratios) = (vec![], vec![]);
        for _ in 0..repeat.max(1) {
            let (found, took) =
                calibrate_simulated(&scene, &frames, &nominal, &Options::default())?;
            let took = took.as_secs_f64();
            let floor = floor.time(frames.len());
            times.push(took * 1e3);
            ratios.push(took / floor);
            floors.push(floor * 1e3);
            cal.get_or_insert(found);
        }
        let Some(cal) = cal else {
            anyhow::bail!("no calibration of case {name}");
        };
        let ms = median(&mut times);
        let ratio = median(&mut ratios);
        let found = [
            cal.placement.dx_mm,
            cal.placement.dy_mm,
            cal.placement.theta_deg,
            cal.placement.height_mm,
        ];
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
            floor_ratio: ratio,
        });
        bar.inc(1);
    }
    bar.finish_and_clear();
    let column = |i: usize| -> Vec<f64> { out.iter().map(|c| c.error[i]).collect() };
    let stat = |f: fn(&mut [f64]) -> f64| [0, 1, 2, 3].map(|i| f(&mut column(i)));
    let max = |v: &mut [f64]| v.iter().copied().fold(0.0, f64::max);
    // Coverage: the simulator's defocus is exact, so h's σ leaves the defocus out.
    let hard = coverage_cases(coverage, seed, json);
    let summary = (!hard.is_empty()).then(|| fpm_physics::coverage::coverage(&hard));
    let mut times: Vec<f64> = out.iter().map(|c| c.calibrate_ms).collect();
    let t = Percentiles::of(&mut times);
    let report = CalibrationBench {
        max_error: stat(max),
        median_error: stat(median),
        paper_table1_max_error: [6.0, 12.0, 0.200, 0.92],
        calibrate_ms_median: t.p50_us,
        calibrate_ms_max: t.max_us,
        floor_ratio_median: median(&mut out.iter().map(|c| c.floor_ratio).collect::<Vec<_>>()),
        floor_ms_median: median(&mut floors),
        cases: out,
        coverage_cases: hard,
        coverage: summary,
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
        "  calibration time (one core, frames in memory; each case's median of {repeat}): median {:.1} ms, max {:.1} ms",
        e.calibrate_ms_median, e.calibrate_ms_max
    );
    println!(
        "  against the same run's floor (forward FFTs of 26 frames of 256², median {:.2} ms): calibration = {:.1}× the floor (median over the cases)",
        e.floor_ms_median, e.floor_ratio_median
    );
    if let Some(c) = &e.coverage {
        print_coverage(c);
    }
    Ok(())
}

/// `n` random hard cases, calibrated with the defocus taken as exact (as simulated).
fn coverage_cases(n: usize, seed: u64, quiet: bool) -> Vec<fpm_physics::coverage::Outcome> {
    use fpm_physics::calibrate::Options;
    use fpm_physics::coverage::{hard_case, run_case};
    use rand::SeedableRng;
    let bar = if quiet || n == 0 {
        indicatif::ProgressBar::hidden()
    } else {
        indicatif::ProgressBar::new(n as u64)
    };
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed ^ 0xC0FE);
    let options = Options {
        defocus_sigma_um: 0.0,
        ..Options::default()
    };
    let out = (0..n)
        .map(|k| {
            let scene = hard_case(&mut rng, seed.wrapping_mul(7919) + k as u64);
            let outcome = run_case(&scene, &options);
            bar.inc(1);
            outcome
        })
        .collect();
    bar.finish_and_clear();
    out
}

fn print_coverage(c: &fpm_physics::coverage::Coverage) {
    println!(
        "\nuncertainty coverage over {} random hard cases (peak 300–3000 counts, 15–60 µm features on and off axis, defocus ±100–300 µm; defocus taken as exact), {} refused with a reason:",
        c.cases, c.refused
    );
    println!("  {:<28} {:>9} {:>9} {:>9} {:>9}", "", "Δx", "Δy", "θ", "h");
    let row = |name: &str, v: [f64; 4], digits: usize| {
        println!(
            "  {:<28} {:>9.digits$} {:>9.digits$} {:>9.digits$} {:>9.digits$}",
            name, v[0], v[1], v[2], v[3]
        );
    };
    row("within 1σ (ideal 0.68)", c.within_1_sigma, 2);
    row("within 3σ (ideal 0.997)", c.within_3_sigma, 3);
    row("median |error| (µm, µm, °, mm)", c.median_abs_error, 4);
    row("max |error|", c.max_abs_error, 4);
    row("median σ reported", c.median_sigma, 4);
    let count = |name: &str, v: [usize; 4]| {
        println!(
            "  {:<28} {:>9} {:>9} {:>9} {:>9}",
            name, v[0], v[1], v[2], v[3]
        );
    };
    let t = fpm_physics::calibrate::ACCURACY_TARGET;
    println!(
        "  accuracy target: Δx, Δy {} µm, θ {}°, h {} mm (1σ beyond it: a warning)",
        t[0], t[2], t[3]
    );
    count("warned", c.warned);
    count("error beyond the target", c.beyond_target);
    count("…of those, not warned", c.beyond_target_unwarned);
}
