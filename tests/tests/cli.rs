//! What a user installs beside the binary: shell completions and man pages, generated
//! from the same definitions the commands parse with.

use std::process::Command;

use fpm_tests::{fpm_bin, fpm_stdout, TempDir};

#[test]
fn completions_know_every_command_and_option() {
    for shell in ["bash", "zsh", "fish"] {
        let script = fpm_stdout(&["completions", shell]);
        for word in [
            "reconstruct",
            "calibrate",
            "device",
            "floor-sigma",
            "dark-field-peak-dn",
        ] {
            assert!(script.contains(word), "{shell} completion lacks {word}");
        }
    }
    let out = Command::new(fpm_bin())
        .args(["completions", "tcsh"])
        .output()
        .unwrap();
    assert!(!out.status.success(), "an unknown shell is refused");
}

#[test]
fn man_pages_are_written_for_every_subcommand() {
    let dir = TempDir::new("man");
    fpm_stdout(&["man", "--out", &dir.0.to_string_lossy()]);
    for page in [
        "fpm.1",
        "fpm-reconstruct.1",
        "fpm-device-list.1",
        "fpm-simulate-acquisition.1",
    ] {
        let text =
            std::fs::read_to_string(dir.0.join(page)).unwrap_or_else(|e| panic!("{page}: {e}"));
        assert!(
            text.starts_with(".ie") || text.contains(".TH"),
            "{page} is not a man page"
        );
    }
    let reconstruct = std::fs::read_to_string(dir.0.join("fpm-reconstruct.1")).unwrap();
    assert!(
        reconstruct.contains("floor\\-sigma"),
        "options are documented"
    );
}

/// `--json` prints what the command wrote, as a script would read it.
#[test]
fn simulate_and_reconstruct_speak_json() {
    let dir = TempDir::new("json");
    let data = dir.0.join("data");
    let out = dir.0.join("rec");
    let written: serde_json::Value = serde_json::from_str(&fpm_stdout(&[
        "simulate",
        "acquisition",
        "--size",
        "64",
        "--out",
        &data.to_string_lossy(),
        "--json",
    ]))
    .expect("simulate --json prints JSON");
    assert_eq!(written["frames"], 441);
    assert_eq!(written["size"], serde_json::json!([64, 64]));
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data.join("truth.json")).unwrap()).unwrap();
    assert_eq!(written["truth"], truth);

    let printed: serde_json::Value = serde_json::from_str(&fpm_stdout(&[
        "reconstruct",
        &data.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--passes",
        "2",
        "--json",
    ]))
    .expect("reconstruct --json prints JSON");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(printed, report);
    assert!(printed["versus_truth"]["complex_nrmse"].is_number());
}
