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

/// Well-built boards, in the paper's geometry and in random ones, calibrate without a
/// single warning. The corner LEDs of the calibration grid sit near the pupil's edge,
/// where the edge cuts the feature's spectrum and bends their shifts: the robust fit
/// used to reject one first, and it was then reported as an LED "off the fitted board
/// by more than 5σ" (0.06 mm at 8σ) on 35 of 48 simulated perfect boards.
#[test]
fn well_built_boards_calibrate_without_a_warning() {
    for (tag, args) in [
        (
            "paper-1",
            &[
                "--dx-mm",
                "1.3",
                "--dy-mm",
                "-0.7",
                "--theta-deg",
                "3",
                "--height-mm",
                "90",
                "--seed",
                "1",
            ][..],
        ),
        ("random-101", &["--random-geometry", "--seed", "101"][..]),
        ("random-104", &["--random-geometry", "--seed", "104"][..]),
    ] {
        let dir = TempDir::new(&format!("cal-good-{tag}"));
        simulate(&dir, args);
        let (stderr, json) = calibrate(&dir);
        assert!(!stderr.contains("warning"), "{tag}: {stderr}");
        let statuses: Vec<&str> = json["leds"]
            .as_array()
            .expect("leds")
            .iter()
            .filter_map(|l| l["status"].as_str())
            .collect();
        assert!(!statuses.contains(&"outlier"), "{tag}: {statuses:?}");
        assert!(
            statuses.iter().filter(|&&s| s == "used").count() >= 18,
            "{tag}: {statuses:?}"
        );
    }
}

/// A hand-built board, each LED off its grid place by its own move (σ 0.25 mm): the
/// fit's σ widens, and the warnings say why (the LEDs' own places, each measured)
/// instead of advising a brighter exposure or a larger defocus, which would not help.
/// Each LED's reported offset follows where truth.json says it was (correlated per
/// axis; what a placed board absorbs of the moves keeps it below 1: measured 0.95 and
/// 0.93).
#[test]
fn a_board_whose_leds_sit_off_their_grid_is_named_as_such() {
    let dir = TempDir::new("cal-warn-jitter");
    simulate(&dir, &["--led-jitter-mm", "0.25", "--seed", "4"]);
    let (stderr, json) = calibrate(&dir);
    assert!(
        stderr.contains("the LEDs sit off a rigid board by"),
        "{stderr}"
    );
    assert!(!stderr.contains("brighter exposure"), "{stderr}");
    assert!(!stderr.contains("larger defocus would help"), "{stderr}");
    // The offsets are the moves truth.json lists (up to what a placed board absorbs,
    // well under the 0.25 mm moves): compare the spread of their differences.
    let truth: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.0.join("truth.json")).expect("truth.json"),
    )
    .expect("JSON");
    let true_leds = truth["leds"]
        .as_array()
        .expect("truth lists the moved LEDs");
    let nominal =
        fpm_physics::LedGeometry::paper().placed_at(fpm_physics::Placement::from_array([
            truth["dx_mm"].as_f64().unwrap(),
            truth["dy_mm"].as_f64().unwrap(),
            truth["theta_deg"].as_f64().unwrap(),
            truth["height_mm"].as_f64().unwrap(),
            0.0,
            0.0,
        ]));
    let (mut moved, mut measured) = (vec![], vec![]);
    for l in json["leds"].as_array().unwrap() {
        let Some(offset) = l["offset_mm"].as_array() else {
            continue;
        };
        let led = fpm_physics::LedIndex::new(
            l["led"][0].as_u64().unwrap() as u8,
            l["led"][1].as_u64().unwrap() as u8,
        );
        let t = true_leds
            .iter()
            .find(|t| t["led"] == l["led"])
            .expect("a moved LED");
        let (x, y, _) = nominal.led_position_3d_mm(led);
        moved.push((
            t["position_mm"][0].as_f64().unwrap() - x,
            t["position_mm"][1].as_f64().unwrap() - y,
        ));
        measured.push((offset[0].as_f64().unwrap(), offset[1].as_f64().unwrap()));
    }
    assert!(measured.len() >= 20, "{} LEDs with offsets", measured.len());
    // Correlation of measured with true moves, each axis: a placed board's absorption
    // leaves it near 1; noise would leave it near 0.
    for axis in 0..2 {
        let pick = |v: &[(f64, f64)]| -> Vec<f64> {
            v.iter()
                .map(|p| if axis == 0 { p.0 } else { p.1 })
                .collect()
        };
        let (a, b) = (pick(&moved), pick(&measured));
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        let (ma, mb) = (mean(&a), mean(&b));
        let cov: f64 = a.iter().zip(&b).map(|(x, y)| (x - ma) * (y - mb)).sum();
        let var = |v: &[f64], m: f64| v.iter().map(|x| (x - m).powi(2)).sum::<f64>();
        let r = cov / (var(&a, ma) * var(&b, mb)).sqrt();
        eprintln!("axis {axis}: correlation of measured with true LED moves {r:.3}");
        assert!(r > 0.9, "axis {axis}: correlation {r}");
    }
}
