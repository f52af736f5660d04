//! `fpm dpc` on a simulated weak phase object (full wave-optics model: every LED's
//! frame imaged on its own, with noise; a half-circle pattern's frame is their sum, as
//! the LEDs' light adds incoherently), against the hidden truth and against the FPM
//! reconstruction of the same frames, both low-passed to 2·NA/λ.

use std::path::Path;

use fpm_host::dataset::image_io;
use fpm_host::dpc::{low_passed_phase, phase_difference};
use fpm_tests::{fpm_stdout, read_f32, simulate_centred, TempDir};

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

#[test]
fn dpc_recovers_a_weak_phase_object_and_agrees_with_fpm_at_its_resolution() {
    let dir = TempDir::new("dpc");
    let sim = dir.0.join("sim");
    simulate_centred(&sim, "128", "6", &["--sample", "weak-phase"]);
    let out = dir.0.join("dpc");
    let report: serde_json::Value = serde_json::from_str(&fpm_stdout(&[
        "dpc",
        &sim.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--json",
    ]))
    .unwrap();
    for half in report["halves"].as_array().unwrap() {
        assert!(!half["leds"].as_array().unwrap().is_empty(), "{half}");
    }
    let nrmse = report["versus_truth"]["detail_nrmse"].as_f64().unwrap();
    let dpc_phase = read_f32(&out.join("phase.tif"));
    assert!(out.join("phase.png").is_file() && out.join("dpc.json").is_file());

    // The same frames with the halves' roles swapped (left as right, top as bottom):
    // the phase comes out negated, so the test sees a sign error.
    let negated = phase_difference(&dpc_phase.mapv(|v| -v), &{
        let truth = image_io::read_complex(
            &sim.join("truth_amplitude.tif"),
            &sim.join("truth_phase.tif"),
        )
        .unwrap();
        let pitch = json(&sim.join("truth.json"))["object_pixel_um"]
            .as_f64()
            .unwrap();
        low_passed_phase(
            &truth,
            pitch,
            dpc_phase.dim(),
            report["max_frequency"].as_f64().unwrap(),
        )
    });

    // FPM's phase of the same frames, low-passed to what DPC sees.
    let fpm_out = dir.0.join("fpm");
    fpm_stdout(&[
        "reconstruct",
        &sim.to_string_lossy(),
        "--out",
        &fpm_out.to_string_lossy(),
    ]);
    let fpm_report = json(&fpm_out.join("report.json"));
    let hr =
        image_io::read_complex(&fpm_out.join("amplitude.tif"), &fpm_out.join("phase.tif")).unwrap();
    let hr_pixel = fpm_report["pixel_um"].as_f64().unwrap();
    let fpm_low = low_passed_phase(
        &hr,
        hr_pixel,
        dpc_phase.dim(),
        report["max_frequency"].as_f64().unwrap(),
    );
    let agreement = phase_difference(&dpc_phase, &fpm_low);
    eprintln!(
        "DPC phase against the truth (2·NA/λ, slow phase fitted out): NRMSE {nrmse:.3} \
         (without the fit {:.3}, {:.4} rad); negated {:.3}; against FPM's phase low-passed \
         alike: {:.3} ({:.3} without the fit)",
        report["versus_truth"]["phase_nrmse"],
        report["versus_truth"]["phase_rmse_rad"],
        negated.detail_nrmse,
        agreement.detail_nrmse,
        agreement.phase_nrmse
    );
    assert!(nrmse < 0.4, "DPC phase NRMSE {nrmse}");
    assert!(negated.detail_nrmse > 1.5, "{negated:?}");
    assert!(agreement.detail_nrmse < 0.6, "{agreement:?}");
}
