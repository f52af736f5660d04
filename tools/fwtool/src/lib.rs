//! Firmware image tools: what the RP2040's boot ROM wants (UF2) and what fits (sizes).

pub mod build;
pub mod uf2;

use anyhow::{bail, Context, Result};

/// RP2040 flash (XIP) window.
pub const FLASH: std::ops::Range<u64> = 0x1000_0000..0x1100_0000;
/// RP2040 SRAM window.
pub const RAM: std::ops::Range<u64> = 0x2000_0000..0x2004_2000;

/// A loadable piece of an ELF image at its load (flash) address.
#[derive(Debug, Clone, PartialEq)]
pub struct Segment {
    /// Load address (where the bytes are stored).
    pub load_addr: u64,
    /// Run address (where they live while running; RAM for .data).
    pub run_addr: u64,
    /// Bytes in the file.
    pub data: Vec<u8>,
    /// Size in memory (larger than `data` for zero-initialised parts).
    pub mem_size: u64,
}

/// Read the loadable (PT_LOAD) segments of a 32-bit little-endian ELF file, as a
/// thumbv6m-none-eabi build produces.
pub fn segments(elf: &[u8]) -> Result<Vec<Segment>> {
    let u16_at = |o: usize| elf.get(o..o + 2).map(|b| u16::from_le_bytes([b[0], b[1]]));
    let u32_at = |o: usize| {
        elf.get(o..o + 4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    if elf.get(..4) != Some(&b"\x7fELF"[..]) {
        bail!("not an ELF file");
    }
    if elf.get(4) != Some(&1) || elf.get(5) != Some(&1) {
        bail!("expected a 32-bit little-endian ELF (a thumbv6m-none-eabi build)");
    }
    let phoff = u32_at(0x1C).context("truncated ELF header")? as usize;
    let phentsize = u16_at(0x2A).context("truncated ELF header")? as usize;
    let phnum = u16_at(0x2C).context("truncated ELF header")? as usize;
    let mut out = vec![];
    for i in 0..phnum {
        let h = phoff + i * phentsize;
        let field =
            |k: usize| u32_at(h + k).with_context(|| format!("truncated program header {i}"));
        const PT_LOAD: u32 = 1;
        if field(0)? != PT_LOAD {
            continue;
        }
        let (offset, vaddr, paddr) = (field(0x04)? as usize, field(0x08)?, field(0x0C)?);
        let (filesz, memsz) = (field(0x10)? as usize, field(0x14)?);
        let data = elf
            .get(offset..offset + filesz)
            .with_context(|| format!("segment {i} lies outside the file"))?
            .to_vec();
        out.push(Segment {
            load_addr: paddr.into(),
            run_addr: vaddr.into(),
            data,
            mem_size: memsz.into(),
        });
    }
    Ok(out)
}

/// Flash and static RAM an image needs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Sizes {
    /// Bytes stored in flash (code, constants, the initial values of .data).
    pub flash: u64,
    /// Bytes of RAM reserved before `main` (.data + .bss + .uninit).
    pub ram: u64,
}

/// Sizes of an image from its segments.
pub fn sizes(segments: &[Segment]) -> Sizes {
    let flash = segments
        .iter()
        .filter(|s| FLASH.contains(&s.load_addr))
        .map(|s| s.data.len() as u64)
        .sum();
    let ram = segments
        .iter()
        .filter(|s| RAM.contains(&s.run_addr))
        .map(|s| s.mem_size)
        .sum();
    Sizes { flash, ram }
}
