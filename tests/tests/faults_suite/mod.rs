//! The faults suite: the controller killed mid-sequence and restarted, a client killed
//! mid-sequence. Run against the host-compiled emulator (`faults.rs`) and the real
//! firmware image in an emulated RP2040 (`faults_firmware.rs`).

use std::io::Read;
use std::time::{Duration, Instant};

use fpm_acquire::controller::scan::{scan_steps, Order, Selection};
use fpm_acquire::controller::{Controller, ControllerError, SequenceEvent};
use fpm_protocol::*;
use fpm_tests::TempDir;

use crate::TARGET;

const TIMEOUT: Duration = Duration::from_secs(2);

fn slow_scan_timing() -> SequenceTiming {
    SequenceTiming {
        settle_us: 1000,
        exposure_us: 20_000,
        trigger_out: Some(TriggerOut {
            delay_us: 0,
            pulse_us: 100,
            polarity: Polarity::ActiveHigh,
        }),
        trigger_in: None,
        clear_at_end: true,
    }
}

#[test]
fn emulator_killed_mid_sequence_is_reported_at_once_and_a_restart_reconnects() {
    let dir = TempDir::new("kill");
    let link = dir.0.join("ctl.tty");
    let mut emu = TARGET.start(&link, &[]);
    let dev = Controller::open(&emu.port(), TIMEOUT).unwrap();
    let steps = scan_steps(
        &dev.info().geometry,
        Selection::All,
        Order::Nearest,
        Rgb::WHITE,
    );
    dev.upload_sequence(1, &steps, slow_scan_timing()).unwrap();
    let mut events = dev.subscribe().unwrap();
    dev.start_sequence(1).unwrap();
    for _ in 0..3 {
        assert!(matches!(
            events.next(TIMEOUT).unwrap(),
            SequenceEvent::Step(_)
        ));
    }

    emu.kill();
    let killed = Instant::now();
    // Drain what was already in flight; then the loss must be reported, well before
    // the event timeout.
    let err = loop {
        match events.next(Duration::from_secs(10)) {
            Ok(SequenceEvent::Step(_) | SequenceEvent::SetStep(_)) => continue,
            Ok(SequenceEvent::End(e)) => panic!("a killed device cannot end its sequence: {e:?}"),
            Err(e) => break e,
        }
    };
    assert!(matches!(err, ControllerError::Disconnected { .. }), "{err}");
    assert!(
        killed.elapsed() < Duration::from_secs(2),
        "took {:?}",
        killed.elapsed()
    );
    assert!(err.to_string().contains("lost the connection"), "{err}");
    let err = dev.status().unwrap_err();
    assert!(
        matches!(
            err,
            ControllerError::Disconnected {
                request: "fpm/status",
                ..
            }
        ),
        "{err}"
    );
    drop(events);
    drop(dev);

    // The crash left its link behind. It is not opened here: the dead terminal's
    // number is free for any process on the machine, so the link may already point at
    // another test's live board.
    assert!(std::fs::symlink_metadata(&link).is_ok());

    // A restarted emulator replaces the stale link; the client reconnects and works.
    let emu2 = TARGET.start(&link, &[]);
    let dev = Controller::open(&emu2.port(), TIMEOUT).unwrap();
    let status = dev.status().unwrap();
    assert_eq!(
        status.sequence.state,
        SequenceState::Empty,
        "a fresh device after restart"
    );
    dev.upload_sequence(2, &steps[..5], slow_scan_timing())
        .unwrap();
    let mut events = dev.subscribe().unwrap();
    dev.start_sequence(2).unwrap();
    let mut n = 0;
    loop {
        match events.next(TIMEOUT).unwrap() {
            SequenceEvent::Step(_) | SequenceEvent::SetStep(_) => n += 1,
            SequenceEvent::End(e) => {
                assert_eq!(e.outcome, SequenceOutcome::Done);
                break;
            }
        }
    }
    assert_eq!(n, 5);
}

#[test]
fn a_client_killed_mid_sequence_leaves_the_device_usable() {
    let dir = TempDir::new("clientkill");
    let emu = TARGET.start(&dir.0.join("ctl.tty"), &[]);
    let mut child = std::process::Command::new(fpm_tests::fpm_bin())
        .args([
            "device",
            "--port",
            &emu.port(),
            "--json",
            "run-sequence",
            "--exposure-us",
            "20000",
            "--id",
            "77",
        ])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    // Wait for the first step to be reported, then kill the client.
    let mut out = child.stdout.take().unwrap();
    let mut first = [0u8; 1];
    out.read_exact(&mut first).unwrap();
    child.kill().unwrap();
    child.wait().unwrap();

    // The device keeps running the sequence; a new client sees it and can abort it.
    let dev = Controller::open(&emu.port(), TIMEOUT).unwrap();
    let status = dev.sequence_status().unwrap();
    assert_eq!((status.state, status.id), (SequenceState::Running, 77));
    let aborted = dev.abort_sequence().unwrap();
    assert_eq!(aborted.last_outcome, Some(SequenceOutcome::Aborted));
    assert!(aborted.completed >= 1);
    assert_eq!(dev.status().unwrap().leds_on, 0);
}
