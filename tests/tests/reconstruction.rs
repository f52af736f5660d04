//! `fpm reconstruct` on real measured data from another lab (data/ in this repository): the result
//! must carry detail the camera cannot even sample, and only where the target has it.

use std::path::{Path, PathBuf};
use std::process::Command;

use fpm_host::dataset::image_io;
use fpm_physics::fft::{bin_frequency, Fft2};
use fpm_tests::{fpm_bin, fpm_stdout, read_f32, TempDir};
use ndarray::{s, Array2};
use rustfft::num_complex::Complex32;

fn usaf() -> PathBuf {
    fpm_tests::data_dir().join("zuo-usaf-11x11")
}

/// The USAF set's camera pixel at the sample: 6.5 µm at 4×.
const USAF_PIXEL_UM: f64 = 1.625;

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
    assert!((report["pixel_um"].as_f64().unwrap() - pixel).abs() < 1e-9);
    // The preview's scale bar: the longest white run in its bottom quarter, as long
    // as the bar's length says.
    let image_io::Pixels::U8(preview) = image_io::read(&out.0.join("amplitude.png")).unwrap()
    else {
        panic!("amplitude.png is not 8-bit grey");
    };
    let bar_um = fpm_report::scale_bar::bar_length_um(512.0 * pixel).unwrap();
    let bar_px = (bar_um / pixel).round() as usize;
    // On its black plate at the lower left (the image beside it may saturate too).
    let longest_run = (384..512)
        .map(|r| {
            let mut run = (0, 0);
            for &v in preview.row(r).iter().take(bar_px + 24) {
                run.0 = if v == 255 { run.0 + 1 } else { 0 };
                run.1 = run.1.max(run.0);
            }
            run.1
        })
        .max()
        .unwrap();
    assert_eq!(longest_run, bar_px);
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

/// `fpm simulate acquisition --out DIR` with `extra` arguments.
fn simulate_acquisition(dir: &TempDir, extra: &[&str]) {
    let out = dir.0.to_string_lossy();
    let mut args = vec!["simulate", "acquisition", "--out", &out];
    args.extend_from_slice(extra);
    fpm_stdout(&args);
}

/// A simulated acquisition with the array where the dataset says it is (for tests that
/// are not about geometry): `size`² frames, `seed`.
fn simulate_centred(dir: &TempDir, size: &str, seed: &str) {
    fpm_tests::simulate_centred(&dir.0, size, seed, &[]);
}

/// The array where the dataset says it is.
const CENTRED: &[&str] = &["--dx-mm", "0", "--dy-mm", "0", "--theta-deg", "0"];

/// The rigid placement the LED-refinement tests simulate with and give (as JSON).
const REFINE_RIGID: &[&str] = &["--dx-mm", "0.3", "--dy-mm", "-0.2", "--theta-deg", "1"];
const REFINE_RIGID_JSON: &str =
    r#"{ "dx_mm": 0.3, "dy_mm": -0.2, "theta_deg": 1.0, "height_mm": 92.0 }"#;

/// 128² frames of the 8-bit camera with dark-field frames as dim as the USAF set's.
const DIM_EIGHT_BIT_128: &[&str] = &[
    "--size",
    "128",
    "--noise",
    "eight-bit",
    "--dark-field-peak-dn",
    "25",
];

/// `truth.json` beside a simulated dataset in `dir`.
fn truth_json(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("truth.json")).unwrap()).unwrap()
}

fn report(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap()
}

/// `fpm reconstruct DATASET --out OUT EXTRA…`, which must succeed; its stderr (the
/// warnings).
fn reconstruct_ok(dataset: &Path, out: &Path, extra: &[&str]) -> String {
    let done = Command::new(fpm_bin())
        .args(["reconstruct", &dataset.to_string_lossy(), "--out"])
        .arg(out)
        .args(extra)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&done.stderr).into_owned();
    assert!(done.status.success(), "{stderr}");
    stderr
}

/// Variation of `amplitude` over the clear glass: pixels where the centre frame `raw`
/// (camera grid of `raw_pixel_um` at the sample, `amplitude` is `f`× finer) is within
/// 15 % of its bright level, three camera pixels and a further 2 µm away from any edge
/// of the sample or of the field. The 2 µm are the ringing of a band-limited image of an
/// opaque edge (a few % that far out at the synthetic NA of the USAF set), which is
/// resolution, not background, and the field's own border. Each
/// pixel is divided by the mean of the clear pixels within ten camera pixels around it,
/// so the slow illumination does not count.
fn clear_glass_variation(raw: &Array2<f32>, amplitude: &Array2<f32>, raw_pixel_um: f64) -> f64 {
    let mut sorted: Vec<f32> = raw.iter().copied().collect();
    sorted.sort_by(f32::total_cmp);
    let bright = sorted[sorted.len() * 95 / 100];
    let mut clear = raw.mapv(|v| v > 0.85 * bright);
    for _ in 0..3 {
        let c = clear.clone();
        let (h, w) = c.dim();
        for ((r, k), v) in clear.indexed_iter_mut() {
            *v = c[[r, k]]
                && c[[r.saturating_sub(1), k]]
                && c[[(r + 1).min(h - 1), k]]
                && c[[r, k.saturating_sub(1)]]
                && c[[r, (k + 1).min(w - 1)]];
        }
    }
    let f = amplitude.dim().0 / raw.dim().0;
    let (h, w) = amplitude.dim();
    let fine = Array2::from_shape_fn((h, w), |(r, c)| clear[[r / f, c / f]]);
    let ringing_px = (2.0 / (raw_pixel_um / f as f64)).round() as usize;
    // Outside the field counts as an edge: the field's own border holds the FFT's
    // wrap-around (a crop's two sides do not meet), not the sample's background.
    let fine = eroded(&fine, ringing_px);
    let is_clear = |r: usize, c: usize| fine[[r, c]];
    // Integral images of the clear pixels' amplitude and count.
    let mut sum = Array2::<f64>::zeros((h + 1, w + 1));
    let mut count = Array2::<f64>::zeros((h + 1, w + 1));
    for r in 0..h {
        for c in 0..w {
            let (a, n) = if is_clear(r, c) {
                (amplitude[[r, c]] as f64, 1.0)
            } else {
                (0.0, 0.0)
            };
            sum[[r + 1, c + 1]] = a + sum[[r, c + 1]] + sum[[r + 1, c]] - sum[[r, c]];
            count[[r + 1, c + 1]] = n + count[[r, c + 1]] + count[[r + 1, c]] - count[[r, c]];
        }
    }
    let half = 10 * f;
    let box_of = |t: &Array2<f64>, r: usize, c: usize| {
        let (r0, r1) = (r.saturating_sub(half), (r + half + 1).min(h));
        let (c0, c1) = (c.saturating_sub(half), (c + half + 1).min(w));
        t[[r1, c1]] - t[[r0, c1]] - t[[r1, c0]] + t[[r0, c0]]
    };
    let ratios: Vec<f64> = (0..h)
        .flat_map(|r| (0..w).map(move |c| (r, c)))
        .filter(|&(r, c)| is_clear(r, c))
        .map(|(r, c)| amplitude[[r, c]] as f64 / (box_of(&sum, r, c) / box_of(&count, r, c)))
        .collect();
    let mean = ratios.iter().sum::<f64>() / ratios.len() as f64;
    (ratios.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / ratios.len() as f64).sqrt()
}

/// `mask` eroded `n` times by the 4-neighbour cross, outside the array counting as
/// false: a pixel stays where no false pixel, nor the outside, lies within city-block
/// distance `n`. Two passes of the city-block distance transform, where `n` passes of
/// the cross over the 25-Mpixel grid of the ring-array test took a minute of one core
/// (a unit test below checks the two agree).
fn eroded(mask: &Array2<bool>, n: usize) -> Array2<bool> {
    let (h, w) = mask.dim();
    let mut d = vec![0u32; h * w];
    for ((r, c), &v) in mask.indexed_iter() {
        let i = r * w + c;
        if v {
            let up = if r > 0 { d[i - w] } else { 0 };
            let left = if c > 0 { d[i - 1] } else { 0 };
            d[i] = up.min(left) + 1;
        }
    }
    for i in (0..h * w).rev() {
        let (r, c) = (i / w, i % w);
        if d[i] > 0 {
            let down = if r + 1 < h { d[i + w] } else { 0 };
            let right = if c + 1 < w { d[i + 1] } else { 0 };
            d[i] = d[i].min(down.min(right) + 1);
        }
    }
    Array2::from_shape_vec((h, w), d.into_iter().map(|v| v as usize > n).collect())
        .expect("the mask's shape")
}

#[test]
fn the_distance_transform_erodes_as_the_cross_does() {
    let mut x = 12345u32;
    for (h, w, n) in [(1, 1, 1), (7, 5, 1), (19, 23, 2), (40, 31, 5), (64, 64, 9)] {
        for density in [60u32, 90, 99] {
            let mask = Array2::from_shape_fn((h, w), |_| {
                x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                (x >> 8) % 100 < density
            });
            let mut crossed = mask.clone();
            for _ in 0..n {
                let c = crossed.clone();
                for ((r, k), v) in crossed.indexed_iter_mut() {
                    *v = c[[r, k]]
                        && r > 0
                        && c[[r - 1, k]]
                        && r + 1 < h
                        && c[[r + 1, k]]
                        && k > 0
                        && c[[r, k - 1]]
                        && k + 1 < w
                        && c[[r, k + 1]];
                }
            }
            assert_eq!(
                eroded(&mask, n),
                crossed,
                "{h}×{w}, {n} passes, {density} % true"
            );
        }
    }
}

/// Dark-field frames of the real USAF set sit on backgrounds the dataset does not state
/// (6 stored counts in the four corner frames, against signals of 10–30; 0.1 counts of
/// light once decoded from the set's display gamma): taken off per frame with a floor at
/// 3σ of their noise (the default), the clear glass is cleaner than with the dataset's
/// dark level alone, and the bars keep their detail (the test above runs with the
/// default too).
#[test]
fn dark_field_backgrounds_come_off_the_real_usaf_frames() {
    let (default, dark_level) = (TempDir::new("usaf-bg"), TempDir::new("usaf-dark"));
    let dir = usaf().to_string_lossy().into_owned();
    fpm_stdout(&["reconstruct", &dir, "--out", &default.0.to_string_lossy()]);
    fpm_stdout(&[
        "reconstruct",
        &dir,
        "--out",
        &dark_level.0.to_string_lossy(),
        "--background",
        "dark-level",
    ]);
    let r = report(&default.0);
    assert_eq!(r["background"]["correction"], "per frame");
    assert_eq!(r["background"]["floor_sigma"], 3.0);
    let frames = r["background"]["dark_field_frames"].as_array().unwrap();
    for corner in [[10, 0], [9, 10], [10, 9], [10, 10]] {
        let b = frames
            .iter()
            .find(|b| b["led"] == serde_json::json!(corner))
            .unwrap_or_else(|| panic!("LED {corner:?} not measured"));
        let level = b["level_counts"].as_f64().unwrap();
        assert!(
            b["taken_off"] == true && level > 0.0,
            "corner frame {corner:?}: {b}"
        );
    }
    assert_eq!(
        report(&dark_level.0)["background"]["dark_field_frames"],
        serde_json::json!([])
    );
    let raw = usaf_centre_light();
    let (ours, plain) = (
        clear_glass_variation(
            &raw,
            &read_f32(&default.0.join("amplitude.tif")),
            USAF_PIXEL_UM,
        ),
        clear_glass_variation(
            &raw,
            &read_f32(&dark_level.0.join("amplitude.tif")),
            USAF_PIXEL_UM,
        ),
    );
    let centre_frame = clear_glass_variation(&raw, &raw.mapv(f32::sqrt), USAF_PIXEL_UM);
    eprintln!(
        "clear-glass variation of |o|: per-frame backgrounds {ours:.4}, dark level only {plain:.4}, centre frame {centre_frame:.4}"
    );
    // Measured: 0.0138 against 0.0299 (the centre frame's light, 0.0114).
    assert!(ours < 0.7 * plain, "{ours} against {plain}");
}

/// The light of the USAF set's centre frame (LED (5, 5)), decoded as the dataset states.
fn usaf_centre_light() -> Array2<f32> {
    let ds = fpm_host::dataset::Dataset::load(&usaf()).unwrap();
    let centre = ds
        .frames
        .iter()
        .position(|f| f.entry.led == fpm_physics::LedIndex::new(5, 5))
        .unwrap();
    let m = ds.measured(centre);
    m.intensity(fpm_physics::frame::Region::whole(m.dim()))
}

/// The vendored USAF frames were saved with a display gamma (γ ≈ 2.2; the set's README
/// has the evidence). Read as linear counts, no object explains their bright-field
/// frames: the report's fit of those frames against the result leaves ~40 % of their
/// light as an offset and warns, and the image rings (bright halos on every bar, the
/// clear glass rippled). Decoded as the dataset says, the fit closes and the clear glass
/// varies no more than the centre frame's light does. A dataset that does not state the
/// gamma of its 8-bit frames has it read from them by default.
#[test]
fn the_usaf_frames_decoded_from_their_display_gamma_are_explained_and_clean() {
    let dir = TempDir::new("usaf-gamma");
    let linear = usaf_copy(&dir.0);
    let toml = linear.join("dataset.toml");
    let stated = std::fs::read_to_string(&toml).unwrap();
    assert!(stated.contains("gamma = 2.2\n"), "{stated}");
    std::fs::write(&toml, stated.replace("gamma = 2.2\n", "")).unwrap();
    let run = |dataset: &Path, out: &Path, extra: &[&str]| {
        let stderr = reconstruct_ok(dataset, out, extra);
        (report(out), read_f32(&out.join("amplitude.tif")), stderr)
    };
    let (as_linear, decoded) = (dir.0.join("as-linear"), dir.0.join("decoded"));
    let (r_linear, a_linear, warned_linear) = run(&linear, &as_linear, &["--camera-gamma", "1"]);
    let (r_decoded, a_decoded, warned_decoded) = run(&usaf(), &decoded, &[]);
    // The command line can say what the dataset does not, to the same result.
    let told = dir.0.join("told");
    let (r_told, _, _) = run(&linear, &told, &["--camera-gamma", "2.2"]);
    assert_eq!(r_told["bright_field_fit"], r_decoded["bright_field_fit"]);
    assert_eq!(r_told["camera_gamma"], 2.2);
    // Or it can read the gamma from the frames.
    let auto = dir.0.join("auto");
    let (r_auto, _, warned_auto) = run(&linear, &auto, &["--camera-gamma", "auto"]);
    let scan = &r_auto["camera_gamma_scan"];
    let best = scan["best"].as_f64().unwrap();
    eprintln!("gamma read from the frames: {best} ({scan})");
    assert!((2.0..=2.5).contains(&best), "{scan}");
    assert_eq!(r_auto["camera_gamma"].as_f64(), Some(best));
    assert!(
        r_auto["bright_field_fit"]["offset_share"]
            .as_f64()
            .unwrap()
            .abs()
            < 0.05,
        "{}",
        r_auto["bright_field_fit"]
    );
    assert!(!warned_auto.contains("is weak"), "{warned_auto}");
    // Without the flag, the unstated gamma of 8-bit frames is read so too, and said.
    let (r_default, _, warned_default) = run(&linear, &dir.0.join("default"), &[]);
    assert_eq!(r_default["camera_gamma"], r_auto["camera_gamma"]);
    assert_eq!(r_default["camera_gamma_scan_reason"], "eight-bit-unstated");
    assert!(
        warned_default.contains("decoded with") && warned_default.contains("--camera-gamma 1"),
        "{warned_default}"
    );
    let share = |r: &serde_json::Value| r["bright_field_fit"]["offset_share"].as_f64().unwrap();
    let correlation =
        |r: &serde_json::Value| r["bright_field_fit"]["correlation"].as_f64().unwrap();
    eprintln!(
        "bright-field fit: as linear {}, decoded {}",
        r_linear["bright_field_fit"], r_decoded["bright_field_fit"]
    );
    assert!(share(&r_linear) > 0.15, "{}", r_linear["bright_field_fit"]);
    assert!(
        warned_linear.contains("display gamma") && warned_linear.contains("--camera-gamma auto"),
        "{warned_linear}"
    );
    // The same frames stored as floats carry no display gamma (a gamma flag would be
    // refused for them): the offset is still named, the gamma advice is not.
    let mut floats = fpm_host::dataset::Dataset::load(&linear).unwrap();
    for f in &mut floats.frames {
        f.raw = fpm_host::dataset::Pixels::F32(f.raw.to_f32());
    }
    let r_floats = fpm_host::reconstruction::Job::default()
        .run_in_memory(&floats, &|_, _| {})
        .unwrap();
    let warned_floats = fpm_host::reconstruction::warnings(&r_floats.report).join("\n");
    assert!(
        warned_floats.contains("no object explains")
            && warned_floats.contains("float frames carry no display gamma")
            && !warned_floats.contains("--camera-gamma"),
        "{warned_floats}"
    );
    assert!(
        share(&r_decoded).abs() < 0.05 && correlation(&r_decoded) > 0.97,
        "{}",
        r_decoded["bright_field_fit"]
    );
    assert!(
        !warned_decoded.contains("no object explains"),
        "{warned_decoded}"
    );
    assert_eq!(r_decoded["camera_gamma"], 2.2);
    assert!(r_linear.get("camera_gamma").is_none());
    let light = usaf_centre_light();
    let frame = clear_glass_variation(&light, &light.mapv(f32::sqrt), USAF_PIXEL_UM);
    let (linear, decoded) = (
        clear_glass_variation(&light, &a_linear, USAF_PIXEL_UM),
        clear_glass_variation(&light, &a_decoded, USAF_PIXEL_UM),
    );
    eprintln!("clear-glass variation: as linear {linear:.4}, decoded {decoded:.4}, the centre frame's light {frame:.4}");
    assert!(
        decoded < 1.5 * frame,
        "{decoded} against the frame's {frame}"
    );
    assert!(
        decoded < 0.5 * linear,
        "{decoded} against {linear} as linear"
    );
}

/// The background of a dark frame as `fpm reconstruct` measures it: (level, noise).
fn dark_frame_background(counts: fpm_physics::frame::Counts<'_>) -> (f64, f64) {
    let b = fpm_physics::background::estimate(&fpm_physics::frame::Measured {
        counts,
        response: fpm_physics::frame::Response::Linear,
        dark_level: 0.0,
        exposure_ms: 1.0,
        floor: 0.0,
        soft_floor: false,
        band: 0.0,
    })
    .expect("a 128² frame has blocks");
    (f64::from(b.level), f64::from(b.noise))
}

/// The simulator's 8-bit camera (`--noise eight-bit`) against the camera behind the
/// vendored USAF set: its dark frames sit on the same background, level and noise as
/// `fpm reconstruct` measures them, against the median of the set's dark-field frames.
/// At that noise, with dark-field frames as dim as the set's (25 counts at the peak),
/// the default reconstruction of a simulated acquisition leaves the clear glass varying
/// about as much as the raw centre frame's: the camera's noise alone does not make the
/// several-fold excess the real set showed while its frames were read as linear counts
/// (their display gamma did: the test above; README, dark-field backgrounds). The set's
/// dark frames are compared as stored, and the simulated camera is a linear one.
#[test]
fn an_eight_bit_camera_as_noisy_as_the_usaf_sets_leaves_clear_glass_clean() {
    use rand::SeedableRng;
    // The set's dark-field frames (all but the 3×3 bright-field block in its middle):
    // the median of each statistic, as a few of them hold more stray light or signal.
    let bright_field =
        |k: usize| (4..=6).contains(&((k - 1) / 11)) && (4..=6).contains(&((k - 1) % 11));
    let real: Vec<(f64, f64)> = (1..=121)
        .filter(|&k| !bright_field(k))
        .map(|k| {
            let image_io::Pixels::U8(a) =
                image_io::read(&usaf().join(format!("frames/img_{k:03}.tif"))).unwrap()
            else {
                panic!("the USAF frames are 8-bit");
            };
            dark_frame_background(fpm_physics::frame::Counts::U8(a.view()))
        })
        .collect();
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let real = (
        median(real.iter().map(|r| r.0).collect()),
        median(real.iter().map(|r| r.1).collect()),
    );
    let camera = fpm_physics::simulate::Camera::eight_bit();
    let dark = camera.record(
        &Array2::zeros((128, 128)),
        1000.0,
        &mut rand::rngs::StdRng::seed_from_u64(3),
    );
    let sim = dark_frame_background(fpm_physics::frame::Counts::U16(dark.view()));
    eprintln!("dark frames (level, noise): real {real:?}, simulated {sim:?}");
    assert!(
        (sim.0 - real.0).abs() < 0.5 && (0.8..1.25).contains(&(sim.1 / real.1)),
        "simulated {sim:?} against real {real:?}"
    );

    let (data, out) = (
        TempDir::new("eight-bit-data"),
        TempDir::new("eight-bit-out"),
    );
    let mut args = DIM_EIGHT_BIT_128.to_vec();
    args.extend_from_slice(CENTRED);
    simulate_acquisition(&data, &args);
    fpm_stdout(&[
        "reconstruct",
        &data.0.to_string_lossy(),
        "--out",
        &out.0.to_string_lossy(),
    ]);
    let image_io::Pixels::U16(centre) = image_io::read(&data.0.join("frames/r10_c10.tif")).unwrap()
    else {
        panic!("simulated frames are 16-bit TIFFs");
    };
    let centre = centre.mapv(|v| (f32::from(v) - camera.dark_level_dn as f32).max(0.0));
    let pixel_um = report(&out.0)["system"]["pixel_size_um"].as_f64().unwrap()
        / report(&out.0)["system"]["magnification"].as_f64().unwrap();
    let (ours, raw) = (
        clear_glass_variation(&centre, &read_f32(&out.0.join("amplitude.tif")), pixel_um),
        clear_glass_variation(&centre, &centre.mapv(f32::sqrt), pixel_um),
    );
    eprintln!("clear-glass variation of |o|: reconstruction {ours:.4}, centre frame {raw:.4}");
    // Measured: 0.0082 against 0.0157. The real set by the same measure: 0.0138 against
    // 0.0114 decoded, 0.0347 read as linear (the tests above).
    assert!(ours < 2.0 * raw, "{ours} against the centre frame's {raw}");
}

/// The full field of view in tiles: on a simulated acquisition (full wave-optics
/// model, truth beside the data), 3×3 overlapping tiles — each with
/// its own wave vectors — blend into one image close to the whole-field reconstruction;
/// and a non-square frame is tiled without complaint.
#[test]
fn tiles_blend_into_the_whole_field() {
    let data = TempDir::new("tiles-data");
    let d = data.0.to_string_lossy().into_owned();
    // This test is about tiles, not geometry.
    simulate_centred(&data, "256", "4");
    let (whole, tiled) = (TempDir::new("tiles-whole"), TempDir::new("tiles-tiled"));
    for (out, tile) in [(&whole, "256"), (&tiled, "128")] {
        fpm_stdout(&[
            "reconstruct",
            &d,
            "--out",
            &out.0.to_string_lossy(),
            "--tile",
            tile,
        ]);
    }
    let (rw, rt) = (report(&whole.0), report(&tiled.0));
    assert_eq!(rw["tiles"].as_array().unwrap().len(), 1);
    let tiles = rt["tiles"].as_array().unwrap();
    assert_eq!(tiles.len(), 9, "3×3 tiles of 128 px over 256 px");
    // Each tile took the wave vectors at its own centre.
    let centres: Vec<f64> = tiles
        .iter()
        .map(|t| t["centre_um"][0].as_f64().unwrap())
        .collect();
    assert!(centres[0] < 0.0 && centres[2] > 0.0, "{centres:?}");
    let score = |r: &serde_json::Value, key: &str| r["versus_truth"][key].as_f64().unwrap();
    let (e_whole, e_tiled) = (score(&rw, "complex_nrmse"), score(&rt, "complex_nrmse"));
    let (a_whole, a_tiled) = (score(&rw, "amplitude_nrmse"), score(&rt, "amplitude_nrmse"));
    eprintln!(
        "complex NRMSE whole field {e_whole:.3}, 3×3 tiles {e_tiled:.3}; amplitude {a_whole:.3} / {a_tiled:.3}"
    );
    assert!(e_whole < 0.2, "whole field {e_whole}");
    // Amplitude blends seamlessly; the phase of features larger than a tile is
    // recovered less well in tiles (each sees only part of them), so allow more there.
    assert!(
        a_tiled < 1.2 * a_whole + 0.005,
        "tiled amplitude {a_tiled} vs {a_whole}"
    );
    assert!(
        e_tiled < 2.0 * e_whole,
        "tiled {e_tiled} vs whole field {e_whole}"
    );
    let amp = read_f32(&tiled.0.join("amplitude.tif"));
    assert_eq!(amp.dim(), (256 * 4, 256 * 4));

    // h from the bright/dark-field edge agrees with the dataset's (the true one, 92 mm)
    // to the NA's uncertainty. (This simulator applies the pupil on its padded grid's
    // frequency bins, which moves the edge by up to half a bin, ~1.2 % of the NA here;
    // host/physics/tests/calibration_boundary.rs takes a wide margin and gets 0.1 mm.)
    let boundary = |r: &serde_json::Value, key: &str| {
        r["height_from_boundary"][key]
            .as_f64()
            .unwrap_or_else(|| panic!("height_from_boundary.{key} in {r}"))
    };
    let h = boundary(&rw, "height_mm");
    eprintln!(
        "h from the edge {h:.3} ± {:.3} mm (± {:.3} with the NA)",
        boundary(&rw, "sigma_mm"),
        boundary(&rw, "sigma_with_na_mm")
    );
    assert!((h - 92.0).abs() < 0.02 * 92.0, "{h}");
    assert!(boundary(&rw, "difference_sigma").abs() < 3.0);
    // …and catches a geometry whose h is 10 % off (a misreported defocus), the edge
    // staying where it is.
    let wrong = data.0.join("h-10-percent-off.json");
    std::fs::write(
        &wrong,
        r#"{ "dx_mm": 0.0, "dy_mm": 0.0, "theta_deg": 0.0, "height_mm": 101.2 }"#,
    )
    .unwrap();
    let off = TempDir::new("tiles-h-off");
    let run = Command::new(fpm_bin())
        .args(["reconstruct", &d, "--passes", "1", "--out"])
        .arg(&off.0)
        .arg("--calibration")
        .arg(&wrong)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{stderr}");
    let r = report(&off.0);
    assert!(
        (boundary(&r, "height_mm") - 92.0).abs() < 0.02 * 92.0,
        "{r}"
    );
    assert!(boundary(&r, "difference_sigma") < -3.0, "{r}");
    assert!(
        stderr.contains("bright/dark-field boundary puts the LEDs"),
        "a warning says so: {stderr}"
    );

    // A non-square frame: crop the frames to 256 × 120 and reconstruct as is.
    let ds = fpm_host::dataset::Dataset::load(&data.0).unwrap();
    let cropped: Vec<Array2<u16>> = ds
        .frames
        .iter()
        .map(|f| match &f.raw {
            image_io::Pixels::U16(a) => a.slice(s![..120, ..]).to_owned(),
            _ => panic!("simulated frames are 16-bit"),
        })
        .collect();
    let narrow = TempDir::new("tiles-narrow");
    fpm_host::dataset::Dataset::write(&narrow.0, &ds.manifest, &cropped).unwrap();
    let out = TempDir::new("tiles-narrow-out");
    fpm_stdout(&[
        "reconstruct",
        &narrow.0.to_string_lossy(),
        "--out",
        &out.0.to_string_lossy(),
        "--passes",
        "3",
    ]);
    let r = report(&out.0);
    assert_eq!(r["frame_size"], serde_json::json!([256, 120]));
    assert_eq!(
        r["tiles"].as_array().unwrap().len(),
        4,
        "four 120-px tiles across 256 px (overlapping by half a tile, the most allowed: \
         8 PSF widths would be 63 px)"
    );
    assert_eq!(
        read_f32(&out.0.join("amplitude.tif")).dim(),
        (120 * 4, 256 * 4)
    );
}

/// `--refine-leds` through the command line: a simulated board whose LEDs are off their
/// grid (σ 0.25 mm) and tilted 1°, the reconstruction told only the rigid placement.
/// The refined run must be closer to the truth, its LEDs closer to where they were,
/// and the board it fits must be a placement file the next run reads.
#[test]
fn refined_leds_come_closer_to_a_misbuilt_board() {
    let data = TempDir::new("refine-data");
    let d = data.0.to_string_lossy().into_owned();
    let mut args = vec!["--size", "128", "--seed", "3"];
    args.extend_from_slice(REFINE_RIGID);
    args.extend(["--tilt-x-deg", "1", "--led-jitter-mm", "0.25"]);
    simulate_acquisition(&data, &args);
    let truth = truth_json(&data.0);
    assert_eq!(
        truth["leds"].as_array().map(Vec::len),
        Some(441),
        "truth.json lists the LEDs"
    );
    let rigid = data.0.join("rigid.json");
    std::fs::write(&rigid, REFINE_RIGID_JSON).unwrap();
    let run = |out: &TempDir, extra: &[&str]| {
        let mut args = vec![
            "reconstruct",
            &d,
            "--out",
            out.0.to_str().unwrap(),
            "--calibration",
            rigid.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        let out = Command::new(fpm_bin()).args(&args).output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(out.status.success(), "{args:?}: {stderr}");
        stderr
    };
    let (plain, refined) = (TempDir::new("refine-plain"), TempDir::new("refine-refined"));
    run(&plain, &[]);
    run(&refined, &["--refine-leds"]);
    let (rp, rr) = (report(&plain.0), report(&refined.0));
    assert!(rp.get("refined_leds").is_none(), "only when asked");
    // Auto-exposed dark field: the positions are worth keeping, no dim warning.
    assert!(!says_dim_dark_field(&rr), "{}", rr["warnings"]);
    let nrmse = |r: &serde_json::Value| r["versus_truth"]["complex_nrmse"].as_f64().unwrap();
    let leds = &rr["refined_leds"];
    let score = |key: &str| leds["versus_truth"][key].as_f64().unwrap();
    eprintln!(
        "complex NRMSE {:.3} rigid, {:.3} refined; LEDs off by {:.3} mm as given, {:.3} refined; board {}",
        nrmse(&rp),
        nrmse(&rr),
        score("given_rms_mm"),
        score("refined_rms_mm"),
        leds["board"]
    );
    assert!(
        nrmse(&rr) < 0.8 * nrmse(&rp),
        "{} vs {}",
        nrmse(&rr),
        nrmse(&rp)
    );
    assert_eq!(leds["leds"].as_array().map(Vec::len), Some(441));
    assert!(score("refined_rms_mm") < 0.8 * score("given_rms_mm"));
    // The fitted board is a placement file: the next run reads it.
    let board = refined.0.join("refined-board.json");
    let placement = fpm_host::calibration::PlacementFile::read(&board).unwrap();
    assert!(
        (placement.placement.tilt_x_deg - leds["board"]["tilt_x_deg"].as_f64().unwrap()).abs()
            < 1e-9
    );
    let again = TempDir::new("refine-again");
    let mut args = vec![
        "reconstruct",
        &d,
        "--out",
        again.0.to_str().unwrap(),
        "--passes",
        "1",
    ];
    args.extend(["--calibration", board.to_str().unwrap()]);
    fpm_stdout(&args);
    assert_eq!(
        report(&again.0)["geometry_source"],
        board.display().to_string()
    );
    // In small tiles a bin is more than a millimetre of LED travel: a warning says so.
    let tiles = TempDir::new("refine-tiles");
    let stderr = run(&tiles, &["--refine-leds", "--tile", "64", "--passes", "3"]);
    assert!(
        stderr.contains("refined in tiles where one frequency bin is"),
        "{stderr}"
    );
}

/// The issue's case through the command line: dark-field frames not auto-exposed
/// (peaking at 25 counts), a board whose LEDs are off their grid and tilted, the
/// reconstruction told the rigid placement. Refinement must improve the image of the
/// misbuilt board, not hurt a perfect board's, and keep the board's height where the
/// placement put it (it once ran away, 1.7 % in ten passes).
#[test]
fn refinement_with_dim_dark_field_helps_a_misbuilt_board_and_spares_a_perfect_one() {
    let case = |name: &str, misbuilt: bool| {
        let data = TempDir::new(name);
        let mut args = vec![
            "--size",
            "128",
            "--seed",
            "11",
            "--dark-field-peak-dn",
            "25",
        ];
        args.extend_from_slice(REFINE_RIGID);
        if misbuilt {
            args.extend(["--tilt-x-deg", "1", "--led-jitter-mm", "0.25"]);
        }
        simulate_acquisition(&data, &args);
        let placement = data.0.join("rigid.json");
        std::fs::write(&placement, REFINE_RIGID_JSON).unwrap();
        let run = |extra: &[&str]| {
            let out = data.0.join(format!("out{}", extra.len()));
            let mut args = vec!["--calibration", placement.to_str().unwrap()];
            args.extend_from_slice(extra);
            reconstruct_ok(&data.0, &out, &args);
            report(&out)
        };
        let (plain, refined) = (run(&[]), run(&["--refine-leds"]));
        let nrmse = |r: &serde_json::Value| r["versus_truth"]["complex_nrmse"].as_f64().unwrap();
        let board = refined["refined_leds"]["board"].clone();
        eprintln!(
            "{name}: complex NRMSE {:.4} rigid, {:.4} refined; LEDs off the board model τ = {} mm; board h {} ± {} mm",
            nrmse(&plain),
            nrmse(&refined),
            refined["refined_leds"]["led_scatter_mm"],
            board["height_mm"],
            board["uncertainty"]["height_mm"]
        );
        let h = board["height_mm"].as_f64().unwrap();
        let sigma = board["uncertainty"]["height_mm"].as_f64().unwrap();
        assert!((h - 92.0).abs() <= 3.0 * sigma, "{name}: h {h} ± {sigma}");
        // Its positions are no calibration, and the run says so.
        assert!(
            says_dim_dark_field(&refined),
            "{name}: {}",
            refined["warnings"]
        );
        (nrmse(&plain), nrmse(&refined))
    };
    // Measured: 0.0884 → 0.0849 and 0.193 → 0.130.
    let (perfect, perfect_refined) = case("refine-dim-perfect", false);
    assert!(
        perfect_refined <= 1.02 * perfect,
        "a perfect board refined: {perfect_refined} vs {perfect}"
    );
    let (misbuilt, misbuilt_refined) = case("refine-dim-misbuilt", true);
    assert!(
        misbuilt_refined < 0.9 * misbuilt,
        "a misbuilt board refined: {misbuilt_refined} vs {misbuilt}"
    );
}

/// Whether a refined run's report warns that its dim dark field makes the refined
/// positions no calibration.
fn says_dim_dark_field(report: &serde_json::Value) -> bool {
    report["warnings"].as_array().is_some_and(|w| {
        w.iter().any(|w| {
            w["check"] == "refinement"
                && w["message"]
                    .as_str()
                    .is_some_and(|m| m.contains("dark-field frames are dim"))
        })
    })
}

/// A copy of the vendored USAF dataset in `dir`, to add files beside it.
fn usaf_copy(dir: &Path) -> PathBuf {
    let to = dir.join("usaf");
    fpm_tests::copy_dataset(&usaf(), &to);
    to
}

/// Frames stored for display (`--display-gamma 2.2`, as camera software exporting 8-bit
/// images for viewing does) reconstruct as well as the same camera's raw counts once the
/// dataset's `[camera] gamma` decodes them; read as linear counts they do not (against
/// the hidden truth). The sample here is weak (no opaque part), so the bright-field fit
/// cannot tell (its warning is tested on the USAF target above).
#[test]
fn display_encoded_frames_decoded_reconstruct_as_well_as_raw_counts() {
    let (raw, encoded, dir) = (
        TempDir::new("gamma-raw"),
        TempDir::new("gamma-encoded"),
        TempDir::new("gamma-as-linear"),
    );
    let mut args = DIM_EIGHT_BIT_128.to_vec();
    args.extend_from_slice(CENTRED);
    simulate_acquisition(&raw, &args);
    args.extend_from_slice(&["--display-gamma", "2.2"]);
    simulate_acquisition(&encoded, &args);
    let as_linear = dir.0.join("as-linear");
    fpm_tests::copy_dataset(&encoded.0, &as_linear);
    let toml = as_linear.join("dataset.toml");
    let stated = std::fs::read_to_string(&toml).unwrap();
    assert!(stated.contains("gamma = 2.2\n"), "{stated}");
    std::fs::write(&toml, stated.replace("gamma = 2.2\n", "")).unwrap();
    let run = |dataset: &Path, tag: &str, extra: &[&str]| {
        let out = dir.0.join(tag);
        let (dataset, out_arg) = (dataset.to_string_lossy(), out.to_string_lossy());
        let mut args = vec!["reconstruct", &dataset, "--out", &out_arg];
        args.extend_from_slice(extra);
        fpm_stdout(&args);
        report(&out)
    };
    let nrmse_of = |r: &serde_json::Value| r["versus_truth"]["complex_nrmse"].as_f64().unwrap();
    // Raw counts stating no gamma are scanned by default, and left linear.
    let r_raw_default = run(&raw.0, "raw", &[]);
    assert!(
        r_raw_default.get("camera_gamma").is_none(),
        "{}",
        r_raw_default["camera_gamma_scan"]
    );
    let (e_raw, e_decoded, e_linear) = (
        nrmse_of(&r_raw_default),
        nrmse_of(&run(&encoded.0, "decoded", &[])),
        nrmse_of(&run(&as_linear, "linear", &["--camera-gamma", "1"])),
    );
    eprintln!("complex NRMSE: raw counts {e_raw:.3}, decoded {e_decoded:.3}, read as linear {e_linear:.3}");
    // Measured: 0.145, 0.146, 0.203.
    assert!(e_decoded < 1.1 * e_raw, "{e_decoded} against {e_raw}");
    assert!(e_linear > 1.2 * e_decoded, "{e_linear} against {e_decoded}");
    // Nobody wrote the gamma down: it is read from the frames by default (8-bit frames),
    // where the bright-field fit cannot see it (a weak sample); raw counts asked for a
    // scan are found linear.
    let auto = ["--camera-gamma", "auto"];
    let (r_encoded, r_raw) = (
        run(&as_linear, "default-encoded", &[]),
        run(&raw.0, "auto-raw", &auto),
    );
    assert_eq!(r_encoded["camera_gamma_scan_reason"], "eight-bit-unstated");
    let scan = |r: &serde_json::Value| r["camera_gamma_scan"].clone();
    eprintln!(
        "read from the frames: stored with 2.2 {}, raw counts {}",
        scan(&r_encoded),
        scan(&r_raw)
    );
    let best = scan(&r_encoded)["best"].as_f64().unwrap();
    assert!((1.9..=2.5).contains(&best), "{}", scan(&r_encoded));
    assert!(
        nrmse_of(&r_encoded) < 1.1 * e_decoded,
        "{} against {e_decoded} with the gamma stated",
        nrmse_of(&r_encoded)
    );
    assert_eq!(scan(&r_raw)["linear"], true, "{}", scan(&r_raw));
    assert!(r_raw.get("camera_gamma").is_none());
    assert!(nrmse_of(&r_raw) < 1.1 * e_raw);
}

/// A dataset that states the wrong LED height (a height measured to the wrong plane of
/// the board): a simulated acquisition (full wave-optics model, the array at 92 mm) told
/// 101.2 mm. The frames' bright/dark-field edge disagrees; weighed on the central square,
/// the edge's height fits the frames clearly better, so the run with no flags takes it,
/// says so with the option that keeps the dataset's, and comes far closer to the hidden
/// truth than the dataset's height given explicitly (which is never overridden: the
/// warning then names `--led-height-mm` with the edge's height). (On a full real frame
/// of another lab, 1440 × 1080 behind an 8 × 8 array, the edge's height took the clear
/// glass's variation from 16 % to 3 %. The vendored USAF set's coarse 5 mm grid pins its
/// edge only to ±8 mm, too loosely for this test.)
#[test]
fn a_wrong_dataset_height_gives_way_to_the_edges_where_the_frames_fit_it_better() {
    let dir = TempDir::new("wrong-height");
    let simulated = TempDir::new("wrong-height-data");
    simulate_centred(&simulated, "128", "8");
    let data = simulated.0.clone();
    let manifest = std::fs::read_to_string(data.join("dataset.toml")).unwrap();
    assert!(manifest.contains("height_mm = 92.0"), "{manifest}");
    std::fs::write(
        data.join("dataset.toml"),
        manifest.replace("height_mm = 92.0", "height_mm = 101.2"),
    )
    .unwrap();
    let run = |out: &str, extra: &[&str]| -> (serde_json::Value, String) {
        let out = dir.0.join(out);
        let args = [&["--passes", "10"], extra].concat();
        let stderr = reconstruct_ok(&data, &out, &args);
        (report(&out), stderr)
    };
    let boundary = |r: &serde_json::Value, key: &str| {
        r["height_from_boundary"][key]
            .as_f64()
            .unwrap_or_else(|| panic!("height_from_boundary.{key} in {r}"))
    };
    let (stated, stderr) = run("stated", &["--led-height-mm", "101.2"]);
    let edge = boundary(&stated, "height_mm");
    assert!(boundary(&stated, "difference_sigma") < -3.0, "{stated}");
    assert!((edge - 92.0).abs() < 0.03 * 92.0, "the edge's {edge} mm");
    assert!(
        stated.get("height_choice").is_none(),
        "a height given is kept: {stated}"
    );
    assert!(
        stderr.contains(&format!("--led-height-mm {edge:.1}")),
        "the warning names the option and the edge's height: {stderr}"
    );
    let (default, stderr) = run("default", &[]);
    let choice = &default["height_choice"];
    let number = |key: &str| {
        choice[key]
            .as_f64()
            .unwrap_or_else(|| panic!("{key} in {choice}"))
    };
    eprintln!("weighed: {choice}");
    assert_eq!(choice["edge_taken"], true, "{choice}");
    assert_eq!(
        default["geometry"]["height_mm"].as_f64(),
        Some(number("edge_mm"))
    );
    assert_eq!(default["geometry"]["pitch_mm"], 2.5);
    assert!(
        default["geometry_source"]
            .as_str()
            .is_some_and(|s| s.contains("edge")),
        "{}",
        default["geometry_source"]
    );
    // Measured: 0.221 against 0.392.
    assert!(
        number("edge_error") < 0.9 * number("stated_error"),
        "{choice}"
    );
    assert!(
        boundary(&default, "difference_sigma").abs() < 1.0,
        "{default}"
    );
    assert!(
        stderr.contains("reconstructed at") && stderr.contains("--led-height-mm 101.2"),
        "the warning says what was done and how to keep the dataset's height: {stderr}"
    );
    let truth = |r: &serde_json::Value| r["versus_truth"]["complex_nrmse"].as_f64().unwrap();
    let (t_stated, t_default) = (truth(&stated), truth(&default));
    eprintln!(
        "complex NRMSE at the dataset's 101.2 mm {t_stated:.3}, with no flags (the edge's {:.2} mm) {t_default:.3}",
        number("edge_mm")
    );
    assert!(t_default < 0.5 * t_stated, "{t_default} against {t_stated}");

    // It replaces the dataset's height, not a calibration's, and must be a height.
    for bad in [
        vec!["--led-height-mm", "80", "--calibration", "x.json"],
        vec!["--led-height-mm", "0"],
    ] {
        let refused = Command::new(fpm_bin())
            .args(["reconstruct", &data.to_string_lossy(), "--out"])
            .arg(dir.0.join("refused"))
            .args(&bad)
            .output()
            .unwrap();
        assert!(!refused.status.success(), "{bad:?} accepted");
        let stderr = String::from_utf8_lossy(&refused.stderr);
        assert!(
            stderr.contains("--led-height-mm") || stderr.contains("positive size in mm"),
            "{bad:?}: {stderr}"
        );
    }
}

/// docs/dataset.md §2: an objective that is not telecentric (its entrance pupil 20 mm
/// above the sample) sees every LED at an angle to its chief ray that changes across the
/// field. Simulated by Fresnel propagation to the pupil (not by the reconstruction's
/// chief-ray rule), tiled so that tiles sit off the axis: reconstructed as telecentric,
/// the field comes back with a bowl and ripples; told the pupil, close to a telecentric
/// acquisition's quality.
#[test]
fn an_entrance_pupil_off_at_a_finite_distance_is_reconstructed_when_stated() {
    let dir = TempDir::new("pupil-distance");
    let data = TempDir::new("pupil-distance-data");
    simulate_acquisition(
        &data,
        &[
            "--size",
            "384",
            "--seed",
            "5",
            "--dx-mm",
            "0",
            "--dy-mm",
            "0",
            "--theta-deg",
            "0",
            "--entrance-pupil-mm",
            "20",
        ],
    );
    let truth = truth_json(&data.0);
    assert_eq!(
        truth["entrance_pupil_mm"], 20.0,
        "truth.json states the pupil"
    );
    let run = |out: &str, extra: &[&str]| -> serde_json::Value {
        let out = dir.0.join(out);
        let done = Command::new(fpm_bin())
            .args(["reconstruct", &data.0.to_string_lossy(), "--tile", "192"])
            .arg("--out")
            .arg(&out)
            .args(extra)
            .output()
            .unwrap();
        assert!(
            done.status.success(),
            "{}",
            String::from_utf8_lossy(&done.stderr)
        );
        report(&out)
    };
    let score = |r: &serde_json::Value, key: &str| {
        r["versus_truth"][key]
            .as_f64()
            .unwrap_or_else(|| panic!("versus_truth.{key} in {r}"))
    };
    let telecentric = run("telecentric", &[]);
    let stated = run("stated", &["--entrance-pupil-mm", "20"]);
    assert!(telecentric["tiles"].as_array().map_or(0, Vec::len) >= 4);
    assert_eq!(stated["system"]["entrance_pupil_mm"], 20.0);
    assert!(telecentric["system"].get("entrance_pupil_mm").is_none());
    let (c_tele, c_stated) = (
        score(&telecentric, "complex_nrmse"),
        score(&stated, "complex_nrmse"),
    );
    let (a_tele, a_stated) = (
        score(&telecentric, "amplitude_nrmse"),
        score(&stated, "amplitude_nrmse"),
    );
    eprintln!(
        "complex NRMSE {c_tele:.3} as telecentric, {c_stated:.3} with the pupil stated; \
         amplitude {a_tele:.4}, {a_stated:.4}"
    );
    assert!(c_stated < 0.7 * c_tele, "{c_stated} against {c_tele}");
    assert!(a_stated < 0.8 * a_tele, "{a_stated} against {a_tele}");
    assert!(c_stated < 0.15, "{c_stated}");
    // The edge check takes the pupil into account: the true 92 mm within its 2σ.
    let edge = &stated["height_from_boundary"];
    let (h, sigma) = (
        edge["height_mm"]
            .as_f64()
            .unwrap_or_else(|| panic!("{edge}")),
        edge["sigma_with_na_mm"]
            .as_f64()
            .unwrap_or_else(|| panic!("{edge}")),
    );
    assert!((h - 92.0).abs() < 2.0 * sigma, "edge {h} ± {sigma} mm");
}

/// docs/dataset.md §5.7: an array measured by other means is given to `fpm reconstruct`
/// as the four numbers alone (the grid comes from the dataset); a file without them
/// names each missing key; and a `truth.json` written by another simulator, which fpm
/// cannot use, costs a warning, never the reconstruction.
#[test]
fn a_hand_written_geometry_places_the_array_and_a_foreign_truth_only_warns() {
    let dir = TempDir::new("geometry-json");
    let data = usaf_copy(&dir.0);
    let geometry = dir.0.join("geometry.json");
    std::fs::write(
        &geometry,
        r#"{ "dx_mm": 0.4, "dy_mm": -0.3, "theta_deg": 1.5, "height_mm": 88.0 }"#,
    )
    .unwrap();
    // Another tool's truth: different keys, no seed, no object images.
    std::fs::write(
        data.join("truth.json"),
        r#"{ "generator": "other-simulator", "led_offset": [0.1, 0.2] }"#,
    )
    .unwrap();
    let out = dir.0.join("out");
    let run = Command::new(fpm_bin())
        .args([
            "reconstruct",
            &data.to_string_lossy(),
            "--passes",
            "2",
            "--out",
        ])
        .arg(&out)
        .arg("--calibration")
        .arg(&geometry)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{stderr}");
    assert!(
        stderr.contains("truth.json") && stderr.contains("not scored"),
        "the unusable truth is named in a warning: {stderr}"
    );
    let r = report(&out);
    let g = &r["geometry"];
    assert_eq!(g["dx_mm"], 0.4);
    assert_eq!(g["dy_mm"], -0.3);
    assert_eq!(g["theta_deg"], 1.5);
    assert_eq!(g["height_mm"], 88.0);
    // The grid is the dataset's (11×11 at 5 mm, centre (5, 5)).
    assert_eq!(g["rows"], 11);
    assert_eq!(g["pitch_mm"], 5.0);
    assert_eq!(g["center"], serde_json::json!([5, 5]));
    assert!(r["versus_truth"].is_null());
    assert!(out.join("amplitude.tif").is_file());

    std::fs::write(&geometry, r#"{ "dx_mm": 0.4, "theta_deg": 1.5 }"#).unwrap();
    let run = Command::new(fpm_bin())
        .args([
            "reconstruct",
            &data.to_string_lossy(),
            "--passes",
            "1",
            "--out",
        ])
        .arg(dir.0.join("out2"))
        .arg("--calibration")
        .arg(&geometry)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success());
    assert!(
        stderr.contains("geometry.json") && stderr.contains("missing key(s) dy_mm, height_mm"),
        "{stderr}"
    );
}

/// A colour sensor: a simulated acquisition (full wave-optics model) recorded through
/// an RGGB mosaic, the green LED's light mostly in the green pixels (red and blue
/// pixels see a little of it, as real filters do). Taken by the green pixels alone
/// (`channel = "G"`: half the size, twice the pitch, reconstructed at twice the
/// upsampling to the same grid) and demosaiced (full size), both reconstruct, close to
/// what a mono sensor of the same pitch gives.
#[test]
fn a_colour_sensor_reconstructs_from_its_green_pixels_both_ways() {
    use fpm_host::dataset::Dataset;
    use fpm_physics::bayer::{BayerChannel, BayerPattern};

    let mono = TempDir::new("bayer-mono");
    simulate_centred(&mono, "128", "6");
    let ds = Dataset::load(&mono.0).unwrap();
    let mosaics: Vec<Array2<u16>> = ds
        .frames
        .iter()
        .map(|f| match &f.raw {
            image_io::Pixels::U16(a) => Array2::from_shape_fn(a.dim(), |(r, c)| {
                let v = a[[r, c]] as f32;
                match BayerPattern::Rggb.filter(r, c) {
                    BayerChannel::G => v,
                    BayerChannel::R => 0.25 * v,
                    BayerChannel::B => 0.15 * v,
                }
                .round() as u16
            }),
            _ => panic!("simulated frames are 16-bit"),
        })
        .collect();
    let score = |dir: &Path, upsample: &str| -> f64 {
        let out = TempDir::new("bayer-out");
        let o = out.0.to_string_lossy().into_owned();
        fpm_stdout(&[
            "reconstruct",
            &dir.to_string_lossy(),
            "--out",
            &o,
            "--upsample",
            upsample,
        ]);
        let r = report(&out.0);
        r["versus_truth"]["complex_nrmse"]
            .as_f64()
            .unwrap_or_else(|| panic!("not scored: {r}"))
    };
    let e_mono = score(&mono.0, "4");
    let mut errors = vec![];
    for demosaic in [false, true] {
        let colour = TempDir::new("bayer-colour");
        let mut manifest = ds.manifest.clone();
        manifest.camera.bayer = Some(BayerPattern::Rggb);
        manifest.camera.channel = Some(BayerChannel::G);
        manifest.camera.demosaic = demosaic;
        Dataset::write(&colour.0, &manifest, &mosaics).unwrap();
        for truth in ["truth.json", "truth_amplitude.tif", "truth_phase.tif"] {
            std::fs::copy(mono.0.join(truth), colour.0.join(truth)).unwrap();
        }
        let loaded = Dataset::load(&colour.0).unwrap();
        let (h, w) = loaded.frames[0].raw.dim();
        let pitch = loaded.manifest.system.pixel_size_um;
        if demosaic {
            assert_eq!((h, w), (128, 128));
            assert_eq!(pitch, ds.manifest.system.pixel_size_um);
        } else {
            assert_eq!((h, w), (64, 64));
            assert_eq!(pitch, 2.0 * ds.manifest.system.pixel_size_um);
        }
        errors.push(score(&colour.0, if demosaic { "4" } else { "8" }));
    }
    let (e_sub, e_dem) = (errors[0], errors[1]);
    eprintln!(
        "complex NRMSE: mono {e_mono:.3}, green pixels (subsampled) {e_sub:.3}, demosaiced {e_dem:.3}"
    );
    assert!(e_mono < 0.3, "mono {e_mono}");
    for (name, e) in [("subsampled", e_sub), ("demosaiced", e_dem)] {
        assert!(e < 1.5 * e_mono + 0.05, "{name}: {e} against mono {e_mono}");
    }
}

/// The vendored full real frame: 1024 × 1024 behind a ring array of 93 LEDs
/// (`data/thuhololab-ring93`), a phase resolution target left about 140 µm out of focus.
fn ring93() -> PathBuf {
    fpm_tests::data_dir().join("thuhololab-ring93")
}

/// How strongly the horizontal bars of group 8, element 2 of the ring-array set's
/// target stand out in `phase` (its 4× grid): the rows' profile, averaged along the
/// bars, at its strongest spatial frequency (Hann-windowed DFT magnitude).
fn group_8_bars(phase: &Array2<f32>) -> f64 {
    let rows = phase.slice(s![1860..1960, 1995..2045]);
    let profile: Vec<f64> = rows
        .rows()
        .into_iter()
        .map(|r| r.iter().map(|&v| v as f64).sum::<f64>() / r.len() as f64)
        .collect();
    let n = profile.len();
    let mean = profile.iter().sum::<f64>() / n as f64;
    (2..20)
        .map(|k| {
            let (mut re, mut im) = (0.0, 0.0);
            for (i, v) in profile.iter().enumerate() {
                let w = 0.5 - 0.5 * (std::f64::consts::TAU * i as f64 / (n - 1) as f64).cos();
                let a = std::f64::consts::TAU * (k * i) as f64 / n as f64;
                re += (v - mean) * w * a.cos();
                im -= (v - mean) * w * a.sin();
            }
            re.hypot(im)
        })
        .fold(0.0, f64::max)
}

/// The default noise band (7.5σ) on the dim dark field of an 8-bit camera (peaks of ~25
/// counts over 2–3 counts of noise), the array where the dataset says: leaving each
/// pixel's model light alone within the band, instead of imposing the noisy, floored
/// measurement (`--noise-band-sigma 0`), recovers more of the detail (complex NRMSE with
/// the slow phase fitted out, against the hidden truth).
#[test]
fn a_noise_band_recovers_detail_from_dim_eight_bit_dark_field() {
    let data = TempDir::new("band-8bit");
    let mut args = vec![
        "--size",
        "128",
        "--seed",
        "1",
        "--noise",
        "eight-bit",
        "--dark-field-peak-dn",
        "25",
    ];
    args.extend_from_slice(CENTRED);
    simulate_acquisition(&data, &args);
    let run = |tag: &str, extra: &[&str]| {
        let out = data.0.join(tag);
        reconstruct_ok(&data.0, &out, extra);
        report(&out)
    };
    let (exact, banded) = (
        run("exact", &["--noise-band-sigma", "0"]),
        run("default", &[]),
    );
    assert_eq!(exact["background"]["noise_band_sigma"], 0.0);
    assert_eq!(
        banded["background"]["noise_band_sigma"],
        f64::from(fpm_physics::reconstruct::NOISE_BAND_SIGMA)
    );
    let detail = |r: &serde_json::Value| r["versus_truth"]["detail_nrmse"].as_f64().unwrap();
    eprintln!(
        "detail NRMSE: imposed exactly {:.4}, noise band (default) {:.4}",
        detail(&exact),
        detail(&banded)
    );
    // Measured: 0.1075 → 0.0585.
    assert!(
        detail(&banded) < 0.75 * detail(&exact),
        "{} against {}",
        detail(&banded),
        detail(&exact)
    );
}

/// A full real frame from another lab, reconstructed whole (25 tiles): the ring array's
/// geometry as its authors state it. With no flags, the bright-field frames' shifts
/// show the sample far out of focus and the run refocuses by itself: the bars of group
/// 8 stand out well over twice as strongly as when the frames are taken as in focus
/// (the result then smears the fine groups into a texture and draws spokes round every
/// particle). The default noise band on the dark-field frames that are mostly noise
/// (most of this set's: they sit at 2–3 counts, their signal a few counts more) brings
/// the clear glass within 3× the centre frame's light, keeping the bars. (Three runs of
/// 4096² in CI's 30 minutes: the hand-refocused run with the hard floor, which showed
/// the soft floor's gain, measured 0.089 against the soft floor's 0.064, went.)
#[test]
fn a_full_real_frame_from_a_ring_array_refocuses_itself_and_its_glass_is_clean() {
    let dir = TempDir::new("ring93");
    let run = |tag: &str, extra: &[&str]| {
        let out = dir.0.join(tag);
        reconstruct_ok(&ring93(), &out, extra);
        let r = report(&out);
        assert_eq!(
            (r["frames"].as_u64(), r["tiles"].as_array().map(Vec::len)),
            (Some(93), Some(25))
        );
        out
    };
    let no_flags = run("no-flags", &[]);
    // The runs it is compared with state the height and gamma it chose (asserted
    // below): each then changes one thing against it, and is one reconstruction
    // instead of a gamma scan and two reconstructions weighing the height (a third
    // of this test's time).
    let as_chosen = ["--led-height-mm", "110", "--camera-gamma", "1"];
    let as_in_focus = run(
        "as-in-focus",
        &[&as_chosen[..], &["--refocus-um", "0"]].concat(),
    );
    let no_band = run(
        "no-band",
        &[&as_chosen[..], &["--noise-band-sigma", "0"]].concat(),
    );
    // The edge reads 91 mm for the stated 110 (the first ring's soft vignetting moves
    // it), but the frames fit 110 better: kept, and no warning.
    let quiet = report(&no_flags);
    // Run with no flags, the job times each step, the checks it made by itself among
    // them (issue 63: what judgement costs, in report.json).
    let steps: Vec<&str> = quiet["steps_ms"]
        .as_array()
        .map(|s| s.iter().filter_map(|s| s["step"].as_str()).collect())
        .unwrap_or_default();
    for step in [
        "gamma scan",
        "refocus estimate and edge checks",
        "EPRY",
        "edge height weighed",
    ] {
        assert!(steps.contains(&step), "no step {step:?} in {steps:?}");
    }
    let choice = &quiet["height_choice"];
    eprintln!("LED height weighed: {choice}");
    assert_eq!(choice["edge_taken"], false, "{choice}");
    assert!(
        choice["stated_error"].as_f64() <= choice["edge_error"].as_f64(),
        "{choice}"
    );
    assert_eq!(quiet["geometry"]["height_mm"], 110.0);
    let gamma = &quiet["camera_gamma_scan"];
    assert!(gamma["linear"] == true && gamma["best"] == 1.0, "{gamma}");
    assert!(
        quiet["warnings"]
            .as_array()
            .is_some_and(|w| w.iter().all(|w| w["check"] != "height-from-edge")),
        "{}",
        quiet["warnings"]
    );
    let found = &report(&no_flags)["refocus"];
    eprintln!("refocus found: {found}");
    assert_eq!(found["choice"], "where-clear");
    // The run says it refocused, and how to reconstruct as in focus instead.
    assert!(
        quiet["warnings"]
            .as_array()
            .is_some_and(|w| w.iter().any(|w| w["check"] == "refocus"
                && w["message"]
                    .as_str()
                    .is_some_and(|m| m.contains("--refocus-um 0")))),
        "{}",
        quiet["warnings"]
    );
    let z = found["refocus_um"].as_f64().unwrap();
    let sigma = found["estimate"]["sigma_um"].as_f64().unwrap();
    // Measured: 164.5 ± 13.4 µm (the shifts give z/h: the dataset's h of 110 mm may be
    // off, as its bright/dark-field edge says).
    assert!(
        (120.0..200.0).contains(&z) && z > 3.0 * sigma,
        "{z} ± {sigma}"
    );
    let bars = |out: &Path| group_8_bars(&read_f32(&out.join("phase.tif")));
    let (by_itself, smeared) = (bars(&no_flags), bars(&as_in_focus));
    eprintln!("group 8 bars: refocused by itself {by_itself:.2}, as in focus {smeared:.2}");
    // Measured: 11.3 against 5.0 (13.2 refocused by hand at 140 µm).
    assert!(by_itself > 2.0 * smeared, "{by_itself} against {smeared}");
    let ds = fpm_host::dataset::Dataset::load(&ring93()).unwrap();
    let m = ds.measured(0);
    assert_eq!(ds.frames[0].entry.led, fpm_physics::LedIndex::new(0, 0));
    let light = m.intensity(fpm_physics::frame::Region::whole(m.dim()));
    let frame = clear_glass_variation(&light, &light.mapv(f32::sqrt), 1.0);
    let glass =
        |out: &Path| clear_glass_variation(&light, &read_f32(&out.join("amplitude.tif")), 1.0);
    let (banded, soft_3) = (glass(&no_flags), glass(&no_band));
    eprintln!(
        "clear-glass variation: no flags (soft 3σ floor, noise band) {banded:.4}, soft 3σ floor without the band {soft_3:.4}, the centre frame's light {frame:.4}"
    );
    // Measured: 0.033 and 0.064 against 0.012.
    assert!(banded < 3.0 * frame, "{banded} against the frame's {frame}");
    assert!(
        banded < 0.7 * soft_3,
        "{banded} with the band against {soft_3} without"
    );
    let unbanded = bars(&no_band);
    eprintln!("group 8 bars without the noise band: {unbanded:.2}");
    // Measured: 11.26 with the band against 11.6 without it.
    assert!(
        by_itself > 0.9 * unbanded,
        "the band keeps the bars: {by_itself} against {unbanded}"
    );
}

/// The dataset in `from` copied to `to` with its `[led]` section rewritten by `led`
/// (given the nominal geometry).
fn with_led_section(
    from: &Path,
    to: &Path,
    led: impl FnOnce(&fpm_physics::LedGeometry) -> fpm_host::dataset::LedSection,
) {
    fpm_tests::copy_dataset(from, to);
    let mut m = fpm_host::dataset::DatasetOnDisk::open(to).unwrap().manifest;
    m.led = led(&m.geometry());
    m.write(to).unwrap();
}

/// Every LED of `g` as `[[led.position]]`, each place passed through `place`.
fn as_positions(
    g: &fpm_physics::LedGeometry,
    place: impl Fn(f64, f64) -> (f64, f64),
) -> fpm_host::dataset::LedSection {
    let leds = g
        .leds()
        .into_iter()
        .map(|led| {
            let (x, y) = g.led_position_mm(led);
            let (x_mm, y_mm) = place(x, y);
            fpm_physics::ListedLed {
                led,
                x_mm,
                y_mm,
                z_mm: 0.0,
            }
        })
        .collect();
    let list = fpm_physics::LedList::new(leds).unwrap();
    fpm_host::dataset::LedSection::of(&fpm_physics::LedGeometry::listed(list, g.height_mm, None))
}

/// Every LED of `g` as `[[led.na]]` (its sines seen from the field's centre), each
/// passed through `turn`.
fn as_nas(
    g: &fpm_physics::LedGeometry,
    turn: impl Fn([f64; 2]) -> [f64; 2],
) -> fpm_host::dataset::LedSection {
    use fpm_host::dataset::{LedNa, LedNas, LedSection};
    let nas = g
        .leds()
        .into_iter()
        .map(|led| {
            let (x, y, h) = g.led_position_3d_mm(led);
            let r = (x * x + y * y + h * h).sqrt();
            LedNa {
                led,
                na: turn([x / r, y / r]),
            }
        })
        .collect();
    LedSection {
        na: Some(LedNas::new(nas).unwrap()),
        ..LedSection::of(g)
    }
    .without_grid()
}

/// An acquisition (full wave-optics model, its array where the dataset says) restated
/// as a list of its LEDs' places, or of their NAs, reconstructs exactly as the grid
/// does; the same list with a sign, the axes or the units wrong is caught by the
/// hidden truth.
#[test]
fn a_listed_layout_reconstructs_as_its_grid_and_a_wrong_sign_axis_or_unit_is_caught() {
    let (sim, dir) = (TempDir::new("layout-sim"), TempDir::new("layout"));
    simulate_centred(&sim, "128", "4");
    let nrmse = |dataset: &Path, tag: &str| {
        let out = dir.0.join(format!("{tag}-out"));
        reconstruct_ok(dataset, &out, &["--passes", "8"]);
        report(&out)["versus_truth"]["complex_nrmse"]
            .as_f64()
            .unwrap()
    };
    let restated =
        |tag: &str, led: &dyn Fn(&fpm_physics::LedGeometry) -> fpm_host::dataset::LedSection| {
            let to = dir.0.join(tag);
            with_led_section(&sim.0, &to, led);
            nrmse(&to, tag)
        };
    let grid = nrmse(&sim.0, "grid");
    let nas = restated("nas", &|g| as_nas(g, |na| na));
    let positions = restated("positions", &|g| as_positions(g, |x, y| (x, y)));
    let sign = restated("sign", &|g| as_nas(g, |na| [-na[0], na[1]]));
    let axes = restated("axes", &|g| as_positions(g, |x, y| (y, x)));
    let units = restated("units", &|g| as_positions(g, |x, y| (x / 10.0, y / 10.0)));
    eprintln!(
        "complex NRMSE: grid {grid:.4}, NA list {nas:.4}, positions {positions:.4}; \
         NAx sign flipped {sign:.4}, x and y swapped {axes:.4}, cm read as mm {units:.4}"
    );
    for (what, e) in [("the NA list", nas), ("the positions", positions)] {
        assert!(
            (e - grid).abs() < 0.02 * grid,
            "{what}: {e} against the grid's {grid}"
        );
    }
    for (what, e) in [
        ("a flipped sign", sign),
        ("swapped axes", axes),
        ("cm as mm", units),
    ] {
        assert!(e > 1.5 * grid, "{what}: {e} against the grid's {grid}");
    }
}
