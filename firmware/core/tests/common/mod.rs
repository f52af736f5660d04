//! Test fixtures for the controller logic: recording strip and trigger, and a
//! request helper that speaks the real wire format (postcard-rpc header + COBS).
#![allow(dead_code)]

use fpm_firmware::{BoardConfig, Device, LedStrip, TriggerOut, RGB8};
use fpm_protocol::{Rgb, WireError};
use postcard_rpc::header::{VarHeader, VarKey, VarSeq};
use postcard_rpc::standard_icd::ERROR_KEY;
use postcard_rpc::{Endpoint, Topic};
use serde::{de::DeserializeOwned, Serialize};

#[derive(Default)]
pub struct Strip {
    pub pixels: Vec<Rgb>,
    pub writes: Vec<Vec<u16>>,
    /// Behave like a DMA-driven strip: the shell reports the latch.
    pub latches_later: bool,
}

impl LedStrip for Strip {
    fn write(&mut self, pixels: &[RGB8], lane_len: usize, shift: &[u16]) {
        if self.pixels.len() != pixels.len() {
            self.pixels = vec![Rgb::OFF; pixels.len()];
        }
        // Emulate the physics: only shifted LEDs change.
        for (lane, &n) in shift.iter().enumerate() {
            let range = lane * lane_len..lane * lane_len + n as usize;
            for (mine, &theirs) in self.pixels[range.clone()].iter_mut().zip(&pixels[range]) {
                *mine = fpm_firmware::hw::to_rgb(theirs);
            }
        }
        self.writes.push(shift.to_vec());
    }

    fn latches_later(&self) -> bool {
        self.latches_later
    }
}

#[derive(Default)]
pub struct Trigger {
    pub levels: Vec<bool>,
}

impl TriggerOut for Trigger {
    fn set_level(&mut self, high: bool) {
        self.levels.push(high);
    }
}

/// Flash of the test board: the calibration store in its first two sectors.
pub type Flash = fpm_firmware::RamNor<{ 2 * 4096 }>;

pub type Dev = Device<Strip, Trigger, Flash>;

/// Decoded frames: header and body.
pub type Frames = Vec<(VarHeader, Vec<u8>)>;

pub fn device() -> Dev {
    Device::new(
        BoardConfig::PICO_21X21,
        42,
        Strip::default(),
        Trigger::default(),
        fpm_firmware::CalibrationStore::new(Flash::erased(), 0),
    )
    .unwrap()
}

/// Everything the device sent, decoded into (header, body) frames.
#[derive(Default)]
pub struct Wire {
    pub bytes: Vec<u8>,
}

impl Wire {
    pub fn frames(&mut self) -> Frames {
        let mut out = vec![];
        for chunk in self.bytes.split(|&b| b == 0) {
            if chunk.is_empty() {
                continue;
            }
            let raw = cobs::decode_vec(chunk).expect("device sends valid COBS");
            let (hdr, body) = VarHeader::take_from_slice(&raw).expect("device sends valid headers");
            out.push((hdr, body.to_vec()));
        }
        self.bytes.clear();
        out
    }
}

pub fn encode_request<E: Endpoint>(req: &E::Request, seq: u32) -> Vec<u8>
where
    E::Request: Serialize,
{
    let hdr = VarHeader {
        key: VarKey::Key8(E::REQ_KEY),
        seq_no: VarSeq::Seq4(seq),
    };
    let mut raw = hdr.write_to_vec();
    raw.extend(postcard::to_stdvec(req).unwrap());
    let mut wire = cobs::encode_vec(&raw);
    wire.push(0);
    wire
}

/// What a request got back.
#[derive(Debug)]
pub enum Reply<R> {
    Ok(R),
    Wire(WireError),
}

/// Send one request at `now`, return its reply and any topic messages sent meanwhile.
pub fn call<E: Endpoint>(dev: &mut Dev, req: &E::Request, now: u64) -> (Reply<E::Response>, Frames)
where
    E::Request: Serialize,
    E::Response: DeserializeOwned,
{
    let mut wire = Wire::default();
    let bytes = encode_request::<E>(req, 7);
    dev.receive(&bytes, now, &mut |b: &[u8]| wire.bytes.extend_from_slice(b));
    let mut reply = None;
    let mut others = vec![];
    for (hdr, body) in wire.frames() {
        if hdr.key == VarKey::Key8(E::RESP_KEY) && hdr.seq_no == VarSeq::Seq4(7) {
            reply = Some(Reply::Ok(
                postcard::from_bytes(&body).expect("reply decodes"),
            ));
        } else if hdr.key == VarKey::Key8(ERROR_KEY) {
            reply = Some(Reply::Wire(
                postcard::from_bytes(&body).expect("error decodes"),
            ));
        } else {
            others.push((hdr, body));
        }
    }
    (reply.expect("device answered"), others)
}

/// Shorthand: the typed reply of a request that must succeed at the wire level.
pub fn ok<E: Endpoint>(dev: &mut Dev, req: &E::Request, now: u64) -> E::Response
where
    E::Request: Serialize,
    E::Response: DeserializeOwned + std::fmt::Debug,
{
    match call::<E>(dev, req, now).0 {
        Reply::Ok(r) => r,
        Reply::Wire(e) => panic!("{} failed at the wire level: {e:?}", E::PATH),
    }
}

/// Decode the topic messages of type `T` among `frames`.
pub fn topics<T: Topic>(frames: &[(VarHeader, Vec<u8>)]) -> Vec<T::Message>
where
    T::Message: DeserializeOwned,
{
    frames
        .iter()
        .filter(|(h, _)| h.key == VarKey::Key8(T::TOPIC_KEY))
        .map(|(_, b)| postcard::from_bytes(b).expect("topic decodes"))
        .collect()
}

/// Run the device's clock from `from` until `until`, polling exactly at each deadline,
/// optionally injecting camera edges `camera_delay` after each trigger-out rising edge.
pub fn run_until(dev: &mut Dev, from: u64, until: u64) -> Frames {
    let mut wire = Wire::default();
    let mut now = from;
    let mut next = dev.poll(now, &mut |b: &[u8]| wire.bytes.extend_from_slice(b));
    while let Some(t) = next {
        if t > until {
            break;
        }
        now = t.max(now);
        next = dev.poll(now, &mut |b: &[u8]| wire.bytes.extend_from_slice(b));
    }
    wire.frames()
}
