//! # fpm-emulator: the LED controller without the board
//!
//! Runs the real firmware logic ([`fpm_firmware::Device`]) on the host behind a
//! pseudo-terminal, so the host's serial client — or any terminal program — talks to it
//! exactly as to the RP2040 over USB. What the board would do physically is emulated at
//! the hardware-trait boundary:
//! * the WS2812 chain ([`hardware::EmulatedStrip`]): only the shifted prefix of each lane
//!   changes, as on real LEDs, and every change is logged as grid positions;
//! * the trigger output, and an emulated camera on the trigger input that answers each
//!   trigger pulse with an exposure-active pulse ([`hardware::Camera`]);
//! * the flash that keeps the board's calibration ([`flash::EmulatedFlash`], a NOR
//!   model with the chip's erase/program rules), in a file with `--flash`;
//! * the clock: the device sees monotonic µs since the emulator started, and the loop
//!   wakes at the deadlines the device asks for.
//!
//! With `--firmware FILE.uf2` it runs the real firmware binary in an emulated RP2040
//! instead (see `firmware`), behind the same terminal.

mod args;
mod firmware;
pub mod flash;
pub mod hardware;
pub mod pty;
mod run;

pub use args::EmulatorOptions;
pub use run::run;
