//! A scan on the virtual rig, end to end: the emulated controller, the virtual camera
//! rendering a slide larger than one field, the virtual stage missing its positions
//! (hidden, up to 10 µm), calibration at the first field, each field reconstructed
//! while the next is acquired, the fields stitched, the mosaic scored against the
//! hidden slide (`fpm demo --scan` runs the same at 3 × 3 with every LED).

use fpm_tests::{fpm_bin, TempDir};

#[test]
fn a_scan_on_the_virtual_rig_is_stitched_where_the_stage_really_went() {
    let tmp = TempDir::new("scan-rig");
    let demo = fpm_rig::demo::ScanDemo {
        out: Some(tmp.0.join("scan")),
        rows: 2,
        cols: 2,
        leds: Some(9),
        // Half the field: a 192² field is 115 µm, a few cells wide.
        overlap: 0.5,
        ..fpm_rig::demo::ScanDemo::default()
    };
    let report = fpm_rig::demo::run_scan(&demo, fpm_bin(), |_, _| {}).expect("the scan");
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
}
