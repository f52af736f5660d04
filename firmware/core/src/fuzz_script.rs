//! A byte script that drives a whole controller, for the coverage-guided fuzzer
//! (`firmware/core/fuzz`) and the regression test that replays its corpus
//! (`tests/fuzz_corpus.rs`). Not used by the firmware itself.
//!
//! The script is a list of operations, each a tag byte and its arguments: raw bytes on
//! the link, a framed request under any endpoint's key with an arbitrary body, the same
//! with the body re-encoded as a *valid* request (structure-aware: the fuzzer's bytes
//! choose the values), camera edges, and time passing. After every operation the
//! invariants are checked, and at the end the next valid request must be answered:
//! [`run`] panics when one does not hold, which is what the fuzzer looks for.

use fpm_protocol::limits::{MAX_ENCODED_FRAME_LEN, MAX_FRAME_LEN};
use fpm_protocol::*;
use postcard_rpc::header::{VarHeader, VarKey, VarSeq};
use postcard_rpc::standard_icd::PingEndpoint;
use postcard_rpc::{Endpoint, Key};
use smart_leds::RGB8;

use crate::board::BoardConfig;
use crate::budget::current_ua;
use crate::hw::{LedStrip, TriggerOut};
use crate::link::{encode, Feed, FrameReceiver};
use crate::storage::{CalibrationStore, RamNor};
use crate::Device;

/// A strip that checks the hard current limit on every frame it is given.
struct CheckedStrip {
    max_ua: u64,
    channel_current_ua: u32,
}

impl LedStrip for CheckedStrip {
    fn write(&mut self, pixels: &[RGB8], _lane_len: usize, _shift: &[u16]) {
        let need = current_ua(pixels, self.channel_current_ua);
        assert!(
            need <= self.max_ua,
            "a frame drawing {need} µA reached the strip (board rating {} µA)",
            self.max_ua
        );
    }
}

struct NoTrigger;

impl TriggerOut for NoTrigger {
    fn set_level(&mut self, _high: bool) {}
}

/// Reads the script's bytes; past the end everything reads as zero.
struct Cursor<'a> {
    data: &'a [u8],
    at: usize,
}

impl<'a> Cursor<'a> {
    fn byte(&mut self) -> u8 {
        let b = self.data.get(self.at).copied().unwrap_or(0);
        self.at += 1;
        b
    }

    fn bytes(&mut self, n: usize) -> &'a [u8] {
        let start = self.at.min(self.data.len());
        let end = (self.at + n).min(self.data.len());
        self.at += n;
        &self.data[start..end]
    }

    fn done(&self) -> bool {
        self.at >= self.data.len()
    }
}

/// Every endpoint of the protocol (ours and postcard-rpc's standard ones): a script
/// addresses one by its index in this list.
fn endpoints() -> &'static [(&'static str, Key, Key)] {
    ENDPOINT_LIST.endpoints
}

/// The body `raw` decoded as the request type of the endpoint at `path` and encoded
/// again: a valid request with values the fuzzer chose. `None` if `raw` does not decode
/// (or the endpoint is not one of ours).
fn valid_body(path: &str, raw: &[u8], out: &mut [u8]) -> Option<usize> {
    fn again<E: Endpoint>(raw: &[u8], out: &mut [u8]) -> Option<usize>
    where
        E::Request: serde::Serialize + serde::de::DeserializeOwned,
    {
        let value: E::Request = postcard::from_bytes(raw).ok()?;
        postcard::to_slice(&value, out).ok().map(|b| b.len())
    }
    macro_rules! by_path {
        ($($ep:ty),* $(,)?) => {
            $(if path == <$ep>::PATH { return again::<$ep>(raw, out); })*
        };
    }
    by_path!(
        PingEndpoint,
        VersionEndpoint,
        InfoEndpoint,
        StatusEndpoint,
        SetLedEndpoint,
        SetLedsEndpoint,
        ClearEndpoint,
        PatternEndpoint,
        BrightnessEndpoint,
        BudgetEndpoint,
        SequenceDefineEndpoint,
        SequenceStepsEndpoint,
        SequenceStartEndpoint,
        SequenceAbortEndpoint,
        SequenceStatusEndpoint,
        GeometryEndpoint,
        GeometrySetEndpoint,
        GammaEndpoint,
        LedSetDefineEndpoint,
        SequenceSetStepsEndpoint,
        BootselEndpoint,
    );
    None
}

/// Frame `body` under `key` with sequence number `seq`, as a host would.
fn frame(key: Key, seq: u32, body: &[u8], out: &mut [u8; MAX_ENCODED_FRAME_LEN + 8]) -> usize {
    let mut raw = [0u8; MAX_FRAME_LEN + 16];
    let hdr = VarHeader {
        key: VarKey::Key8(key),
        seq_no: VarSeq::Seq4(seq),
    };
    // Written header, and the rest of the buffer.
    let Some(used) = hdr.write_to_slice(&mut raw).map(|(h, _)| h.len()) else {
        return 0;
    };
    let n = body.len().min(raw.len() - used);
    raw[used..used + n].copy_from_slice(&body[..n]);
    encode(&raw[..used + n], out).map_or(0, |w| w.len())
}

/// Run `script` against a fresh controller; panics if an invariant breaks.
pub fn run(script: &[u8]) {
    // A board as it starts (again, after a restart in BOOTSEL brings it back).
    let start = || {
        let board = BoardConfig::PICO_21X21;
        let strip = CheckedStrip {
            max_ua: board.max_current_ma as u64 * 1000,
            channel_current_ua: board.channel_current_ua,
        };
        let store = CalibrationStore::new(RamNor::<{ 2 * 4096 }>::erased(), 0);
        let Ok(dev) = Device::new(board, 1, strip, NoTrigger, store) else {
            panic!("the reference board is valid");
        };
        dev
    };
    let mut dev = start();
    let mut sink = |_: &[u8]| {};
    let mut now = 0u64;
    let mut cur = Cursor {
        data: script,
        at: 0,
    };
    let mut wire = [0u8; MAX_ENCODED_FRAME_LEN + 8];
    while !cur.done() {
        match cur.byte() % 5 {
            0 => {
                let n = cur.byte() as usize;
                dev.receive(cur.bytes(n), now, &mut sink);
            }
            1 => {
                let list = endpoints();
                let key = list[cur.byte() as usize % list.len()].1;
                let seq = u16::from_le_bytes([cur.byte(), cur.byte()]) as u32;
                let n = cur.byte() as usize;
                let len = frame(key, seq, cur.bytes(n), &mut wire);
                dev.receive(&wire[..len], now, &mut sink);
            }
            2 => {
                let list = endpoints();
                let (path, key, _) = list[cur.byte() as usize % list.len()];
                let n = cur.byte() as usize;
                let raw = cur.bytes(n);
                let mut body = [0u8; MAX_FRAME_LEN];
                if let Some(m) = valid_body(path, raw, &mut body) {
                    let len = frame(key, 7, &body[..m], &mut wire);
                    dev.receive(&wire[..len], now, &mut sink);
                }
            }
            3 => {
                let edge = if cur.byte() & 1 == 0 {
                    Edge::Rising
                } else {
                    Edge::Falling
                };
                let back = cur.byte() as u64;
                dev.trigger_edge(edge, now.saturating_sub(back), now, &mut sink);
            }
            _ => {
                let dt = u16::from_le_bytes([cur.byte(), cur.byte()]) as u64 * 16;
                now += dt;
                dev.poll(now, &mut sink);
            }
        }
        let (lit_ma, limit_ma) = (dev.current_ma(), dev.budget().limit_ma);
        assert!(
            lit_ma <= limit_ma,
            "{lit_ma} mA lit over a budget of {limit_ma} mA"
        );
        if dev.bootsel_requested() {
            assert_eq!(
                lit_ma, 0,
                "{lit_ma} mA still lit when restarting in BOOTSEL"
            );
            dev = start();
        }
    }

    // Whatever came before, a delimiter then a valid request gets its answer.
    answers_a_ping(&mut dev, now);
}

/// A delimiter then a ping gets its answer, whatever `dev` was sent before.
fn answers_a_ping<S: LedStrip, F: embedded_storage::nor_flash::NorFlash>(
    dev: &mut Device<S, NoTrigger, F>,
    now: u64,
) {
    let mut wire = [0u8; MAX_ENCODED_FRAME_LEN + 8];
    let mut answered = false;
    let mut rx = FrameReceiver::new();
    let mut check = |bytes: &[u8]| {
        for &b in bytes {
            if let Feed::Frame(f) = rx.feed(b) {
                if let Some((hdr, body)) = VarHeader::take_from_slice(f) {
                    answered |= hdr.key == VarKey::Key8(PingEndpoint::RESP_KEY)
                        && hdr.seq_no == VarSeq::Seq4(0xF00D)
                        && body == [0xEF, 0xE0, 0x03];
                }
            }
        }
    };
    let len = frame(
        PingEndpoint::REQ_KEY,
        0xF00D,
        &[0xEF, 0xE0, 0x03],
        &mut wire,
    );
    dev.receive(&[0], now, &mut check);
    dev.receive(&wire[..len], now, &mut check);
    assert!(
        answered,
        "the controller did not answer a ping after the script"
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The strip's check can fail: a frame over the rating is caught.
    #[test]
    #[should_panic(expected = "reached the strip")]
    fn a_frame_over_the_rating_is_caught() {
        let mut strip = CheckedStrip {
            max_ua: 1_000,
            channel_current_ua: 20_000,
        };
        strip.write(&[RGB8::new(255, 255, 255)], 1, &[1]);
    }

    /// Valid requests built from the fuzzer's bytes light what they say.
    #[test]
    fn a_script_of_valid_requests_runs() {
        // SetLed (10, 10) white, then time.
        run(&[2, 4, 5, 10, 10, 255, 255, 255, 4, 0x10, 0x27]);
        // Garbage, half a frame, then the final ping.
        run(&[0, 6, 1, 2, 3, 0, 9, 9, 1, 3, 1, 0, 200]);
    }
}
