//! The robustness suite: bad input over the real pseudo-terminal never kills or wedges
//! the controller — random bytes, truncated and oversized frames, wrong keys and
//! out-of-range values each get an error reply or are dropped, and the next valid
//! request succeeds. Run against the host-compiled emulator (`robustness.rs`) and the
//! real firmware image in an emulated RP2040, over its USB port
//! (`robustness_firmware.rs`).

use std::io::{Read, Write};
use std::time::{Duration, Instant};

use fpm_acquire::controller::Controller;
use fpm_protocol::*;
use fpm_tests::wire::{frame, frames};
use fpm_tests::{Emulator, TempDir};

use crate::TARGET;
use postcard_rpc::header::{VarKey, VarSeq};
use postcard_rpc::{Endpoint, Key};
use rand::{Rng, SeedableRng};

/// Open the port raw, write `bytes`, and collect what comes back for `wait`.
/// Send `bytes` while reading the replies, until the link has been quiet for `wait`
/// (at most a minute: the emulated RP2040 runs slower than a real one on a loaded
/// machine, and what is tested is that requests are answered, not how fast).
fn exchange(port: &str, bytes: &[u8], wait: Duration) -> Vec<u8> {
    let mut p = serialport::new(port, 115_200)
        .timeout(Duration::from_millis(20))
        .open()
        .unwrap();
    let _ = p.clear(serialport::ClearBuffer::All);
    // Write from another thread while reading here, as a real client does: the device
    // answers as it reads, and a client that never reads would stall it.
    let mut writer = p.try_clone().unwrap();
    writer.set_timeout(Duration::from_secs(10)).unwrap();
    let bytes = bytes.to_vec();
    let writing = std::thread::spawn(move || {
        for chunk in bytes.chunks(256) {
            writer.write_all(chunk).unwrap();
        }
    });
    let mut got = vec![];
    let mut buf = [0u8; 4096];
    let start = Instant::now();
    let mut last_byte = Instant::now();
    while last_byte.elapsed() < wait && start.elapsed() < Duration::from_secs(60) {
        match p.read(&mut buf) {
            Ok(n) => {
                got.extend_from_slice(&buf[..n]);
                if n > 0 {
                    last_byte = Instant::now();
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
            Err(e) => panic!("read failed: {e}"),
        }
    }
    writing.join().expect("all bytes written");
    got
}

fn healthy(emu: &Emulator) -> DeviceStatus {
    let dev = Controller::open(&emu.port(), Duration::from_secs(2))
        .expect("controller answers after bad input");
    assert_eq!(dev.ping(99).unwrap(), 99);
    dev.set_led(LedIndex::new(1, 1), Rgb::WHITE).unwrap();
    dev.clear().unwrap();
    dev.status().unwrap()
}

#[test]
fn random_bytes_and_broken_frames_are_dropped_and_counted() {
    let dir = TempDir::new("garbage");
    let emu = TARGET.start(&dir.0.join("ctl.tty"), &[]);
    let mut rng = rand::rngs::StdRng::seed_from_u64(0xF0_0D);

    let mut bytes = vec![];
    // 64 KiB of noise.
    bytes.extend((0..65_536).map(|_| rng.gen::<u8>()));
    bytes.push(0);
    // Oversized frames: longer than any buffer on the device.
    bytes.extend(std::iter::repeat_n(0x55u8, 5000));
    bytes.push(0);
    // Truncated frames: a valid request cut short, then a delimiter.
    let valid = frame(
        SetLedEndpoint::REQ_KEY,
        1,
        &postcard::to_stdvec(&SetLed {
            led: LedIndex::new(0, 0),
            color: Rgb::WHITE,
        })
        .unwrap(),
    );
    for cut in 1..valid.len() - 1 {
        bytes.extend_from_slice(&valid[..cut]);
        bytes.push(0);
    }
    let reply = exchange(&emu.port(), &bytes, Duration::from_millis(500));
    // Whatever came back is well-formed: errors for frames that happened to decode.
    for (hdr, _) in frames(&reply) {
        assert!(
            hdr.key == VarKey::Key8(postcard_rpc::standard_icd::ERROR_KEY)
                || ENDPOINT_LIST
                    .endpoints
                    .iter()
                    .any(|(_, _, resp)| hdr.key == VarKey::Key8(*resp))
        );
    }
    let status = healthy(&emu);
    assert!(status.link.frames_dropped > 0, "{:?}", status.link);
    assert_eq!(status.leds_on, 0);
}

#[test]
fn wrong_keys_and_bad_bodies_get_wire_errors_with_their_sequence_numbers() {
    let dir = TempDir::new("keys");
    let emu = TARGET.start(&dir.0.join("ctl.tty"), &[]);
    let mut bytes = vec![];
    // A peer built against another schema for the same path: different key.
    let stale = Key::for_path::<(u8, u8)>("fpm/light/led");
    bytes.extend(frame(stale, 100, &[1, 2]));
    // A right key with a body of the wrong shape, and one with trailing bytes.
    bytes.extend(frame(SetLedEndpoint::REQ_KEY, 101, &[0xFF]));
    let mut body = postcard::to_stdvec(&SetLed {
        led: LedIndex::new(0, 0),
        color: Rgb::WHITE,
    })
    .unwrap();
    body.extend([1, 2, 3]);
    bytes.extend(frame(SetLedEndpoint::REQ_KEY, 102, &body));
    // Out-of-range values: a typed application error, not a wire error.
    let body = postcard::to_stdvec(&SetLed {
        led: LedIndex::new(250, 250),
        color: Rgb::WHITE,
    })
    .unwrap();
    bytes.extend(frame(SetLedEndpoint::REQ_KEY, 103, &body));
    let reply = exchange(&emu.port(), &bytes, Duration::from_millis(400));
    let got = frames(&reply);
    let find = |seq: u32| {
        got.iter()
            .find(|(h, _)| h.seq_no == VarSeq::Seq4(seq))
            .unwrap_or_else(|| panic!("no reply to {seq}"))
    };
    let wire_err = |seq: u32| {
        let (h, b) = find(seq);
        assert_eq!(h.key, VarKey::Key8(postcard_rpc::standard_icd::ERROR_KEY));
        postcard::from_bytes::<WireError>(b).unwrap()
    };
    assert_eq!(wire_err(100), WireError::UnknownKey);
    assert_eq!(wire_err(101), WireError::DeserFailed);
    assert_eq!(wire_err(102), WireError::DeserFailed);
    let (h, b) = find(103);
    assert_eq!(h.key, VarKey::Key8(SetLedEndpoint::RESP_KEY));
    assert_eq!(
        postcard::from_bytes::<LitResult>(b).unwrap(),
        Err(DeviceError::BadLed { row: 250, col: 250 })
    );

    let status = healthy(&emu);
    assert_eq!(status.link.unknown_keys, 1);
    assert_eq!(status.link.decode_errors, 2);
}

#[test]
fn random_request_bodies_on_every_key_never_wedge_the_process() {
    let dir = TempDir::new("fuzzkeys");
    let emu = TARGET.start(&dir.0.join("ctl.tty"), &[]);
    let mut rng = rand::rngs::StdRng::seed_from_u64(7);
    // Every key but the reboot into BOOTSEL, which ends the session by design (an
    // empty body is a valid request); its own test covers it.
    let keys: Vec<Key> = ENDPOINT_LIST
        .endpoints
        .iter()
        .map(|(_, k, _)| *k)
        .filter(|k| k.to_bytes() != BootselEndpoint::REQ_KEY.to_bytes())
        .collect();
    let mut bytes = vec![];
    for seq in 0..2000u32 {
        let key = keys[rng.gen_range(0..keys.len())];
        let len = rng.gen_range(0..64);
        let body: Vec<u8> = (0..len).map(|_| rng.gen()).collect();
        bytes.extend(frame(key, seq, &body));
    }
    let reply = exchange(&emu.port(), &bytes, Duration::from_millis(1500));
    let answered = frames(&reply).len();
    // Each request is answered (a reply or a wire error); topic messages from any
    // sequence the noise started may come on top.
    assert!(
        answered >= 1900,
        "only {answered} of 2000 requests answered"
    );
    let dev = Controller::open(&emu.port(), Duration::from_secs(2)).unwrap();
    if dev.sequence_status().unwrap().state == SequenceState::Running {
        dev.abort_sequence().unwrap();
    }
    drop(dev);
    healthy(&emu);
}
