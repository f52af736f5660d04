//! # fpm-rig
//!
//! The virtual FPM rig, for the demo and the tests: what stands in for the parts that
//! cannot exist on a machine without hardware, driven through the same interfaces as
//! the real ones.
//!
//! * [`camera`]: the virtual camera — watches the rig's trigger pulses and stage
//!   (`fpm-rig-bus`), renders each exposure with the full wave-optics model for a
//!   hidden, misplaced LED array, and publishes frames on the iceoryx2 frame contract
//!   like any camera driver;
//! * [`stage`]: the virtual focus stage, an `fpm_acquire::FocusStage`;
//! * [`boot_rom`]: the RP2040 boot ROM's PICOBOOT interface with its flash, which
//!   `fpm device flash` writes a board through once it is in BOOTSEL;
//! * [`process`]: rig processes (the controller emulator, the virtual camera) started
//!   as children and stopped on drop, shared by the demo, the benchmarks and the tests.

pub mod boot_rom;
pub mod camera;
pub mod demo;
pub mod process;
pub mod stage;
