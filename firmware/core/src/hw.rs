//! The hardware the controller logic drives. Each trait is one concern, small enough
//! that an embassy driver or an emulator implements it in a few lines.

use smart_leds::RGB8;

/// The WS2812 chain, possibly split into several data lanes. Drivers also implement
/// smart-leds' `SmartLedsWrite` (a whole-chain write); this is the partial one the
/// controller uses.
pub trait LedStrip {
    /// Shift LED data out. `pixels` is the whole chain in chain order, exactly as it
    /// is to be shifted out (gamma and brightness applied); lane `k` carries
    /// `pixels[k * lane_len ..]` and must shift out its first `shift[k]` LEDs (0 =
    /// leave that lane alone). LEDs past the shifted ones keep their colour, which is
    /// what makes partial updates fast.
    fn write(&mut self, pixels: &[RGB8], lane_len: usize, shift: &[u16]);

    /// Whether `write` only queues the data and the shift happens later (a DMA task
    /// that runs when the shell's main loop yields). The shell then reports when the
    /// LEDs have latched with [`crate::Device::strip_latched`], and a capture sequence
    /// waits for that report before it settles and triggers the camera, instead of
    /// trusting the shift-time model. Strips that shift inside `write` keep `false`.
    fn latches_later(&self) -> bool {
        false
    }
}

/// The whole-chain write of smart-leds' `SmartLedsWrite`, for drivers to implement
/// it with: the colours from `colors` in chain order (as many as the chain holds; the
/// rest are off), every lane shifted out in full.
pub fn write_whole_chain<S: LedStrip + ?Sized, I: Into<RGB8>>(
    strip: &mut S,
    colors: impl IntoIterator<Item = I>,
    led_count: usize,
    lanes: usize,
) {
    let n = led_count.min(fpm_protocol::limits::MAX_LEDS);
    let mut pixels = [RGB8::default(); fpm_protocol::limits::MAX_LEDS];
    for (px, c) in pixels[..n].iter_mut().zip(colors) {
        *px = c.into();
    }
    let lanes = lanes.clamp(1, crate::chain::MAX_LANES);
    let lane_len = n.div_ceil(lanes);
    let mut shift = [0u16; crate::chain::MAX_LANES];
    for (lane, s) in shift[..lanes].iter_mut().enumerate() {
        *s = n.saturating_sub(lane * lane_len).min(lane_len) as u16;
    }
    strip.write(&pixels[..n], lane_len, &shift[..lanes]);
}

/// A shifted-out colour as the wire's colour type.
pub const fn to_rgb(p: RGB8) -> fpm_protocol::Rgb {
    fpm_protocol::Rgb::new(p.r, p.g, p.b)
}

/// The camera trigger output line.
pub trait TriggerOut {
    /// Drive the line to `high`.
    fn set_level(&mut self, high: bool);
}

/// Where outgoing frames go: each call gets one complete COBS frame including its
/// terminating zero.
pub trait FrameSink {
    /// Send one encoded frame.
    fn send(&mut self, encoded: &[u8]);
}

impl<F: FnMut(&[u8])> FrameSink for F {
    fn send(&mut self, encoded: &[u8]) {
        self(encoded)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::vec::Vec;

    #[derive(Default)]
    struct Recorder {
        writes: Vec<(Vec<RGB8>, usize, Vec<u16>)>,
    }

    impl LedStrip for Recorder {
        fn write(&mut self, pixels: &[RGB8], lane_len: usize, shift: &[u16]) {
            self.writes
                .push((pixels.to_vec(), lane_len, shift.to_vec()));
        }
    }

    #[test]
    fn a_whole_chain_write_shifts_every_lane_in_full() {
        for (lanes, lane_len, shift) in [
            (1, 441, vec![441]),
            (2, 221, vec![221, 220]),
            (4, 111, vec![111, 111, 111, 108]),
        ] {
            let mut strip = Recorder::default();
            // Fewer colours than LEDs: the rest are off.
            write_whole_chain(&mut strip, [RGB8::new(1, 2, 3); 10], 441, lanes);
            let (pixels, len, s) = &strip.writes[0];
            assert_eq!((pixels.len(), *len, s), (441, lane_len, &shift));
            assert_eq!(pixels[9], RGB8::new(1, 2, 3));
            assert_eq!(pixels[10], RGB8::default());
        }
    }
}
