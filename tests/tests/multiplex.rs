//! Multiplexed illumination (issue 39 §2): frames lit by several LEDs at once, from the
//! full wave-optics simulator (each LED rendered alone, the intensities summed, the sum
//! recorded with the camera's noise), reconstructed against the hidden truth.

use std::path::Path;
use std::process::Command;

use fpm_host::dataset::{Dataset, Manifest};
use fpm_tests::{fpm_bin, simulate_centred, TempDir};

fn reconstruct(dataset: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    Command::new(fpm_bin())
        .args(["reconstruct", &dataset.to_string_lossy(), "--out"])
        .arg(out)
        .args(extra)
        .output()
        .unwrap()
}

/// The reconstruction's complex NRMSE against the truth.
fn nrmse(dataset: &Path, out: &Path) -> f64 {
    let done = reconstruct(dataset, out, &[]);
    assert!(
        done.status.success(),
        "{}",
        String::from_utf8_lossy(&done.stderr)
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    report["versus_truth"]["complex_nrmse"].as_f64().unwrap()
}

fn total_exposure_ms(dataset: &Path) -> f64 {
    let ds = Dataset::load(dataset).unwrap();
    ds.manifest.frames.iter().map(|f| f.exposure_ms).sum()
}

#[test]
fn multiplexed_frames_reconstruct_near_the_single_led_scan_and_ignoring_their_other_leds_is_caught()
{
    let tmp = TempDir::new("multiplex");
    let mut scores = vec![];
    for k in ["1", "4", "8"] {
        let data = tmp.0.join(format!("k{k}"));
        simulate_centred(&data, "128", "1", &["--multiplex", k]);
        let ds = Dataset::load(&data).unwrap();
        let frames = ds.frames.len();
        let lit: usize = ds.frames.iter().map(|f| f.entry.leds().count()).sum();
        assert_eq!(lit, 441, "every LED once");
        let widest = ds.frames.iter().map(|f| f.entry.leds().count()).max();
        assert_eq!(widest, Some(k.parse().unwrap()));
        let score = nrmse(&data, &tmp.0.join(format!("r{k}")));
        eprintln!(
            "k = {k}: {frames} frames, {:.0} ms exposure in all, complex NRMSE {score:.4}",
            total_exposure_ms(&data)
        );
        scores.push(score);
    }
    let single = scores[0];
    assert!(
        total_exposure_ms(&tmp.0.join("k4")) <= total_exposure_ms(&tmp.0.join("k1")),
        "the multiplexed scan may not take more exposure than the single-LED one"
    );
    // Measured 0.085 (one LED, 441 frames), 0.076 (K = 4, 144 frames), 0.083 (K = 8,
    // 95 frames): docs/results.md. The goal: within 1.3x.
    assert!(scores[1] <= 1.3 * single, "K = 4: {scores:?}");
    assert!(scores[2] <= 1.3 * single, "K = 8: {scores:?}");

    // The same frames read as if only their first LED had lit them.
    let data = tmp.0.join("k4");
    let first_only = tmp.0.join("k4-first-only");
    std::fs::create_dir_all(&first_only).unwrap();
    let mut manifest: Manifest = Dataset::load(&data).unwrap().manifest;
    for f in &mut manifest.frames {
        f.also.clear();
        f.file = data.join(&f.file).to_string_lossy().into_owned();
    }
    manifest.write(&first_only).unwrap();
    for truth in ["truth.json", "truth_amplitude.tif", "truth_phase.tif"] {
        std::fs::copy(data.join(truth), first_only.join(truth)).unwrap();
    }
    let wrong = nrmse(&first_only, &tmp.0.join("r-first-only"));
    eprintln!("k = 4 read as one LED per frame: complex NRMSE {wrong:.4}");
    // Measured 0.115, 1.51x.
    assert!(wrong > 1.3 * scores[1], "{wrong} vs {}", scores[1]);
}

#[test]
fn a_frame_lit_by_several_leds_is_read_back_and_refused_where_one_led_is_needed() {
    let tmp = TempDir::new("multiplex-format");
    let data = tmp.0.join("k4");
    simulate_centred(&data, "64", "2", &["--multiplex", "4"]);
    let ds = Dataset::load(&data).unwrap();
    assert!(ds.manifest.frames.iter().all(|f| f.leds().count() <= 4));
    assert!(ds.manifest.frames.iter().any(|f| f.also.len() == 3));
    let lit: usize = ds.manifest.frames.iter().map(|f| f.leds().count()).sum();
    assert_eq!(lit, 441, "every LED once");

    // LED refinement moves one LED per frame: refused, naming what to do instead.
    let done = reconstruct(&data, &tmp.0.join("refined"), &["--refine-leds"]);
    let stderr = String::from_utf8_lossy(&done.stderr);
    assert!(!done.status.success());
    assert!(
        stderr.contains("--refine-leds needs frames lit by one LED"),
        "{stderr}"
    );
    // So a run that does not converge (here: the dataset states NA 0.13 for 0.1) is not
    // told to try it: the advice applies to the frames at hand.
    let wrong_na = tmp.0.join("wrong-na");
    fpm_tests::copy_dataset(&data, &wrong_na);
    let manifest = wrong_na.join("dataset.toml");
    let stated = std::fs::read_to_string(&manifest).unwrap();
    assert!(stated.contains("\nna = 0.1\n"), "{stated}");
    std::fs::write(&manifest, stated.replace("\nna = 0.1\n", "\nna = 0.13\n")).unwrap();
    let done = reconstruct(&wrong_na, &tmp.0.join("wrong-na-out"), &[]);
    assert!(done.status.success());
    let report: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(tmp.0.join("wrong-na-out/report.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(
        report["multiplexed_frames"], 99,
        "{}",
        report["multiplexed_frames"]
    );
    let rose = report["warnings"]
        .as_array()
        .unwrap()
        .iter()
        .find(|w| w["check"] == "error-rose")
        .unwrap_or_else(|| panic!("no error-rose warning: {}", report["warnings"]));
    let message = rose["message"].as_str().unwrap();
    assert!(
        message.contains("fpm calibrate, then --calibration") && !message.contains("--refine-leds"),
        "{message}"
    );

    let text = std::fs::read_to_string(data.join("dataset.toml")).unwrap();
    let first = text.find("leds = [[").unwrap();
    let line_end = first + text[first..].find('\n').unwrap();
    let leds_line = &text[first..line_end];
    for (broken, expect) in [
        (format!("led = [0, 0]\n{leds_line}"), "not both"),
        ("leds = []".to_string(), "lights nothing"),
        ("leds = [[3, 4], [3, 4]]".to_string(), "listed twice"),
        (
            "leds = [[3, 4], [30, 4]]".to_string(),
            "outside the 21x21 array",
        ),
        (
            format!("{leds_line}\ndefocus_um = 50.0"),
            "calibration frames are lit by one LED",
        ),
    ] {
        let mut t = format!("{}{}{}", &text[..first], broken, &text[line_end..]);
        if broken.contains("defocus_um = 50.0") {
            // That frame's own in-focus line goes.
            t = t.replacen(
                "defocus_um = 50.0\ndefocus_um = 0.0\n",
                "defocus_um = 50.0\n",
                1,
            );
        }
        std::fs::write(data.join("dataset.toml"), &t).unwrap();
        let err = Dataset::load(&data).unwrap_err().to_string();
        assert!(err.contains(expect), "{broken}: {err}");
        assert!(err.contains("dataset.toml"), "{err}");
    }
}
