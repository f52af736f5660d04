//! The emulated hardware: the LED chain, the trigger line and a camera.

use std::cell::RefCell;
use std::cmp::Reverse;
use std::collections::BinaryHeap;

use fpm_firmware::chain::led_at;
use fpm_firmware::{LedStrip, SmartLedsWrite, TriggerOut, RGB8};
use fpm_protocol::{BoardGeometry, Edge, Rgb};

/// A WS2812 chain: each lane latches only the LEDs shifted into it; the rest keep their
/// colour. Every change is logged with grid positions.
pub struct EmulatedStrip {
    geometry: BoardGeometry,
    pixels: Vec<Rgb>,
    writes: u64,
}

impl EmulatedStrip {
    /// A dark chain for `geometry`.
    pub fn new(geometry: BoardGeometry) -> Self {
        Self {
            geometry,
            pixels: vec![Rgb::OFF; geometry.led_count() as usize],
            writes: 0,
        }
    }

    /// What every LED shows now, in chain order.
    pub fn pixels(&self) -> &[Rgb] {
        &self.pixels
    }

    /// The board this strip was made for.
    pub fn geometry(&self) -> BoardGeometry {
        self.geometry
    }

    /// The LEDs shining now: (row, col, colour), at most `max`.
    pub fn lit(&self, max: usize) -> Vec<(u8, u8, Rgb)> {
        self.pixels
            .iter()
            .enumerate()
            .filter(|(_, p)| **p != Rgb::OFF)
            .filter_map(|(i, p)| led_at(&self.geometry, i as u16).map(|l| (l.row, l.col, *p)))
            .take(max)
            .collect()
    }

    /// Chain updates so far.
    pub fn writes(&self) -> u64 {
        self.writes
    }
}

/// A whole-chain write, as any smart-leds user would drive the chain.
impl SmartLedsWrite for EmulatedStrip {
    type Error = std::convert::Infallible;
    type Color = RGB8;

    fn write<T, I>(&mut self, colors: T) -> Result<(), Self::Error>
    where
        T: IntoIterator<Item = I>,
        I: Into<RGB8>,
    {
        let (count, lanes) = (self.pixels.len(), self.geometry.lanes as usize);
        fpm_firmware::hw::write_whole_chain(self, colors, count, lanes);
        Ok(())
    }
}

impl LedStrip for EmulatedStrip {
    fn write(&mut self, pixels: &[RGB8], lane_len: usize, shift: &[u16]) {
        for (lane, &n) in shift.iter().enumerate() {
            let start = lane * lane_len;
            let end = (start + n as usize)
                .min(pixels.len())
                .min(self.pixels.len());
            for (mine, &theirs) in self.pixels[start.min(end)..end]
                .iter_mut()
                .zip(&pixels[start.min(end)..end])
            {
                *mine = fpm_firmware::hw::to_rgb(theirs);
            }
        }
        self.writes += 1;
        // Listing what is lit walks the chain: skip it when nobody reads the log.
        if !tracing::enabled!(tracing::Level::INFO) {
            return;
        }
        tracing::info!("chain shifted {shift:?} LED(s) per lane");
        let lit: Vec<(usize, Rgb)> = self
            .pixels
            .iter()
            .enumerate()
            .filter(|(_, p)| !p.is_off())
            .map(|(i, p)| (i, *p))
            .collect();
        if lit.is_empty() {
            tracing::info!("LEDs: all off");
        } else if lit.len() <= 6 {
            let names: Vec<String> = lit
                .iter()
                .filter_map(|&(i, p)| {
                    let led = led_at(&self.geometry, i as u16)?;
                    Some(format!(
                        "({},{}) #{:02x}{:02x}{:02x}",
                        led.row, led.col, p.r, p.g, p.b
                    ))
                })
                .collect();
            tracing::info!("LEDs lit: {}", names.join(", "));
        } else {
            tracing::info!("LEDs lit: {} of {}", lit.len(), self.pixels.len());
        }
    }
}

/// The trigger output line: records level changes for the run loop to time-stamp.
#[derive(Default)]
pub struct EmulatedTrigger {
    level: bool,
    changes: RefCell<Vec<bool>>,
}

impl EmulatedTrigger {
    /// Level changes since the last call.
    pub fn take_changes(&self) -> Vec<bool> {
        std::mem::take(&mut *self.changes.borrow_mut())
    }

    /// The line's level now.
    pub fn level(&self) -> bool {
        self.level
    }
}

impl TriggerOut for EmulatedTrigger {
    fn set_level(&mut self, high: bool) {
        if high != self.level {
            self.level = high;
            self.changes.borrow_mut().push(high);
        }
    }
}

/// A camera on the trigger lines: a trigger pulse starts an exposure `latency_us` later;
/// its exposure-active output rises then and falls `exposure_us` after.
pub struct Camera {
    /// Trigger to exposure start, µs.
    pub latency_us: u64,
    /// Exposure time, µs.
    pub exposure_us: u64,
    pending: BinaryHeap<Reverse<(u64, bool)>>,
}

impl Camera {
    /// A camera with the given timing, triggered by a rising edge.
    pub fn new(latency_us: u64, exposure_us: u64) -> Self {
        Self {
            latency_us,
            exposure_us,
            pending: BinaryHeap::new(),
        }
    }

    /// The trigger line changed to `level` at `at`; the camera triggers on the edge to
    /// `active_level`.
    pub fn trigger_line(&mut self, level: bool, at: u64, active_level: bool) {
        if level == active_level {
            let start = at + self.latency_us;
            self.pending.push(Reverse((start, true)));
            self.pending
                .push(Reverse((start + self.exposure_us, false)));
        }
    }

    /// When the next edge is due.
    pub fn next_edge_at(&self) -> Option<u64> {
        self.pending.peek().map(|Reverse((t, _))| *t)
    }

    /// The next edge if it is due at `now`.
    pub fn due(&mut self, now: u64) -> Option<(u64, Edge)> {
        let Reverse((t, rising)) = *self.pending.peek()?;
        if t > now {
            return None;
        }
        self.pending.pop();
        Some((t, if rising { Edge::Rising } else { Edge::Falling }))
    }
}
