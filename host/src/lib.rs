//! # fpm-host
//!
//! The host side of the fpm microscope: the LED controller client and the `fpm`
//! command. Later parts (optics, calibration, reconstruction, acquisition) join here.

pub mod calibration;
pub mod cli;
pub mod controller;
pub mod dataset;
pub mod emulator_process;
pub mod plot;
pub mod reconstruction;
