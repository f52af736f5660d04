//! Identity and state of a controller: what board it drives and how.

use heapless::String;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

use crate::limits::MAX_NAME_LEN;
use crate::{BudgetConfig, ProtocolVersion, SequenceStatus};

/// One LED, addressed by its place in the grid (0-based, row 0 at the top of the
/// board as seen from the sample, i.e. along −y; see docs/dataset.md §1). The one LED
/// index of the whole stack: the wire, the firmware, datasets, calibration and
/// reconstruction all use it.
///
/// Serialised as the pair `[row, col]` in every format: on the wire (postcard) that is
/// byte for byte what a struct of the two fields is, and in files it is the
/// `led = [10, 10]` of a dataset.
#[derive(Schema, Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LedIndex {
    /// Grid row.
    pub row: u8,
    /// Grid column.
    pub col: u8,
}

impl LedIndex {
    /// The LED at (`row`, `col`).
    pub const fn new(row: u8, col: u8) -> Self {
        Self { row, col }
    }

    /// Grid row as an index.
    pub const fn r(self) -> usize {
        self.row as usize
    }

    /// Grid column as an index.
    pub const fn c(self) -> usize {
        self.col as usize
    }
}

impl core::fmt::Display for LedIndex {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "({}, {})", self.row, self.col)
    }
}

impl Serialize for LedIndex {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        (self.row, self.col).serialize(serializer)
    }
}

impl<'de> Deserialize<'de> for LedIndex {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let (row, col) = <(u8, u8)>::deserialize(deserializer)?;
        Ok(Self { row, col })
    }
}

/// Where the first LED of the data chain sits on the grid.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ChainStart {
    /// Row 0, column 0.
    TopLeft,
    /// Row 0, last column.
    TopRight,
    /// Last row, column 0.
    BottomLeft,
    /// Last row, last column.
    BottomRight,
}

/// Whether the chain runs along rows or along columns first.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ChainMajor {
    /// The chain walks a whole row, then moves to the next row.
    Rows,
    /// The chain walks a whole column, then moves to the next column.
    Columns,
}

/// How the WS2812 data chain threads through the grid.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ChainOrder {
    /// Corner of the first LED.
    pub start: ChainStart,
    /// Direction of the first run.
    pub major: ChainMajor,
    /// Every other run reversed (the common zig-zag wiring of LED matrices).
    pub serpentine: bool,
}

/// Physical layout of the LED array, as compiled into the firmware's board config.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BoardGeometry {
    /// Grid rows.
    pub rows: u8,
    /// Grid columns.
    pub cols: u8,
    /// LED pitch in µm.
    pub pitch_um: u32,
    /// Nominal distance from the LED plane to the sample in µm (used by on-device
    /// NA patterns; the host calibrates the real value).
    pub height_um: u32,
    /// The LED nominally on the optical axis.
    pub center: LedIndex,
    /// Data-chain wiring.
    pub chain: ChainOrder,
    /// Number of parallel data lanes the chain is split into (1 = one data line).
    pub lanes: u8,
}

impl BoardGeometry {
    /// Number of LEDs on the grid.
    pub const fn led_count(&self) -> u16 {
        self.rows as u16 * self.cols as u16
    }

    /// Whether `led` lies on the grid.
    pub const fn contains(&self, led: LedIndex) -> bool {
        led.row < self.rows && led.col < self.cols
    }
}

/// Nominal peak wavelength of each colour channel in nm (0 = channel absent).
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ColorChannels {
    /// Red.
    pub red_nm: u16,
    /// Green.
    pub green_nm: u16,
    /// Blue.
    pub blue_nm: u16,
}

/// Version of the firmware build.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FirmwareVersion {
    /// Semver major.
    pub major: u16,
    /// Semver minor.
    pub minor: u16,
    /// Semver patch.
    pub patch: u16,
}

impl core::fmt::Display for FirmwareVersion {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "{}.{}.{}", self.major, self.minor, self.patch)
    }
}

/// What a device accepts; always within [`crate::limits`].
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Limits {
    /// Largest frame (header + body, before COBS) the device accepts.
    pub max_frame_len: u16,
    /// Most LEDs in one list request.
    pub max_leds_per_list: u16,
    /// Most steps in one sequence.
    pub max_sequence_steps: u16,
    /// Most steps in one upload chunk.
    pub max_steps_per_chunk: u16,
    /// Highest current budget the board's supply allows, in mA; no request can raise
    /// the budget above it.
    pub max_current_ma: u32,
    /// Current one colour channel of one LED draws at full value, in µA.
    pub channel_current_ua: u32,
    /// Time to shift one LED's data out of one lane, in ns (24 bits at 800 kHz = 30 µs).
    pub led_shift_ns: u32,
    /// Latch (reset) gap after a chain update, in µs.
    pub latch_us: u32,
}

/// Camera trigger lines the board wires up.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TriggerLines {
    /// Trigger outputs (to the camera's trigger input).
    pub outputs: u8,
    /// Trigger inputs (from the camera's exposure-active / strobe output).
    pub inputs: u8,
}

/// Response of [`crate::InfoEndpoint`]: everything a host needs to drive the board.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DeviceInfo {
    /// Wire contract the firmware speaks.
    pub protocol: ProtocolVersion,
    /// Firmware build.
    pub firmware: FirmwareVersion,
    /// Human-readable board name from the board config.
    pub board: String<MAX_NAME_LEN>,
    /// Serial number or emulator instance id.
    pub serial: u64,
    /// LED layout.
    pub geometry: BoardGeometry,
    /// Colour channels.
    pub channels: ColorChannels,
    /// Trigger lines.
    pub triggers: TriggerLines,
    /// What the device accepts.
    pub limits: Limits,
}

/// Counters of what arrived on the link, for diagnosing a noisy or mismatched host.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LinkStats {
    /// Frames decoded and dispatched.
    pub frames_ok: u32,
    /// Frames dropped before dispatch: bad COBS, too long, or a header too short.
    pub frames_dropped: u32,
    /// Requests whose key matched no endpoint (answered with `WireError::UnknownKey`).
    pub unknown_keys: u32,
    /// Requests whose body did not decode (answered with `WireError::DeserFailed`).
    pub decode_errors: u32,
}

/// Response of [`crate::StatusEndpoint`]: the device's state right now.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DeviceStatus {
    /// Device clock, µs since boot.
    pub now_us: u64,
    /// LEDs currently lit (any channel non-zero after brightness).
    pub leds_on: u16,
    /// Current the lit LEDs draw, in mA (channel current only).
    pub current_ma: u32,
    /// Global brightness (0–255) applied to every colour.
    pub brightness: u8,
    /// Current budget in force.
    pub budget: BudgetConfig,
    /// Capture sequence state.
    pub sequence: SequenceStatus,
    /// Link counters.
    pub link: LinkStats,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The pair form keeps the wire bytes of the two-field struct the firmware has
    /// always sent: row, then column, one byte each.
    #[test]
    fn an_led_index_is_two_bytes_on_the_wire_and_round_trips() {
        let led = LedIndex::new(10, 3);
        let bytes = postcard::to_allocvec(&led).unwrap();
        assert_eq!(bytes, [10, 3]);
        assert_eq!(postcard::from_bytes::<LedIndex>(&bytes).unwrap(), led);
    }
}
