//! The board configuration: everything about the physical controller in one place.

use fpm_protocol::{
    limits, BoardGeometry, ChainMajor, ChainOrder, ChainStart, ColorChannels, FirmwareVersion,
    LedIndex, Limits, TriggerLines,
};

/// Static description of a controller board. The RP2040 firmware compiles one in; the
/// emulator builds one from its command line.
#[derive(Debug, Clone, PartialEq)]
pub struct BoardConfig {
    /// Name reported in `DeviceInfo`.
    pub name: &'static str,
    /// LED layout and wiring.
    pub geometry: BoardGeometry,
    /// Colour channel wavelengths.
    pub channels: ColorChannels,
    /// Trigger lines wired up.
    pub triggers: TriggerLines,
    /// The supply's current limit for the LEDs, mA: no request can exceed it.
    pub max_current_ma: u32,
    /// Current of one colour channel of one LED at full value, µA.
    pub channel_current_ua: u32,
    /// Time to shift one LED's 24 bits out of one lane, ns.
    pub led_shift_ns: u32,
    /// Latch (reset) gap after a chain update, µs.
    pub latch_us: u32,
}

/// This firmware's version, from the crate version.
pub const FIRMWARE_VERSION: FirmwareVersion = FirmwareVersion {
    major: parse_u16(env!("CARGO_PKG_VERSION_MAJOR")),
    minor: parse_u16(env!("CARGO_PKG_VERSION_MINOR")),
    patch: parse_u16(env!("CARGO_PKG_VERSION_PATCH")),
};

const fn parse_u16(s: &str) -> u16 {
    let bytes = s.as_bytes();
    let mut value: u16 = 0;
    let mut i = 0;
    while i < bytes.len() {
        value = value * 10 + (bytes[i] - b'0') as u16;
        i += 1;
    }
    value
}

impl BoardConfig {
    /// The reference board: a Raspberry Pi Pico driving a 21×21 WS2812 matrix with
    /// 2.5 mm pitch on one serpentine data line, 92 mm below the sample, with a 4 A
    /// 5 V supply for the LEDs and one trigger line each way.
    pub const PICO_21X21: BoardConfig = BoardConfig {
        name: "fpm-pico-21x21",
        geometry: BoardGeometry {
            rows: 21,
            cols: 21,
            pitch_um: 2_500,
            height_um: 92_000,
            center: LedIndex::new(10, 10),
            chain: ChainOrder {
                start: ChainStart::TopLeft,
                major: ChainMajor::Rows,
                serpentine: true,
            },
            lanes: 1,
        },
        channels: ColorChannels {
            red_nm: 630,
            green_nm: 525,
            blue_nm: 470,
        },
        triggers: TriggerLines {
            outputs: 1,
            inputs: 1,
        },
        max_current_ma: 4_000,
        channel_current_ua: 20_000,
        led_shift_ns: 30_000,
        latch_us: 280,
    };

    /// Check that the configuration fits the protocol's and the firmware's limits.
    pub fn validate(&self) -> Result<(), &'static str> {
        let g = &self.geometry;
        if g.rows == 0 || g.cols == 0 {
            return Err("board has no LEDs");
        }
        if g.led_count() as usize > limits::MAX_LEDS {
            return Err("board has more LEDs than the firmware's frame buffer");
        }
        if !g.contains(g.center) {
            return Err("centre LED is not on the board");
        }
        if g.lanes == 0 || g.lanes as usize > crate::chain::MAX_LANES {
            return Err("lane count out of range");
        }
        if g.pitch_um == 0 || g.height_um == 0 {
            return Err("pitch and height must be positive");
        }
        if self.max_current_ma == 0 || self.channel_current_ua == 0 {
            return Err("current limits must be positive");
        }
        Ok(())
    }

    /// The limits this board advertises.
    pub fn limits(&self) -> Limits {
        Limits {
            max_frame_len: limits::MAX_FRAME_LEN as u16,
            max_leds_per_list: limits::MAX_LEDS_PER_LIST as u16,
            max_sequence_steps: limits::MAX_SEQUENCE_STEPS as u16,
            max_steps_per_chunk: limits::MAX_STEPS_PER_CHUNK as u16,
            max_current_ma: self.max_current_ma,
            channel_current_ua: self.channel_current_ua,
            led_shift_ns: self.led_shift_ns,
            latch_us: self.latch_us,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reference_board_is_valid() {
        assert_eq!(BoardConfig::PICO_21X21.validate(), Ok(()));
    }

    #[test]
    fn version_comes_from_the_crate() {
        let v = FIRMWARE_VERSION;
        let text = format!("{}.{}.{}", v.major, v.minor, v.patch);
        assert_eq!(text, env!("CARGO_PKG_VERSION"));
    }

    #[test]
    fn invalid_boards_are_rejected() {
        let mut b = BoardConfig::PICO_21X21;
        b.geometry.center = LedIndex::new(21, 0);
        assert!(b.validate().is_err());
        let mut b = BoardConfig::PICO_21X21;
        b.geometry.rows = 40;
        b.geometry.cols = 40;
        assert!(b.validate().is_err());
        let mut b = BoardConfig::PICO_21X21;
        b.geometry.lanes = 0;
        assert!(b.validate().is_err());
    }
}
