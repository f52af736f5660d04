//! # fpm LED controller firmware (Raspberry Pi Pico, RP2040)
//!
//! A thin embassy shell around [`fpm_firmware::Device`], which holds all the logic.
//! One task each: the USB device, the LED chain (PIO + DMA), the camera's trigger
//! input; the main task feeds the device bytes, edges and time, and sends what it
//! answers. Pins, chain wiring and the current budget are in [`board`].
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
mod board;
#[cfg(target_os = "none")]
mod firmware;
#[cfg(target_os = "none")]
mod link;
#[cfg(target_os = "none")]
mod triggers;
#[cfg(target_os = "none")]
mod ws2812;

/// On the host this crate is an empty program, so workspace-wide builds and tests
/// need no embedded toolchain; the firmware is built with
/// `cargo build --release --target thumbv6m-none-eabi -p fpm-firmware-rp2040`.
#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("fpm-led-controller runs on the RP2040: build it with --target thumbv6m-none-eabi");
}
