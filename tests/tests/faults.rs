//! Faults on either side of the link: the emulator killed mid-sequence, restarted,
//! a client killed mid-sequence, and peers that speak another protocol version.

use std::io::{Read, Write};
use std::os::fd::AsFd;
use std::time::{Duration, Instant};

use fpm_acquire::controller::scan::{scan_steps, Order, Selection};
use fpm_acquire::controller::{Controller, ControllerError, SequenceEvent};
use fpm_protocol::*;
use fpm_tests::wire::{frame, frames};
use fpm_tests::{Emulator, TempDir};
use postcard_rpc::header::VarSeq;
use postcard_rpc::Endpoint;

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
    let mut emu = Emulator::start_at(&link, &[]);
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
            Ok(SequenceEvent::Step(_)) => continue,
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

    // The crash left its link behind: opening it fails with a clear message.
    assert!(std::fs::symlink_metadata(&link).is_ok());
    if let Err(e) = Controller::open(&link.to_string_lossy(), Duration::from_millis(300)) {
        let text = e.to_string();
        assert!(text.contains(&*link.to_string_lossy()), "{text}");
    }

    // A restarted emulator replaces the stale link; the client reconnects and works.
    let emu2 = Emulator::start_at(&link, &[]);
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
            SequenceEvent::Step(_) => n += 1,
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
    let emu = Emulator::start_at(&dir.0.join("ctl.tty"), &[]);
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

/// A stand-in for other firmware on a pseudo-terminal: answers the version request
/// with `version`, or everything with `UnknownKey` when `version` is `None`.
fn foreign_device(
    version: Option<ProtocolVersion>,
) -> (std::thread::JoinHandle<()>, String, nix::pty::OpenptyResult) {
    let pair = nix::pty::openpty(None, None).unwrap();
    let mut t = nix::sys::termios::tcgetattr(pair.slave.as_fd()).unwrap();
    nix::sys::termios::cfmakeraw(&mut t);
    nix::sys::termios::tcsetattr(pair.slave.as_fd(), nix::sys::termios::SetArg::TCSANOW, &t)
        .unwrap();
    let path = nix::unistd::ttyname(pair.slave.as_fd())
        .unwrap()
        .to_string_lossy()
        .into_owned();
    let mut master = std::fs::File::from(pair.master.try_clone().unwrap());
    let handle = std::thread::spawn(move || {
        let mut buf = [0u8; 512];
        let mut acc = vec![];
        let deadline = Instant::now() + Duration::from_secs(10);
        while Instant::now() < deadline {
            let n = match master.read(&mut buf) {
                Ok(0) | Err(_) => return,
                Ok(n) => n,
            };
            acc.extend_from_slice(&buf[..n]);
            if !acc.contains(&0) {
                continue;
            }
            for (hdr, _) in frames(&acc) {
                let VarSeq::Seq4(seq) = hdr.seq_no else {
                    continue;
                };
                let reply = match version {
                    Some(v)
                        if hdr.key
                            == postcard_rpc::header::VarKey::Key8(VersionEndpoint::REQ_KEY) =>
                    {
                        frame(
                            VersionEndpoint::RESP_KEY,
                            seq,
                            &postcard::to_stdvec(&v).unwrap(),
                        )
                    }
                    _ => frame(
                        postcard_rpc::standard_icd::ERROR_KEY,
                        seq,
                        &postcard::to_stdvec(&WireError::UnknownKey).unwrap(),
                    ),
                };
                if master.write_all(&reply).is_err() {
                    return;
                }
            }
            acc.clear();
        }
    });
    (handle, path, pair)
}

#[test]
fn a_protocol_version_mismatch_names_both_versions() {
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
