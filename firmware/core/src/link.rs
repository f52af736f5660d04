//! Framing on the byte stream: COBS frames terminated by a zero byte.
//!
//! The receiver keeps at most [`MAX_ENCODED_FRAME_LEN`] bytes. A frame that grows past
//! that is dropped whole: everything up to its terminating zero is skipped, so the tail
//! of an oversized frame is never mistaken for a new one.

use fpm_protocol::limits::{MAX_ENCODED_FRAME_LEN, MAX_FRAME_LEN};

/// What feeding one byte produced.
#[derive(Debug, PartialEq, Eq)]
pub enum Feed<'a> {
    /// Frame still incomplete.
    Pending,
    /// A complete, decoded frame.
    Frame(&'a [u8]),
    /// A frame ended but was too long or not valid COBS; it was dropped.
    Dropped,
}

/// Accumulates bytes into decoded frames, with bounded memory.
pub struct FrameReceiver {
    buf: [u8; MAX_ENCODED_FRAME_LEN],
    len: usize,
    overflowed: bool,
}

impl Default for FrameReceiver {
    fn default() -> Self {
        Self::new()
    }
}

impl FrameReceiver {
    /// An empty receiver.
    pub const fn new() -> Self {
        Self {
            buf: [0; MAX_ENCODED_FRAME_LEN],
            len: 0,
            overflowed: false,
        }
    }

    /// Feed one byte.
    pub fn feed(&mut self, byte: u8) -> Feed<'_> {
        if byte != 0 {
            if self.len < self.buf.len() {
                self.buf[self.len] = byte;
                self.len += 1;
            } else {
                self.overflowed = true;
            }
            return Feed::Pending;
        }
        let len = core::mem::take(&mut self.len);
        if core::mem::take(&mut self.overflowed) {
            return Feed::Dropped;
        }
        if len == 0 {
            // Back-to-back delimiters: an empty frame, used by hosts to resynchronise.
            return Feed::Pending;
        }
        match cobs::decode_in_place(&mut self.buf[..len]) {
            Ok(n) if n > 0 && n <= MAX_FRAME_LEN => Feed::Frame(&self.buf[..n]),
            _ => Feed::Dropped,
        }
    }

    /// Bytes of an unfinished frame held now (for tests of bounded memory).
    pub fn pending_len(&self) -> usize {
        self.len
    }
}

/// Encode `frame` as COBS with a terminating zero into `out`; returns the used prefix,
/// or `None` if `out` is too small.
pub fn encode<'a>(frame: &[u8], out: &'a mut [u8]) -> Option<&'a [u8]> {
    if out.len() < cobs::max_encoding_length(frame.len()) + 1 {
        return None;
    }
    let n = cobs::try_encode(frame, out).ok()?;
    *out.get_mut(n)? = 0;
    out.get(..n + 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frames(rx: &mut FrameReceiver, bytes: &[u8]) -> (std::vec::Vec<std::vec::Vec<u8>>, usize) {
        let mut out = std::vec::Vec::new();
        let mut dropped = 0;
        for &b in bytes {
            match rx.feed(b) {
                Feed::Frame(f) => out.push(f.to_vec()),
                Feed::Dropped => dropped += 1,
                Feed::Pending => {}
            }
        }
        (out, dropped)
    }

    #[test]
    fn round_trip_with_zeros_inside() {
        let msg = [0u8, 1, 0, 0, 255, 0, 7];
        let mut enc = [0u8; 32];
        let wire = encode(&msg, &mut enc).unwrap().to_vec();
        assert_eq!(*wire.last().unwrap(), 0);
        assert_eq!(wire.iter().filter(|&&b| b == 0).count(), 1);
        let mut rx = FrameReceiver::new();
        let (got, dropped) = frames(&mut rx, &wire);
        assert_eq!(got, vec![msg.to_vec()]);
        assert_eq!(dropped, 0);
    }

    #[test]
    fn oversized_frame_is_dropped_whole_and_the_next_one_survives() {
        let mut rx = FrameReceiver::new();
        let mut bytes = vec![1u8; MAX_ENCODED_FRAME_LEN * 3];
        bytes.push(0);
        let mut enc = [0u8; 16];
        bytes.extend_from_slice(encode(&[9, 9], &mut enc).unwrap());
        let (got, dropped) = frames(&mut rx, &bytes);
        assert_eq!(dropped, 1);
        assert_eq!(got, vec![vec![9, 9]]);
        assert!(rx.pending_len() <= MAX_ENCODED_FRAME_LEN);
    }

    #[test]
    fn decoded_frame_longer_than_the_limit_is_dropped() {
        let big = vec![5u8; MAX_FRAME_LEN + 1];
        let mut enc = vec![0u8; MAX_ENCODED_FRAME_LEN + 8];
        let wire = encode(&big, &mut enc).unwrap().to_vec();
        let mut rx = FrameReceiver::new();
        let (got, dropped) = frames(&mut rx, &wire);
        assert!(got.is_empty());
        assert_eq!(dropped, 1);
    }

    #[test]
    fn invalid_cobs_is_dropped() {
        let mut rx = FrameReceiver::new();
        // code byte 5 promises 4 more bytes before the delimiter
        let (got, dropped) = frames(&mut rx, &[5, 1, 0]);
        assert!(got.is_empty());
        assert_eq!(dropped, 1);
    }

    #[test]
    fn encode_refuses_a_small_buffer() {
        let mut out = [0u8; 3];
        assert!(encode(&[1, 2, 3], &mut out).is_none());
    }
}
