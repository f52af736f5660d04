//! A calibration that cannot reach the accuracy a user needs says so: a small feature
//! off the axis at a small defocus (full wave-optics simulator) gets warnings that name
//! each parameter it cannot pin down, and the paper's standard case gets none of them.

use std::process::Command;

use fpm_tests::{fpm_bin, fpm_stdout, TempDir};

/// `fpm calibrate DIR`: (stderr, calibration.json).
fn calibrate(dir: &TempDir) -> (String, serde_json::Value) {
    let run = Command::new(fpm_bin())
        .arg("calibrate")
        .arg(&dir.0)
        .output()
        .expect("runs fpm");
    let stderr = String::from_utf8_lossy(&run.stderr).into_owned();
    assert!(run.status.success(), "{stderr}");
    let text = std::fs::read_to_string(dir.0.join("calibration.json")).expect("calibration.json");
    (stderr, serde_json::from_str(&text).expect("JSON"))
}

fn simulate(dir: &TempDir, extra: &[&str]) {
    let d = dir.0.to_string_lossy().into_owned();
    let mut args = vec!["simulate", "calibration", "--out", &d];
    args.extend_from_slice(extra);
    fpm_stdout(&args);
}

#[test]
fn an_uncertain_calibration_warns_and_a_sure_one_does_not() {
    let hard = TempDir::new("cal-warn-hard");
    simulate(
        &hard,
        &[
            "--feature-um",
            "18",
            "--feature-x-um",
            "30",
            "--feature-y-um",
            "-25",
            "--defocus-um",
            "100",
        ],
    );
    let (stderr, json) = calibrate(&hard);
    let sigma_um = json["uncertainty"]["dx_mm"].as_f64().unwrap() * 1e3;
    assert!(sigma_um > 2.0, "this case is uncertain: {sigma_um} µm");
    assert!(
        stderr.contains("Δx, Δy are uncertain by") && stderr.contains("more than the 2 µm"),
        "{stderr}"
    );
    assert!(stderr.contains("θ is uncertain by"), "{stderr}");

    let easy = TempDir::new("cal-warn-easy");
    simulate(&easy, &[]);
    let (stderr, json) = calibrate(&easy);
    assert!(json["uncertainty"]["dx_mm"].as_f64().unwrap() * 1e3 < 2.0);
    assert!(!stderr.contains("uncertain by"), "{stderr}");
}
