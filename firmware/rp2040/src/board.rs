//! The board, in one place: which pins do what, how the LED chain is wired, and how
//! much current the LED supply can give. Change this file for another board.
//!
//! Raspberry Pi Pico defaults:
//!
//! | what | pin | notes |
//! |---|---|---|
//! | WS2812 data, lane 0 | GP16 | through a 3.3 V → 5 V level shifter (74AHCT125) |
//! | WS2812 data, lanes 1–3 | GP17, GP18, GP19 | only on boards wired as 2 or 4 lanes |
//! | camera trigger out | GP14 | to the camera's trigger input (opto-isolated on most cameras) |
//! | camera trigger in | GP15 | from the camera's exposure/strobe output; internal pull-up, so an open-collector output works |
//! | status LED | GP25 | on while a host is connected |
//!
//! The chain is one serpentine line starting at the top-left LED (row 0, col 0) as
//! seen from the sample, 2.5 mm pitch, 92 mm below the sample, fed by a 5 V 4 A supply.
//! It may be cut into 2 or 4 consecutive runs, each fed by its own data pin, to shift
//! the whole array 2 or 4 times faster: one image is built per wiring
//! (`fpm-led-controller`, `fpm-led-controller-2lanes`, `fpm-led-controller-4lanes`).

use fpm_firmware::BoardConfig;

/// The board description the controller logic works with, for a chain wired as
/// `lanes` data lanes (1 to 4, one PIO state machine each, on GP16 onwards).
pub const fn board(lanes: u8) -> BoardConfig {
    let mut board = BoardConfig::PICO_21X21;
    board.geometry.lanes = lanes;
    board
}

/// USB identity: part of the wire contract, since hosts find boards by it.
pub use fpm_protocol::{USB_PID, USB_VID};
