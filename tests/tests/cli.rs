//! What a user installs beside the binary: shell completions and man pages, generated
//! from the same definitions the commands parse with.

use std::process::Command;

use fpm_tests::{fpm_bin, TempDir};

fn fpm(args: &[&str]) -> String {
    let out = Command::new(fpm_bin()).args(args).output().unwrap();
    assert!(
        out.status.success(),
        "fpm {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
fn completions_know_every_command_and_option() {
    for shell in ["bash", "zsh", "fish"] {
        let script = fpm(&["completions", shell]);
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
    fpm(&["man", "--out", &dir.0.to_string_lossy()]);
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
