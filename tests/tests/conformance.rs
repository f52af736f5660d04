//! Conformance against the host-compiled emulator (the firmware logic on the host,
//! behind a pseudo-terminal): the shared suite, plus the client's own timeout.

use std::time::Duration;

use fpm_acquire::controller::{Controller, ControllerError};
use fpm_tests::Target;

/// The controller the suite runs against.
pub const TARGET: Target = Target::HostEmulator;

mod conformance_suite;

#[test]
fn timeouts_are_reported_per_request() {
    // A pseudo-terminal nobody serves: the version request must time out cleanly.
    let pair = nix::pty::openpty(None, None).unwrap();
    let path = nix::unistd::ttyname(std::os::fd::AsFd::as_fd(&pair.slave)).unwrap();
    let start = std::time::Instant::now();
    let err = Controller::open(path.to_str().unwrap(), Duration::from_millis(300))
        .err()
        .expect("no device");
    assert!(
        matches!(
            err,
            ControllerError::Timeout {
                request: "fpm/version",
                ..
            }
        ),
        "{err}"
    );
    assert!(start.elapsed() < Duration::from_secs(2));
    drop(pair);
}
