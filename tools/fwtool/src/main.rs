//! `fpm-fwtool`: turn the firmware ELF into a UF2 for drag-and-drop flashing, and check
//! that it fits the RP2040.
use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use fpm_fwtool::{segments, sizes, uf2};

#[derive(Parser)]
#[command(
    name = "fpm-fwtool",
    version,
    about = "Firmware image tools for the fpm LED controller (RP2040)"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Write a UF2 file: hold BOOTSEL while plugging the Pico in, then copy it onto the
    /// RPI-RP2 drive that appears.
    Uf2 {
        /// The firmware ELF (target/thumbv6m-none-eabi/release/fpm-led-controller).
        elf: PathBuf,
        /// Output file.
        out: PathBuf,
    },
    /// Print flash and static RAM use; fail if over the limits.
    Size {
        /// The firmware ELF.
        elf: PathBuf,
        /// Most flash allowed, KiB.
        #[arg(long, default_value_t = 256)]
        max_flash_kib: u64,
        /// Most static RAM allowed, KiB.
        #[arg(long, default_value_t = 128)]
        max_ram_kib: u64,
    },
}

/// Read the UF2 back and check every flash byte of the ELF is in it, at its address.
fn verify(segs: &[fpm_fwtool::Segment], image: &[u8]) -> Result<()> {
    let blocks = uf2::decode(image).map_err(|e| anyhow::anyhow!("UF2 self-check: {e}"))?;
    let pages: std::collections::HashMap<u64, &[u8]> = blocks
        .iter()
        .map(|(a, d)| (*a as u64, d.as_slice()))
        .collect();
    for s in segs
        .iter()
        .filter(|s| fpm_fwtool::FLASH.contains(&s.load_addr))
    {
        for (i, byte) in s.data.iter().enumerate() {
            let addr = s.load_addr + i as u64;
            let page = addr & !(uf2::PAYLOAD as u64 - 1);
            let got = pages.get(&page).and_then(|d| d.get((addr - page) as usize));
            if got != Some(byte) {
                bail!("UF2 self-check: byte at {addr:#x} differs from the ELF");
            }
        }
    }
    Ok(())
}

fn main() -> Result<()> {
    match Cli::parse().command {
        Command::Uf2 { elf, out } => {
            let bytes =
                std::fs::read(&elf).with_context(|| format!("reading {}", elf.display()))?;
            let segs = segments(&bytes).with_context(|| format!("parsing {}", elf.display()))?;
            let image = uf2::encode(&segs, uf2::RP2040_FAMILY);
            if image.is_empty() {
                bail!("{} has nothing to put in flash", elf.display());
            }
            verify(&segs, &image)?;
            std::fs::write(&out, &image).with_context(|| format!("writing {}", out.display()))?;
            println!(
                "{}: {} blocks, {} bytes of flash",
                out.display(),
                image.len() / 512,
                image.len() / 2
            );
        }
        Command::Size {
            elf,
            max_flash_kib,
            max_ram_kib,
        } => {
            let bytes =
                std::fs::read(&elf).with_context(|| format!("reading {}", elf.display()))?;
            let s = sizes(&segments(&bytes)?);
            println!(
                "{}: flash {:.1} KiB (limit {max_flash_kib}), static RAM {:.1} KiB (limit {max_ram_kib})",
                elf.display(),
                s.flash as f64 / 1024.0,
                s.ram as f64 / 1024.0
            );
            if s.flash > max_flash_kib * 1024 || s.ram > max_ram_kib * 1024 {
                bail!("the firmware does not fit");
            }
        }
    }
    Ok(())
}
