//! # fpm-host
//!
//! The host side of the fpm microscope: the LED controller client and the `fpm`
//! command: datasets, calibration, reconstruction, and (with the emulator) the virtual
//! microscope.

pub mod acquire;
pub mod calibration;
pub mod cli;
pub mod controller;
pub mod dataset;
pub mod emulator_process;
pub mod plot;
pub mod reconstruction;
pub mod truth;
pub mod virtual_camera;
