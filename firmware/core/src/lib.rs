//! # fpm-firmware: the LED controller's logic
//!
//! Everything the fpm LED controller does that does not touch a pin: decoding requests,
//! computing patterns from the board geometry, mapping the grid onto the WS2812 data
//! chain, keeping the current budget, and running capture sequences against the
//! device clock. It is `no_std`, allocation-free and never panics on input from the
//! link, so the same code runs on the RP2040 and, unchanged, inside the host emulator.
//!
//! The shell around it (embassy on the RP2040, a pseudo-terminal on the host) does
//! three things:
//! 1. feeds received bytes to [`Device::receive`] and writes what the [`FrameSink`]
//!    gets back to the link;
//! 2. reports camera trigger-in edges with [`Device::trigger_edge`];
//! 3. calls [`Device::poll`] when the deadline it returned has passed.
//!
//! Time is always passed in (µs since boot): the core owns no clock, so its timing is
//! exact and testable.
#![no_std]
#![cfg_attr(
    not(test),
    deny(clippy::unwrap_used, clippy::expect_used, clippy::panic)
)]
#![warn(missing_docs)]

#[cfg(test)]
#[macro_use]
extern crate std;

pub mod board;
pub mod budget;
pub mod chain;
mod device;
#[cfg(any(test, feature = "fuzzing"))]
#[allow(clippy::panic)] // panicking is how it reports a broken invariant to the fuzzer
pub mod fuzz_script;
pub mod hw;
pub mod led_sets;
pub mod leds;
pub mod link;
pub mod patterns;
pub mod sequence;
pub mod storage;

pub use board::BoardConfig;
pub use device::Device;
pub use hw::{FrameSink, LedStrip, TriggerOut};
pub use smart_leds::{SmartLedsWrite, RGB8};
pub use storage::{CalibrationStore, RamNor};
