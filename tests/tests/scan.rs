//! Whole slides against hidden truth: a simulated 3×3 scan of one larger slide (each
//! field a full wave-optics acquisition, the stage off its commanded positions by up
//! to 20 µm), stitched by `fpm stitch`, scored against the slide. Seeds 1–6 measured
//! (docs/results.md, "Whole slides"): five place every field within 0.2–0.9 µm; in
//! seed 3 one field's overlaps are blank glass and it keeps the stage's position
//! (warned). Seed 2 is one of the five.

use fpm_tests::{fpm_bin, fpm_stdout, TempDir};

#[test]
fn a_three_by_three_scan_stitches_within_the_fields_own_error() {
    let tmp = TempDir::new("scan-stitch");
    let scan = tmp.0.join("scan");
    let scan_s = scan.to_str().unwrap();
    // 160² fields at 2× (1.2 µm pixels: 192 µm), 30 % overlap (58 µm, so that a 20 µm
    // error either way still leaves an overlap to register on), the central 9 × 9 LEDs.
    fpm_stdout(&[
        "simulate",
        "scan",
        "--out",
        scan_s,
        "--fields",
        "3x3",
        "--size",
        "160",
        "--magnification",
        "2",
        "--leds",
        "9",
        "--overlap",
        "0.3",
        "--stage-error-um",
        "20",
        "--seed",
        "2",
    ]);
    let out = fpm_stdout(&["stitch", scan_s, "--json"]);
    let report: serde_json::Value = serde_json::from_str(&out).expect("stitch.json");
    let t = &report["versus_truth"];
    let (mosaic, fields) = (
        t["complex_nrmse"].as_f64().unwrap(),
        t["fields_complex_nrmse"].as_f64().unwrap(),
    );
    let (max_err, stage_rms) = (
        t["max_position_error_um"].as_f64().unwrap(),
        t["rms_stage_error_um"].as_f64().unwrap(),
    );
    let (seam, within) = (
        t["seam_step_rad"].as_f64().unwrap(),
        t["within_step_rad"].as_f64().unwrap(),
    );
    eprintln!("mosaic {mosaic:.4} fields {fields:.4}; placed within {max_err:.2} µm (stage {stage_rms:.1} µm rms); seam {seam:.4} rad, within {within:.4}");
    // The stage's error is real (stitching on it alone would keep it) …
    assert!(
        stage_rms > 5.0,
        "the simulated stage should be off: {stage_rms} µm rms"
    );
    // … and the images take it out.
    assert!(
        max_err <= 1.0,
        "fields placed within {max_err} µm of the truth"
    );
    assert!(
        mosaic <= 1.1 * fields,
        "mosaic {mosaic} against the fields' own {fields}"
    );
    assert!(
        seam <= 1.5 * within + 0.005,
        "seam step {seam} rad against {within} across a field"
    );
    // The mosaic: an OME-Zarr pyramid placed in the slide's coordinates.
    let zattrs: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(scan.join("mosaic/mosaic.zarr/.zattrs")).unwrap(),
    )
    .unwrap();
    let transforms = &zattrs["multiscales"][0]["datasets"][0]["coordinateTransformations"];
    assert_eq!(transforms[1]["type"], "translation", "{transforms}");
    // The report page beside it, with the score.
    let page = std::fs::read_to_string(scan.join("mosaic/report.html")).unwrap();
    assert!(page.contains("id=\"mosaic-nrmse\""), "{page}");
    // Fields done are not reconstructed again; kept in memory as few as a band of the
    // mosaic needs (the others read again from disk), the same mosaic, byte for byte.
    let lean = tmp.0.join("lean");
    let again = std::process::Command::new(fpm_bin())
        .args(["stitch", scan_s, "--field-memory-mib", "0", "--out"])
        .arg(&lean)
        .output()
        .unwrap();
    assert!(again.status.success());
    let text = String::from_utf8_lossy(&again.stdout);
    assert!(text.contains("9 fields joined"), "{text}");
    let files = |dir: &std::path::Path| {
        let mut out = std::collections::BTreeMap::new();
        let mut stack = vec![dir.to_path_buf()];
        while let Some(d) = stack.pop() {
            for e in std::fs::read_dir(&d).unwrap() {
                let p = e.unwrap().path();
                if p.is_dir() {
                    stack.push(p);
                } else {
                    let bytes = std::fs::read(&p).unwrap();
                    out.insert(p.strip_prefix(dir).unwrap().to_path_buf(), bytes);
                }
            }
        }
        out
    };
    let (whole, streamed) = (
        files(&scan.join("mosaic/mosaic.zarr")),
        files(&lean.join("mosaic.zarr")),
    );
    assert!(whole.len() > 3 && whole == streamed, "the mosaics differ");
}

#[test]
fn a_scan_directory_that_is_not_one_is_named() {
    let tmp = TempDir::new("scan-bad");
    let out = std::process::Command::new(fpm_bin())
        .args(["stitch", tmp.0.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("scan.json"), "{err}");
    std::fs::write(tmp.0.join("scan.json"), r#"{"format":"fpm-scan/1","rows":1,"cols":1,"overlap":0.1,"fields":[{"row":0,"col":0,"dataset":"../x","stage_um":[0,0]}]}"#).unwrap();
    let out = std::process::Command::new(fpm_bin())
        .args(["stitch", tmp.0.to_str().unwrap()])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("inside the scan"), "{err}");
}
