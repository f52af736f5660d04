//! The firmware built from a checkout, for `fpm device flash` given no image: the
//! xtask way (cargo builds the RP2040 target where the sources are, when asked)
//! rather than an image embedded in `fpm` at its own build, which would compile the
//! firmware for the RP2040 with every build of the host and fix one chain wiring.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{bail, Context, Result};

use crate::uf2;

/// The firmware's images: the chain's data lanes and the ELF's name.
pub const IMAGES: [(u8, &str); 3] = [
    (1, "fpm-led-controller"),
    (2, "fpm-led-controller-2lanes"),
    (4, "fpm-led-controller-4lanes"),
];

/// The ELF of the image for `lanes` data lanes in `checkout`'s build.
pub fn elf_path(checkout: &Path, lanes: u8) -> Result<PathBuf> {
    let Some((_, name)) = IMAGES.iter().find(|(n, _)| *n == lanes) else {
        bail!("no firmware image for {lanes} data lanes (1, 2 or 4)");
    };
    Ok(checkout
        .join("target/thumbv6m-none-eabi/release")
        .join(name))
}

/// Build the firmware in `checkout` (`cargo build --release --locked` in
/// `firmware/rp2040`, its progress on stderr) and return the UF2 of the image for
/// `lanes` data lanes.
pub fn build_uf2(checkout: &Path, lanes: u8) -> Result<Vec<u8>> {
    let sources = checkout.join("firmware/rp2040");
    if !sources.join("Cargo.toml").is_file() {
        bail!(
            "no firmware sources at {} (this fpm was built from a checkout that is gone, or installed): give the UF2 image (docs/hardware.md)",
            sources.display()
        );
    }
    let elf = elf_path(checkout, lanes)?;
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    // From its own directory, so that its .cargo/config.toml (target, linker scripts)
    // applies; a no-op when nothing changed.
    let status = Command::new(&cargo)
        .args(["build", "--release", "--locked"])
        .current_dir(&sources)
        .env_remove("CARGO_TARGET_DIR")
        .status()
        .with_context(|| format!("running {cargo} build in {}", sources.display()))?;
    if !status.success() {
        bail!(
            "building the firmware in {} failed ({status}): its errors are above; `rustup target add thumbv6m-none-eabi` if the target is missing",
            sources.display()
        );
    }
    let bytes = std::fs::read(&elf).with_context(|| format!("reading {}", elf.display()))?;
    let segments = crate::segments(&bytes).with_context(|| format!("reading {}", elf.display()))?;
    Ok(uf2::encode(&segments, uf2::RP2040_FAMILY))
}
