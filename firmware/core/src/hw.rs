//! The hardware the controller logic drives. Each trait is one concern, small enough
//! that an embassy driver or an emulator implements it in a few lines.

use fpm_protocol::Rgb;

/// The WS2812 chain, possibly split into several data lanes.
pub trait LedStrip {
    /// Shift LED data out. `pixels` is the whole chain in chain order with brightness
    /// applied; lane `k` carries `pixels[k * lane_len ..]` and must shift out its first
    /// `shift[k]` LEDs (0 = leave that lane alone). LEDs past the shifted ones keep
    /// their colour, which is what makes partial updates fast.
    fn write(&mut self, pixels: &[Rgb], lane_len: usize, shift: &[u16]);

    /// Whether `write` only queues the data and the shift happens later (a DMA task
    /// that runs when the shell's main loop yields). The shell then reports when the
    /// LEDs have latched with [`crate::Device::strip_latched`], and a capture sequence
    /// waits for that report before it settles and triggers the camera, instead of
    /// trusting the shift-time model. Strips that shift inside `write` keep `false`.
    fn latches_later(&self) -> bool {
        false
    }
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
