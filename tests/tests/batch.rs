//! `fpm reconstruct DIR... --out-root ROOT`: a slide's fields of view, each into its
//! own directory, the same images as one-by-one runs, done fields skipped, interrupted
//! work redone, and one broken field not stopping the others.

use std::path::Path;
use std::process::{Command, Output};

use fpm_tests::{fpm_bin, TempDir};

fn fpm(args: &[&str]) -> Output {
    Command::new(fpm_bin())
        .args(args)
        .output()
        .expect("running fpm")
}

fn ok(out: Output, what: &str) -> String {
    assert!(
        out.status.success(),
        "{what}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn modified(path: &Path) -> std::time::SystemTime {
    std::fs::metadata(path)
        .and_then(|m| m.modified())
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn a_slide_is_reconstructed_field_by_field_and_resumes() {
    let scratch = TempDir::new("batch");
    let slide = scratch.0.join("slide");
    let s = |p: &Path| p.to_string_lossy().into_owned();
    for seed in 1..=3 {
        let field = s(&slide.join(format!("field_{seed}")));
        let args = ["simulate", "acquisition", "--out", &field, "--size", "64"];
        ok(
            fpm(&[&args[..], &["--seed", &seed.to_string()]].concat()),
            "simulate",
        );
    }
    let root = scratch.0.join("results");
    let pattern = s(&slide.join("field_*"));
    let root_arg = s(&root);
    let batch = |extra: &[&str]| {
        let args = [
            &[
                "reconstruct",
                &pattern,
                "--out-root",
                &root_arg,
                "--passes",
                "2",
            ],
            extra,
        ]
        .concat();
        fpm(&args)
    };
    let first = ok(batch(&[]), "first batch");
    assert!(
        first.contains("3 reconstructed, 0 already done, 0 failed"),
        "{first}"
    );

    // Each field's images are those of a run of its own.
    let single = scratch.0.join("single");
    let field_2 = s(&slide.join("field_2"));
    ok(
        fpm(&[
            "reconstruct",
            &field_2,
            "--out",
            &s(&single),
            "--passes",
            "2",
        ]),
        "single run",
    );
    for image in ["amplitude.tif", "phase.tif"] {
        let batch_bytes = std::fs::read(root.join("field_2").join(image)).unwrap();
        let single_bytes = std::fs::read(single.join(image)).unwrap();
        assert!(
            batch_bytes == single_bytes,
            "{image} differs from a run of its own"
        );
    }

    // Done fields are skipped; a field whose output is gone, or left partial by an
    // interrupted run, is done again.
    let kept = modified(&root.join("field_1/amplitude.tif"));
    std::fs::remove_dir_all(root.join("field_3")).unwrap();
    std::fs::create_dir_all(root.join(".field_3.partial/plots")).unwrap();
    let again = ok(batch(&[]), "second batch");
    assert!(again.contains("1 reconstructed, 2 already done"), "{again}");
    assert_eq!(modified(&root.join("field_1/amplitude.tif")), kept);
    assert!(root.join("field_3/report.json").is_file());
    assert!(!root.join(".field_3.partial").exists());

    // A broken field fails alone, named, and the run says so in its exit status.
    let broken = slide.join("field_4");
    std::fs::create_dir_all(&broken).unwrap();
    std::fs::write(broken.join("dataset.toml"), "[system]\nna = 2.0\n").unwrap();
    let out = batch(&["--redo"]);
    assert!(!out.status.success(), "a failed field fails the batch");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("3 reconstructed, 0 already done, 1 failed"),
        "{stdout}"
    );
    assert!(
        stdout.contains("field_4") && stdout.contains("dataset.toml"),
        "{stdout}"
    );
    assert!(!root.join("field_4").exists() && !root.join(".field_4.partial").exists());

    // One --out takes one dataset.
    let two = fpm(&[
        "reconstruct",
        &field_2,
        &s(&slide.join("field_1")),
        "--out",
        "x",
    ]);
    assert!(!two.status.success());
    assert!(String::from_utf8_lossy(&two.stderr).contains("--out-root"));
}
