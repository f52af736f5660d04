//! The reconstruction judged on data from a forward model we did not write (issue 63):
//! `tests/independent/simulate.py`, NumPy from the physics of docs/dataset.md, with
//! each LED's exact spherical wave and a sample larger than the field. fpm's own
//! simulator is the model its solver fits, so a bias shared by both cannot show on its
//! sets; it can on these.

use std::path::Path;
use std::process::Command;

use fpm_tests::{fpm_bin, python_with_numpy, workspace, TempDir};

/// An independent set of `size`² frames in `out`.
fn simulate(out: &Path, size: usize) {
    let run = Command::new(python_with_numpy())
        .arg(workspace().join("tests/independent/simulate.py"))
        .arg(out)
        .args(["--size", &size.to_string()])
        .output()
        .expect("running simulate.py");
    assert!(
        run.status.success(),
        "simulate.py: {}",
        String::from_utf8_lossy(&run.stderr)
    );
}

/// `fpm reconstruct` of `dataset` as the issue measured it (10 passes, U = 2), the
/// tiling its own unless `tile` is given: (the tile side it used, its complex NRMSE
/// against the hidden sample).
fn reconstruct(dataset: &Path, out: &Path, tile: Option<usize>) -> (u64, f64) {
    let mut cmd = Command::new(fpm_bin());
    cmd.arg("reconstruct")
        .arg(dataset)
        .arg("--out")
        .arg(out)
        .args(["--upsample", "2", "--passes", "10", "--json"]);
    if let Some(t) = tile {
        cmd.args(["--tile", &t.to_string()]);
    }
    let started = std::time::Instant::now();
    let run = cmd.output().expect("running fpm reconstruct");
    let wall_ms = started.elapsed().as_secs_f64() * 1e3;
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&run.stdout).expect("report JSON");
    let nrmse = report["versus_truth"]["complex_nrmse"]
        .as_f64()
        .unwrap_or_else(|| panic!("no score against the truth: {report}"));
    assert_steps_timed(&report, wall_ms);
    assert_no_stray_light_alarm(&report);
    (report["tile_size"].as_u64().unwrap_or(0), nrmse)
}

/// These sets' sample fills the field, so their dark-field frames' darkest blocks hold
/// its own light, which is not flat: left on, as it should be, and no sign of stray
/// light. The check warned on every such set (396 of 396 frames left on) until it
/// asked first whether the sample leaves clear glass (issue 63: a check over 2 % false
/// alarms on another forward model's sets).
fn assert_no_stray_light_alarm(report: &serde_json::Value) {
    let warnings = report["warnings"].as_array().expect("warnings");
    assert!(
        warnings
            .iter()
            .all(|w| w["check"] != "dark-field-background"),
        "clear glass in the axial frame {}: {warnings:?}",
        report["background"]["axis_clear_share"]
    );
}

/// report.json times each step of the job (issue 63): EPRY as the report's own
/// `total_ms`, the automatic checks beside it, every step's time within the process's
/// own wall-clock time.
fn assert_steps_timed(report: &serde_json::Value, wall_ms: f64) {
    let steps = report["steps_ms"].as_array().expect("steps_ms");
    let ms = |name: &str| {
        steps
            .iter()
            .find(|s| s["step"] == name)
            .and_then(|s| s["ms"].as_f64())
            .unwrap_or_else(|| panic!("no step {name:?}: {steps:?}"))
    };
    assert_eq!(
        ms("EPRY"),
        report["total_ms"].as_f64().unwrap(),
        "{steps:?}"
    );
    assert!(ms("refocus estimate and edge checks") >= 0.0, "{steps:?}");
    let sum: f64 = steps.iter().filter_map(|s| s["ms"].as_f64()).sum();
    assert!(
        sum > 0.0 && sum <= wall_ms,
        "steps {sum} ms in a {wall_ms} ms run: {steps:?}"
    );
}

/// The default tiling is within 1.1× of the best of the tilings tried, on a field of
/// one default tile (128²) and on one the issue found the default 4.4× off on (256²,
/// there with another set). Two sizes because the tile rule's choice changes with the
/// field: the whole frame as one tile at both here, tiles of a half and three
/// quarters as the rivals. The same sets also show that our model and the
/// independent one agree: the default recovers the hidden sample to a complex NRMSE
/// under 0.08 (0.058 and 0.046 measured).
#[test]
fn the_default_tiling_is_within_a_tenth_of_the_best_on_independent_fields() {
    let dir = TempDir::new("independent-tiling");
    for size in [128usize, 256] {
        let mut lines = vec![];
        let set = dir.0.join(format!("set-{size}"));
        simulate(&set, size);
        let (default_tile, default) = reconstruct(&set, &dir.0.join(format!("r{size}")), None);
        let mut best = default;
        for tile in [size / 2, size * 3 / 4] {
            let (_, nrmse) = reconstruct(&set, &dir.0.join(format!("r{size}-{tile}")), Some(tile));
            lines.push(format!("{size}²: --tile {tile}: complex NRMSE {nrmse:.4}"));
            best = best.min(nrmse);
        }
        lines.push(format!(
            "{size}²: default (tile {default_tile}): complex NRMSE {default:.4}"
        ));
        eprintln!("{}", lines.join("\n"));
        assert!(
            default <= 1.1 * best,
            "the default tiling is {:.2}× the best:\n{}",
            default / best,
            lines.join("\n")
        );
        assert!(default <= 0.08, "{}", lines.join("\n"));
    }
}
