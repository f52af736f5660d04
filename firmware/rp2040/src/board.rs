//! The board, in one place: which pins do what, how the LED chain is wired, and how
//! much current the LED supply can give. Change this file for another board.
//!
//! Raspberry Pi Pico defaults:
//!
//! | what | pin | notes |
//! |---|---|---|
//! | WS2812 data, lane 0 | GP16 | through a 3.3 V → 5 V level shifter (74AHCT125) |
//! | WS2812 data, lanes 1–3 | GP17, GP18, GP19 | only with `LANES` > 1 |
//! | camera trigger out | GP14 | to the camera's trigger input (opto-isolated on most cameras) |
//! | camera trigger in | GP15 | from the camera's exposure/strobe output; internal pull-up, so an open-collector output works |
//! | status LED | GP25 | on while a host is connected |
//!
//! The chain is one serpentine line starting at the top-left LED (row 0, col 0) as
//! seen from the sample, 2.5 mm pitch, 92 mm below the sample, fed by a 5 V 4 A supply.

use fpm_firmware::BoardConfig;

/// The board description the controller logic works with.
pub const BOARD: BoardConfig = BoardConfig::PICO_21X21;

/// Data lanes actually wired (1 to 4), one PIO state machine each. Must equal
/// `BOARD.geometry.lanes`.
pub const LANES: usize = BOARD.geometry.lanes as usize;

/// USB identity. 0x1209/0x0001 is pid.codes' test PID: fine for development, register a
/// PID before shipping boards.
pub const USB_VID: u16 = 0x1209;
/// USB product id.
pub const USB_PID: u16 = 0x0001;

const _: () = assert!(LANES >= 1 && LANES <= fpm_firmware::chain::MAX_LANES);
