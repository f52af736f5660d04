//! Conformance against the host-compiled emulator (the firmware logic on the host,
//! behind a pseudo-terminal): the shared suite, plus what only this emulator has.

use std::time::Duration;

use fpm_acquire::controller::{Controller, ControllerError};
use fpm_protocol::*;
use fpm_tests::{Emulator, Target, TempDir};

/// The controller the suite runs against.
pub const TARGET: Target = Target::HostEmulator;

const TIMEOUT: Duration = Duration::from_secs(2);

mod conformance_suite;

#[test]
fn the_emulator_logs_what_it_lights_and_cleans_up_its_link() {
    let dir = TempDir::new("log");
    let link = dir.0.join("ctl.tty");
    let mut emu = Emulator::start_at(&link, &[]);
    {
        let dev = Controller::open(&emu.port(), TIMEOUT).unwrap();
        dev.set_led(LedIndex::new(2, 19), Rgb::new(1, 2, 3))
            .unwrap();
    }
    let status = emu.stop().expect("emulator ran");
    assert!(status.success(), "{status}");
    assert!(
        emu.log_text().contains("LEDs lit: (2,19) #010203"),
        "{}",
        emu.log_text()
    );
    assert!(
        std::fs::symlink_metadata(&link).is_err(),
        "link removed on exit"
    );
}

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
