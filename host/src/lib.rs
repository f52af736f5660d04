//! # fpm-host
//!
//! The host side of the fpm microscope: the LED controller client and the `fpm`
//! command. Later parts (optics, calibration, reconstruction, acquisition) join here.

pub mod cli;
pub mod controller;
pub mod emulator_process;
