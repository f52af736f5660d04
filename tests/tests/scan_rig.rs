//! A scan on the virtual rig, end to end: the emulated controller, the virtual camera
//! rendering a slide larger than one field whose focus height changes from field to
//! field, the virtual stage missing its positions (hidden, up to 10 µm), each field
//! focused from a few bright-field frames, calibration at the first field, each field
//! reconstructed while the next is acquired, the fields stitched, the mosaic scored
//! against the hidden slide (`fpm demo --scan` runs the same at 3 × 3 with every LED).

use fpm_tests::TempDir;

#[test]
fn a_scan_on_the_virtual_rig_is_focused_and_stitched_where_the_stage_really_went() {
    let tmp = TempDir::new("scan-rig");
    let out = tmp.0.join("scan");
    let demo = fpm_rig::demo::ScanDemo {
        out: Some(out.clone()),
        rows: 2,
        cols: 2,
        leds: Some(9),
        // A 192² field is 115 µm, a few cells wide: 60 % of it overlaps (at 50 % the
        // weakest of the four overlaps scored 0.42–0.74 from run to run of the noise).
        overlap: 0.6,
        ..fpm_rig::demo::ScanDemo::default()
    };
    let report = fpm_rig::demo::run_scan(&demo, fpm_tests::fpm_bin(), |_, _| {}).expect("the scan");
    assert_eq!(report.scan.fields, 4);
    assert_eq!(report.scan.acquired, 4);
    let t = report
        .stitch
        .versus_truth
        .as_ref()
        .expect("scored against the slide");
    eprintln!("{t:?}");
    // The stage missed (the test could fail on it) and the images put the fields back.
    assert!(t.rms_stage_error_um > 2.0, "{t:?}");
    assert!(t.max_position_error_um < 1.0, "{t:?}");
    assert!(t.ratio <= 1.1, "{t:?}");
    // A slide in focus (3 µm per mm) is left alone: each field measured, none moved.
    for f in &manifest_of(&out).fields {
        let focus = f.focus.expect("each field focused");
        assert!(!focus.moved, "{}: moved for {focus:?}", f.dataset);
    }
}

fn manifest_of(out: &std::path::Path) -> fpm_host::scan::ScanManifest {
    fpm_host::scan::ScanManifest::read(out).unwrap()
}

/// A slide whose focus height changes steeply (1.5 µm per µm here: a real slide's tens
/// of µm over centimetres, on fields this small): each field is brought into focus
/// from where the stage held the last.
#[test]
fn each_field_of_a_scan_is_brought_into_focus() {
    let tmp = TempDir::new("scan-focus");
    let out = tmp.0.join("scan");
    let demo = fpm_rig::demo::ScanDemo {
        out: Some(out.clone()),
        rows: 1,
        cols: 2,
        leds: Some(5),
        overlap: 0.6,
        tilt_um_per_mm: 1500.0,
        ..fpm_rig::demo::ScanDemo::default()
    };
    fpm_rig::demo::run_scan(&demo, fpm_tests::fpm_bin(), |_, _| {}).expect("the scan");
    // Each field's defocus as acquired: the slide's height under it (the camera's
    // hidden log) less the stage's Z there (the virtual stage's Z is minus its defocus).
    let surface: Vec<([f64; 2], f64)> = std::fs::read_to_string(out.join("rig-truth/stage.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .map(|v| {
            let c = [0, 1].map(|i| v["commanded_um"][i].as_f64().unwrap());
            (c, v["surface_um"].as_f64().unwrap())
        })
        .collect();
    let (mut farthest, mut sigma): (f64, f64) = (0.0, 0.0);
    for f in &manifest_of(&out).fields {
        let height = surface
            .iter()
            .rev()
            .find(|(c, _)| {
                (c[0] - f.stage_um[0]).abs() < 1e-3 && (c[1] - f.stage_um[1]).abs() < 1e-3
            })
            .expect("the camera rendered the field")
            .1;
        let focus = f.focus.expect("each field focused");
        let defocus = height - f.z_um.expect("the field's Z");
        eprintln!(
            "{}: surface {height:+.1} µm, acquired {defocus:+.1} µm out of focus ({focus:?})",
            f.dataset
        );
        farthest = farthest.max(height.abs());
        sigma = sigma.max(focus.sigma_um);
        // Within the measure's own 3σ (a sample's relief reads as a defocus of its own).
        assert!(
            defocus.abs() < 3.0 * focus.sigma_um,
            "{} acquired {defocus} µm out of focus",
            f.dataset
        );
    }
    // Without refocusing (the stage at the Z it started at), a field would have been
    // acquired clearly out of focus.
    assert!(
        farthest > 3.0 * sigma,
        "the slide's height is within {farthest} µm of focus: nothing to follow"
    );
}
