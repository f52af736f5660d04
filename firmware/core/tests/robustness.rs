//! Property tests: no byte sequence panics the controller, wedges it, or grows its
//! memory, and a valid request right after garbage is answered.

mod common;

use common::*;
use fpm_protocol::*;
use postcard_rpc::header::{VarHeader, VarKey, VarSeq};
use postcard_rpc::Endpoint;
use proptest::prelude::*;

/// Every request key the device knows, so random bodies reach the handlers.
fn keys() -> Vec<postcard_rpc::Key> {
    ENDPOINT_LIST
        .endpoints
        .iter()
        .map(|(_, req, _)| *req)
        .collect()
}

fn frame(key: postcard_rpc::Key, seq: u32, body: &[u8]) -> Vec<u8> {
    let hdr = VarHeader {
        key: VarKey::Key8(key),
        seq_no: VarSeq::Seq4(seq),
    };
    let mut raw = hdr.write_to_vec();
    raw.extend_from_slice(body);
    let mut wire = cobs::encode_vec(&raw);
    wire.push(0);
    wire
}

/// After whatever came before, a version request on a clean frame boundary is answered.
fn still_answers(dev: &mut Dev, now: u64) {
    let mut wire = Wire::default();
    // A lone delimiter ends whatever partial frame the garbage left behind.
    let mut bytes = vec![0u8];
    bytes.extend(encode_request::<VersionEndpoint>(&(), 0xABCD));
    dev.receive(&bytes, now, &mut |b: &[u8]| wire.bytes.extend_from_slice(b));
    let replies: Vec<_> = wire
        .frames()
        .into_iter()
        .filter(|(h, _)| h.key == VarKey::Key8(VersionEndpoint::RESP_KEY))
        .collect();
    assert_eq!(
        replies.len(),
        1,
        "device wedged: no answer to a valid request"
    );
    assert_eq!(replies[0].0.seq_no, VarSeq::Seq4(0xABCD));
    assert_eq!(
        postcard::from_bytes::<ProtocolVersion>(&replies[0].1).unwrap(),
        PROTOCOL_VERSION
    );
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn random_bytes_never_panic_or_wedge(chunks in prop::collection::vec(prop::collection::vec(any::<u8>(), 0..700), 1..8)) {
        let mut dev = device();
        let mut now = 1_000u64;
        for c in &chunks {
            dev.receive(c, now, &mut |_: &[u8]| {});
            now += 1_000;
        }
        still_answers(&mut dev, now);
    }

    #[test]
    fn random_bodies_on_real_keys_get_a_reply_and_never_panic(
        reqs in prop::collection::vec((0usize..64, prop::collection::vec(any::<u8>(), 0..120)), 1..40),
        polls in prop::collection::vec(0u64..200_000, 0..20),
    ) {
        let keys = keys();
        let mut dev = device();
        let mut now = 1_000u64;
        let mut replies = 0usize;
        for (i, (k, body)) in reqs.iter().enumerate() {
            let key = keys[k % keys.len()];
            let mut wire = Wire::default();
            dev.receive(&frame(key, i as u32, body), now, &mut |b: &[u8]| wire.bytes.extend_from_slice(b));
            // Exactly one reply (an answer or a wire error) with our sequence number.
            let frames = wire.frames();
            replies += frames.iter().filter(|(h, _)| h.seq_no == VarSeq::Seq4(i as u32)).count().min(1);
            now += polls.get(i).copied().unwrap_or(100);
            dev.poll(now, &mut |_: &[u8]| {});
            if dev.bootsel_requested() {
                // A board restarting in BOOTSEL comes back as a fresh one.
                prop_assert_eq!(dev.current_ma(), 0);
                dev = device();
            }
        }
        prop_assert_eq!(replies, reqs.len());
        // Drain any sequence the random requests started, then check the link is alive.
        let _ = run_until(&mut dev, now, now + 600_000_000);
        still_answers(&mut dev, now + 600_000_000);
    }

    #[test]
    fn garbage_between_valid_requests_loses_only_the_garbage(
        garbage in prop::collection::vec(prop::collection::vec(1u8..=255, 0..600), 1..6),
    ) {
        // Garbage without zeros is one long unfinished frame; the zero that starts the
        // next request ends it, so at most that request is lost, never a later one.
        let mut dev = device();
        let mut bytes = vec![];
        for (i, g) in garbage.iter().enumerate() {
            bytes.extend_from_slice(g);
            bytes.push(0);
            bytes.extend(frame(SequenceStatusEndpoint::REQ_KEY, i as u32, &[]));
        }
        let mut wire = Wire::default();
        dev.receive(&bytes, 1_000, &mut |b: &[u8]| wire.bytes.extend_from_slice(b));
        let answered = wire
            .frames()
            .iter()
            .filter(|(h, _)| h.key == VarKey::Key8(SequenceStatusEndpoint::RESP_KEY))
            .count();
        prop_assert_eq!(answered, garbage.len());
    }
}

#[test]
fn memory_is_fixed_by_type() {
    // No heap in the controller: its whole state is this many bytes, whatever arrives.
    let size = std::mem::size_of::<Dev>();
    assert!(size < 48 * 1024, "controller state is {size} bytes");
}
