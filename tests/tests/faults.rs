//! Faults on either side of the link, against the host-compiled emulator: the shared
//! faults suite, and peers that speak another protocol version.

use std::io::{Read, Write};
use std::os::fd::AsFd;
use std::time::{Duration, Instant};

use fpm_acquire::controller::{Controller, ControllerError};
use fpm_protocol::*;
use fpm_tests::wire::{frame, frames};
use postcard_rpc::header::VarSeq;
use postcard_rpc::Endpoint;

/// The controller the suite runs against.
pub const TARGET: fpm_tests::Target = fpm_tests::Target::HostEmulator;

mod faults_suite;

const TIMEOUT: Duration = Duration::from_secs(2);

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
