//! # fpm LED controller firmware (Raspberry Pi Pico, RP2040)
//!
//! A thin embassy shell around [`fpm_firmware::Device`], which holds all the logic.
//! One task each: the USB device, the LED chain (PIO + DMA), the camera's trigger
//! input; the main task feeds the device bytes, edges and time, and sends what it
//! answers. Pins, chain wiring and the current budget are in [`board`]; each image
//! (one per chain wiring, `src/main.rs` and `src/bin/`) only chooses the wiring and
//! calls [`run`].
#![cfg_attr(target_os = "none", no_std)]

#[cfg(target_os = "none")]
pub mod board;
#[cfg(target_os = "none")]
mod firmware;
#[cfg(target_os = "none")]
mod link;
#[cfg(target_os = "none")]
mod triggers;
#[cfg(target_os = "none")]
mod ws2812;

#[cfg(target_os = "none")]
pub use firmware::run;

/// Start the controller for a chain of `$lanes` data lanes: the whole `main` of an
/// image. On the host it is an empty program, so workspace-wide builds and tests need
/// no embedded toolchain.
#[macro_export]
macro_rules! image {
    ($lanes:expr) => {
        #[cfg(target_os = "none")]
        const _: () = assert!($lanes >= 1 && $lanes <= fpm_firmware::chain::MAX_LANES);

        #[cfg(target_os = "none")]
        #[embassy_executor::main]
        async fn main(spawner: embassy_executor::Spawner) {
            const BOARD: fpm_firmware::BoardConfig = $crate::board::board($lanes as u8);
            $crate::run(spawner, BOARD).await
        }

        #[cfg(not(target_os = "none"))]
        fn main() {
            eprintln!(
                "the fpm LED controller runs on the RP2040: build it in firmware/rp2040 (cargo build --release)"
            );
        }
    };
}
