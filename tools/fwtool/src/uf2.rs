//! UF2, the format the RP2040 boot ROM accepts by drag-and-drop (BOOTSEL mass storage):
//! 512-byte blocks, each carrying 256 bytes for one flash address.
//! Format: <https://github.com/microsoft/uf2>.

use crate::{Segment, FLASH};

const MAGIC_START0: u32 = 0x0A32_4655;
const MAGIC_START1: u32 = 0x9E5D_5157;
const MAGIC_END: u32 = 0x0AB1_6F30;
const FLAG_FAMILY_ID: u32 = 0x0000_2000;
/// The RP2040's family id.
pub const RP2040_FAMILY: u32 = 0xE48B_FF56;
/// Payload bytes per block (the RP2040 boot ROM takes 256).
pub const PAYLOAD: usize = 256;

/// Encode the flash-resident parts of `segments` as UF2, page by page; bytes between
/// segments that share a page are zero.
pub fn encode(segments: &[Segment], family: u32) -> Vec<u8> {
    let mut pages: std::collections::BTreeMap<u64, [u8; PAYLOAD]> = Default::default();
    for s in segments
        .iter()
        .filter(|s| FLASH.contains(&s.load_addr) && !s.data.is_empty())
    {
        for (i, byte) in s.data.iter().enumerate() {
            let addr = s.load_addr + i as u64;
            let page = addr & !(PAYLOAD as u64 - 1);
            pages.entry(page).or_insert([0; PAYLOAD])[(addr - page) as usize] = *byte;
        }
    }
    let total = pages.len() as u32;
    let mut out = Vec::with_capacity(pages.len() * 512);
    for (n, (addr, data)) in pages.iter().enumerate() {
        let mut block = [0u8; 512];
        let words = [
            MAGIC_START0,
            MAGIC_START1,
            FLAG_FAMILY_ID,
            *addr as u32,
            PAYLOAD as u32,
            n as u32,
            total,
            family,
        ];
        for (k, w) in words.iter().enumerate() {
            block[k * 4..k * 4 + 4].copy_from_slice(&w.to_le_bytes());
        }
        block[32..32 + PAYLOAD].copy_from_slice(data);
        block[508..512].copy_from_slice(&MAGIC_END.to_le_bytes());
        out.extend_from_slice(&block);
    }
    out
}

/// Decode UF2 blocks back into (address, payload) pairs, checking every magic number
/// and the block numbering.
pub fn decode(uf2: &[u8]) -> Result<Vec<(u32, Vec<u8>)>, String> {
    if !uf2.len().is_multiple_of(512) {
        return Err(format!(
            "{} bytes is not a whole number of 512-byte blocks",
            uf2.len()
        ));
    }
    let total = uf2.len() / 512;
    let mut out = vec![];
    for (n, block) in uf2.chunks(512).enumerate() {
        let w = |k: usize| {
            u32::from_le_bytes([
                block[k * 4],
                block[k * 4 + 1],
                block[k * 4 + 2],
                block[k * 4 + 3],
            ])
        };
        if w(0) != MAGIC_START0 || w(1) != MAGIC_START1 || w(127) != MAGIC_END {
            return Err(format!("block {n}: bad magic"));
        }
        if w(5) as usize != n || w(6) as usize != total {
            return Err(format!("block {n}: numbered {} of {}", w(5), w(6)));
        }
        let size = w(4) as usize;
        if size > 476 {
            return Err(format!("block {n}: payload of {size} bytes"));
        }
        out.push((w(3), block[32..32 + size].to_vec()));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seg(addr: u64, data: Vec<u8>) -> Segment {
        Segment {
            load_addr: addr,
            run_addr: addr,
            mem_size: data.len() as u64,
            data,
        }
    }

    #[test]
    fn pages_carry_exactly_the_image() {
        let a: Vec<u8> = (0..700u32).map(|i| (i % 251) as u8).collect();
        let b: Vec<u8> = vec![0xAB; 10];
        // b lands in the middle of a's last page; a RAM segment is left out.
        let segs = [
            seg(0x1000_0000, a.clone()),
            seg(0x1000_0000 + 740, b.clone()),
            seg(0x2000_0000, vec![1; 64]),
        ];
        let uf2 = encode(&segs, RP2040_FAMILY);
        let blocks = decode(&uf2).unwrap();
        assert_eq!(blocks.len(), 3);
        let addrs: Vec<u32> = blocks.iter().map(|(a, _)| *a).collect();
        assert_eq!(addrs, vec![0x1000_0000, 0x1000_0100, 0x1000_0200]);
        let mut image = vec![];
        for (_, d) in &blocks {
            assert_eq!(d.len(), PAYLOAD);
            image.extend_from_slice(d);
        }
        assert_eq!(&image[..700], &a[..]);
        assert_eq!(&image[700..740], &[0u8; 40][..]);
        assert_eq!(&image[740..750], &b[..]);
        assert!(image[750..].iter().all(|&x| x == 0));
        // every block names the RP2040
        for block in uf2.chunks(512) {
            assert_eq!(
                u32::from_le_bytes(block[28..32].try_into().unwrap()),
                RP2040_FAMILY
            );
        }
    }

    #[test]
    fn corrupted_files_are_rejected() {
        let uf2 = encode(&[seg(0x1000_0000, vec![1; 300])], RP2040_FAMILY);
        assert!(decode(&uf2[..511]).is_err());
        let mut bad = uf2.clone();
        bad[0] ^= 1;
        assert!(decode(&bad).unwrap_err().contains("magic"));
        let mut renumbered = uf2.clone();
        renumbered[20] = 7;
        assert!(decode(&renumbered).unwrap_err().contains("numbered"));
    }
}
