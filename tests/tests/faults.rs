//! Faults on either side of the link, against the host-compiled emulator: the shared
//! faults suite, and peers that speak another protocol version.

use std::time::Duration;

use fpm_acquire::controller::{Controller, ControllerError};
use fpm_protocol::*;
use fpm_tests::foreign_device;

/// The controller the suite runs against.
pub const TARGET: fpm_tests::Target = fpm_tests::Target::HostEmulator;

mod faults_suite;

const TIMEOUT: Duration = Duration::from_secs(2);

#[test]
fn a_protocol_version_mismatch_names_both_versions() {
    // Built (if it must be) before the stand-ins start: they answer for a minute.
    let fpm = fpm_tests::fpm_bin();
    let newer = ProtocolVersion {
        major: PROTOCOL_VERSION.major + 1,
        minor: 0,
    };
    let (_h, path, _pair) = foreign_device(Some(newer));
    let err = Controller::open(&path, TIMEOUT)
        .err()
        .expect("mismatch refused");
    let text = err.to_string();
    assert!(
        matches!(err, ControllerError::VersionMismatch { .. }),
        "{text}"
    );
    assert!(
        text.contains(&PROTOCOL_VERSION.to_string()) && text.contains(&newer.to_string()),
        "{text}"
    );
    assert!(text.contains("update the fpm host"), "{text}");

    let older = ProtocolVersion {
        major: PROTOCOL_VERSION.major.saturating_sub(1),
        minor: 9,
    };
    let (_h, path, _pair) = foreign_device(Some(older));
    let text = Controller::open(&path, TIMEOUT)
        .err()
        .expect("mismatch refused")
        .to_string();
    assert!(text.contains("flash newer firmware"), "{text}");

    // `fpm acquire` on that board stops before anything is lit or written, and says
    // how to flash it.
    let out = tempfile::tempdir().unwrap();
    let acquired = std::process::Command::new(fpm)
        .args(["acquire", "--port", &path, "--out"])
        .arg(out.path().join("data"))
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&acquired.stderr);
    assert!(!acquired.status.success(), "{said}");
    assert!(
        said.contains(&older.to_string()) && said.contains("fpm device flash"),
        "{said}"
    );
    assert!(!out.path().join("data").exists(), "{said}");
}

#[test]
fn a_device_that_does_not_speak_fpm_is_named_as_such() {
    let (_h, path, _pair) = foreign_device(None);
    let err = Controller::open(&path, TIMEOUT).err().expect("refused");
    assert!(matches!(err, ControllerError::NotFpm { .. }), "{err}");
    assert!(
        err.to_string().contains("does not speak the fpm protocol"),
        "{err}"
    );
}
