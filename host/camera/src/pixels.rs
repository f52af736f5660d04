//! Pixel formats as GenICam cameras send them (PFNC codes), decoded into the frame
//! contract's `u16` pixels straight into the loaned shared-memory sample: the one copy
//! between the camera's buffer and the host.
//!
//! Packed layouts (GenICam PFNC 2.x and the GigE Vision 2.0 legacy formats):
//! * `Mono10p`, `Mono12p`: a little-endian bit stream, pixel after pixel, least
//!   significant bit first (4 pixels in 5 bytes, 2 pixels in 3 bytes).
//! * `Mono12Packed`, `Mono10Packed` (GigE Vision): 2 pixels in 3 bytes; byte 0 and
//!   byte 2 hold the high bits of pixels 0 and 1, byte 1 their low bits (pixel 0 in
//!   bits 0–3, pixel 1 in bits 4–7; for 10 bits, bits 0–1 and 4–5).

use std::mem::MaybeUninit;

/// A pixel format the driver decodes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum PixelFormat {
    /// 8 bits per pixel.
    Mono8,
    /// 10 bits in 16, little-endian.
    Mono10,
    /// 12 bits in 16, little-endian.
    Mono12,
    /// 14 bits in 16, little-endian.
    Mono14,
    /// 16 bits, little-endian.
    Mono16,
    /// 10 bits, 4 pixels in 5 bytes (PFNC).
    Mono10p,
    /// 12 bits, 2 pixels in 3 bytes (PFNC).
    Mono12p,
    /// 10 bits, 2 pixels in 3 bytes (GigE Vision).
    Mono10Packed,
    /// 12 bits, 2 pixels in 3 bytes (GigE Vision).
    Mono12Packed,
    /// A colour sensor's raw mosaic, 8 bits (the pattern's name, e.g. "RGGB").
    Bayer8(&'static str),
    /// A raw mosaic, `bits` significant bits in 16, little-endian.
    Bayer16(&'static str, u32),
}

/// Why a buffer could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    /// A pixel format without a decoder here.
    #[error("pixel format 0x{0:08x} is not supported (Mono8/10/12/14/16, Mono10p/12p, Mono10Packed/12Packed, Bayer 8/10/12/16 are)")]
    Unsupported(u32),
    /// Fewer bytes than the image needs.
    #[error("{format:?} {width}x{height} needs {needed} bytes, the buffer holds {got}")]
    Short {
        /// The format.
        format: PixelFormat,
        /// Width.
        width: u32,
        /// Height.
        height: u32,
        /// Bytes needed.
        needed: usize,
        /// Bytes received.
        got: usize,
    },
    /// A channel was asked of a mono format.
    #[error("{0:?} is not a colour mosaic: there is no channel to take")]
    NotAMosaic(PixelFormat),
    /// A packed format whose pixel count does not fill its groups.
    #[error("{format:?} needs a pixel count divisible by {group}, got {pixels}")]
    Ragged {
        /// The format.
        format: PixelFormat,
        /// Pixels per group.
        group: usize,
        /// Pixels in the image.
        pixels: usize,
    },
}

impl PixelFormat {
    /// The format of a PFNC code.
    pub fn from_pfnc(code: u32) -> Result<Self, DecodeError> {
        Ok(match code {
            0x0108_0001 => Self::Mono8,
            0x0110_0003 => Self::Mono10,
            0x0110_0005 => Self::Mono12,
            0x0110_0025 => Self::Mono14,
            0x0110_0007 => Self::Mono16,
            0x010A_0046 => Self::Mono10p,
            0x010C_0047 => Self::Mono12p,
            0x010C_0004 => Self::Mono10Packed,
            0x010C_0006 => Self::Mono12Packed,
            0x0108_0008 => Self::Bayer8("GRBG"),
            0x0108_0009 => Self::Bayer8("RGGB"),
            0x0108_000A => Self::Bayer8("GBRG"),
            0x0108_000B => Self::Bayer8("BGGR"),
            0x0110_000C => Self::Bayer16("GRBG", 10),
            0x0110_000D => Self::Bayer16("RGGB", 10),
            0x0110_000E => Self::Bayer16("GBRG", 10),
            0x0110_000F => Self::Bayer16("BGGR", 10),
            0x0110_0010 => Self::Bayer16("GRBG", 12),
            0x0110_0011 => Self::Bayer16("RGGB", 12),
            0x0110_0012 => Self::Bayer16("GBRG", 12),
            0x0110_0013 => Self::Bayer16("BGGR", 12),
            0x0110_002E => Self::Bayer16("GRBG", 16),
            0x0110_002F => Self::Bayer16("RGGB", 16),
            0x0110_0030 => Self::Bayer16("GBRG", 16),
            0x0110_0031 => Self::Bayer16("BGGR", 16),
            other => return Err(DecodeError::Unsupported(other)),
        })
    }

    /// Significant bits per pixel.
    pub fn bit_depth(self) -> u32 {
        match self {
            Self::Mono8 | Self::Bayer8(_) => 8,
            Self::Mono10 | Self::Mono10p | Self::Mono10Packed => 10,
            Self::Mono12 | Self::Mono12p | Self::Mono12Packed => 12,
            Self::Mono14 => 14,
            Self::Mono16 => 16,
            Self::Bayer16(_, bits) => bits,
        }
    }

    /// The colour filter pattern of a raw mosaic ("RGGB", ...), None for mono.
    pub fn bayer(self) -> Option<&'static str> {
        match self {
            Self::Bayer8(p) | Self::Bayer16(p, _) => Some(p),
            _ => None,
        }
    }

    /// Bytes for `pixels` pixels, and the pixels per packing group.
    fn layout(self, pixels: usize) -> (usize, usize) {
        match self {
            Self::Mono8 | Self::Bayer8(_) => (pixels, 1),
            Self::Mono10 | Self::Mono12 | Self::Mono14 | Self::Mono16 | Self::Bayer16(..) => {
                (pixels * 2, 1)
            }
            Self::Mono10p => (pixels / 4 * 5, 4),
            Self::Mono12p | Self::Mono10Packed | Self::Mono12Packed => (pixels / 2 * 3, 2),
        }
    }
}

/// The first `needed` bytes of `src`, or the error naming what is short.
fn leading(
    src: &[u8],
    needed: usize,
    format: PixelFormat,
    width: u32,
    height: u32,
) -> Result<&[u8], DecodeError> {
    src.get(..needed).ok_or(DecodeError::Short {
        format,
        width,
        height,
        needed,
        got: src.len(),
    })
}

/// Decode a `width × height` image in `format` from `src` into `dst` (exactly
/// `width · height` pixels, every one written).
pub fn decode(
    format: PixelFormat,
    width: u32,
    height: u32,
    src: &[u8],
    dst: &mut [MaybeUninit<u16>],
) -> Result<(), DecodeError> {
    let pixels = width as usize * height as usize;
    assert_eq!(
        dst.len(),
        pixels,
        "the destination holds the image's pixels"
    );
    let (needed, group) = format.layout(pixels);
    if !pixels.is_multiple_of(group) {
        return Err(DecodeError::Ragged {
            format,
            group,
            pixels,
        });
    }
    let src = leading(src, needed, format, width, height)?;
    match format {
        PixelFormat::Mono8 | PixelFormat::Bayer8(_) => {
            for (d, &s) in dst.iter_mut().zip(src) {
                d.write(s as u16);
            }
        }
        PixelFormat::Mono10
        | PixelFormat::Mono12
        | PixelFormat::Mono14
        | PixelFormat::Mono16
        | PixelFormat::Bayer16(..) => {
            for (d, s) in dst.iter_mut().zip(src.chunks_exact(2)) {
                d.write(u16::from_le_bytes([s[0], s[1]]));
            }
        }
        PixelFormat::Mono10p => {
            for (d, s) in dst.chunks_exact_mut(4).zip(src.chunks_exact(5)) {
                let bits = u64::from_le_bytes([s[0], s[1], s[2], s[3], s[4], 0, 0, 0]);
                for (k, p) in d.iter_mut().enumerate() {
                    p.write(((bits >> (10 * k)) & 0x3FF) as u16);
                }
            }
        }
        PixelFormat::Mono12p => {
            for (d, s) in dst.chunks_exact_mut(2).zip(src.chunks_exact(3)) {
                let (b0, b1, b2) = (s[0] as u16, s[1] as u16, s[2] as u16);
                d[0].write(b0 | (b1 & 0x0F) << 8);
                d[1].write(b1 >> 4 | b2 << 4);
            }
        }
        PixelFormat::Mono12Packed => {
            for (d, s) in dst.chunks_exact_mut(2).zip(src.chunks_exact(3)) {
                let (b0, b1, b2) = (s[0] as u16, s[1] as u16, s[2] as u16);
                d[0].write(b0 << 4 | (b1 & 0x0F));
                d[1].write(b2 << 4 | b1 >> 4);
            }
        }
        PixelFormat::Mono10Packed => {
            for (d, s) in dst.chunks_exact_mut(2).zip(src.chunks_exact(3)) {
                let (b0, b1, b2) = (s[0] as u16, s[1] as u16, s[2] as u16);
                d[0].write(b0 << 2 | (b1 & 0x03));
                d[1].write(b2 << 2 | (b1 >> 4 & 0x03));
            }
        }
    }
    Ok(())
}

/// A colour channel of a raw mosaic.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Channel {
    /// Red.
    R,
    /// Green.
    G,
    /// Blue.
    B,
}

impl std::str::FromStr for Channel {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "R" | "r" => Ok(Self::R),
            "G" | "g" => Ok(Self::G),
            "B" | "b" => Ok(Self::B),
            other => Err(format!("channel {other:?}: expected R, G or B")),
        }
    }
}

/// Where `channel` sits in the 2 × 2 cell of mosaic `pattern` ("RGGB", ...), as
/// (row, col): one site for red and blue, two for green.
fn sites(pattern: &str, channel: Channel) -> Vec<(usize, usize)> {
    let want = match channel {
        Channel::R => b'R',
        Channel::G => b'G',
        Channel::B => b'B',
    };
    pattern
        .bytes()
        .enumerate()
        .filter(|&(_, f)| f == want)
        .map(|(k, _)| (k / 2, k % 2))
        .collect()
}

/// One channel of a raw mosaic (`Bayer8`/`Bayer16` formats), straight from the
/// camera's bytes into `dst`: the channel's own pixels, one value per 2 × 2 cell (the
/// two green pixels averaged), so `dst` holds (width / 2) · (height / 2) pixels of
/// twice the sensor's pitch. Width and height must be even.
pub fn decode_channel(
    format: PixelFormat,
    width: u32,
    height: u32,
    src: &[u8],
    channel: Channel,
    dst: &mut [MaybeUninit<u16>],
) -> Result<(), DecodeError> {
    let (w, h) = (width as usize, height as usize);
    let Some(pattern) = format.bayer() else {
        return Err(DecodeError::NotAMosaic(format));
    };
    if w % 2 == 1 || h % 2 == 1 {
        return Err(DecodeError::Ragged {
            format,
            group: 2,
            pixels: w * h,
        });
    }
    let (needed, _) = format.layout(w * h);
    let bytes = needed / (w * h).max(1);
    let src = leading(src, needed, format, width, height)?;
    assert_eq!(
        dst.len(),
        (w / 2) * (h / 2),
        "the destination holds the channel's pixels"
    );
    let at = |r: usize, c: usize| -> u32 {
        let k = r * w + c;
        if bytes == 1 {
            src[k] as u32
        } else {
            u16::from_le_bytes([src[2 * k], src[2 * k + 1]]) as u32
        }
    };
    let sites = sites(pattern, channel);
    let n = sites.len() as u32;
    for (k, d) in dst.iter_mut().enumerate() {
        let (i, j) = (k / (w / 2), k % (w / 2));
        let sum: u32 = sites.iter().map(|&(r, c)| at(2 * i + r, 2 * j + c)).sum();
        // Rounded half up: the mean of two green pixels.
        d.write(((sum + n / 2) / n) as u16);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// A PFNC "p" stream written bit by bit from the spec's definition: each pixel's
    /// bits, least significant first, appended to a little-endian bit stream.
    fn encode_lsb_stream(pixels: &[u16], bits: u32) -> Vec<u8> {
        let mut out = vec![0u8; (pixels.len() * bits as usize).div_ceil(8)];
        let mut at = 0usize;
        for &p in pixels {
            for b in 0..bits {
                if p >> b & 1 == 1 {
                    out[at / 8] |= 1 << (at % 8);
                }
                at += 1;
            }
        }
        out
    }

    /// The GigE Vision 2-in-3 layout, from its definition.
    fn encode_gige_packed(pixels: &[u16], bits: u32) -> Vec<u8> {
        let low = bits - 8;
        let mask = (1u16 << low) - 1;
        pixels
            .chunks(2)
            .flat_map(|p| {
                [
                    (p[0] >> low) as u8,
                    ((p[0] & mask) | (p[1] & mask) << 4) as u8,
                    (p[1] >> low) as u8,
                ]
            })
            .collect()
    }

    fn run(format: PixelFormat, w: u32, h: u32, src: &[u8]) -> Result<Vec<u16>, DecodeError> {
        let mut dst = vec![MaybeUninit::<u16>::uninit(); (w * h) as usize];
        decode(format, w, h, src, &mut dst)?;
        // SAFETY: decode wrote every pixel (it returned Ok).
        Ok(dst
            .into_iter()
            .map(|p| unsafe { p.assume_init() })
            .collect())
    }

    fn random(n: usize, bits: u32, seed: u64) -> Vec<u16> {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        (0..n)
            .map(|_| rng.gen_range(0..1u32 << bits) as u16)
            .collect()
    }

    #[test]
    fn every_packed_format_round_trips_its_definition() {
        let (w, h) = (16u32, 6u32);
        for (format, bits) in [(PixelFormat::Mono10p, 10), (PixelFormat::Mono12p, 12)] {
            let want = random((w * h) as usize, bits, bits as u64);
            let got = run(format, w, h, &encode_lsb_stream(&want, bits)).unwrap();
            assert_eq!(got, want, "{format:?}");
        }
        for (format, bits) in [
            (PixelFormat::Mono10Packed, 10),
            (PixelFormat::Mono12Packed, 12),
        ] {
            let want = random((w * h) as usize, bits, 100 + bits as u64);
            let got = run(format, w, h, &encode_gige_packed(&want, bits)).unwrap();
            assert_eq!(got, want, "{format:?}");
        }
    }

    #[test]
    fn known_bytes_decode_to_known_pixels() {
        // Mono12p: 0xABC, 0x123 → bytes BC, 3A, 12.
        assert_eq!(
            run(PixelFormat::Mono12p, 2, 1, &[0xBC, 0x3A, 0x12]).unwrap(),
            [0xABC, 0x123]
        );
        // Mono12Packed (GigE): 0xABC, 0x123 → bytes AB, 3C, 12.
        assert_eq!(
            run(PixelFormat::Mono12Packed, 2, 1, &[0xAB, 0x3C, 0x12]).unwrap(),
            [0xABC, 0x123]
        );
        // Mono10p: 1, 2, 3, 1023 → the stream 0000000001 0000000010 ... LSB first.
        assert_eq!(
            run(PixelFormat::Mono10p, 4, 1, &[0x01, 0x08, 0x30, 0xC0, 0xFF]).unwrap(),
            [1, 2, 3, 1023]
        );
        assert_eq!(
            run(PixelFormat::Mono16, 2, 1, &[0x34, 0x12, 0xFF, 0xFF]).unwrap(),
            [0x1234, 0xFFFF]
        );
        assert_eq!(
            run(PixelFormat::Mono8, 3, 1, &[0, 7, 255]).unwrap(),
            [0, 7, 255]
        );
    }

    #[test]
    fn short_buffers_and_ragged_images_are_refused_by_name() {
        let e = run(PixelFormat::Mono16, 4, 4, &[0; 31]).unwrap_err();
        assert!(
            e.to_string()
                .contains("needs 32 bytes, the buffer holds 31"),
            "{e}"
        );
        let e = run(PixelFormat::Mono12Packed, 3, 1, &[0; 9]).unwrap_err();
        assert!(matches!(e, DecodeError::Ragged { group: 2, .. }), "{e}");
        let e = PixelFormat::from_pfnc(0x0218_0014).unwrap_err();
        assert!(e.to_string().contains("0x02180014"), "{e}");
    }

    #[test]
    fn a_mosaic_channel_is_its_own_pixels_one_per_cell() {
        // RGGB, 4 × 2: each site holds a code of its filter and position.
        let raw: Vec<u8> = (0..2)
            .flat_map(|r| {
                (0..4).map(move |c| match (r % 2, c % 2) {
                    (0, 0) => 10 + c as u8,       // R
                    (1, 1) => 200 + c as u8,      // B
                    _ => 100 + (r * 4 + c) as u8, // G
                })
            })
            .collect();
        let take = |ch| {
            let mut dst = vec![MaybeUninit::<u16>::uninit(); 2];
            decode_channel(PixelFormat::Bayer8("RGGB"), 4, 2, &raw, ch, &mut dst).unwrap();
            dst.into_iter()
                .map(|p| unsafe { p.assume_init() })
                .collect::<Vec<u16>>()
        };
        assert_eq!(take(Channel::R), [10, 12]);
        assert_eq!(take(Channel::B), [201, 203]);
        // Cell 0: greens at (0,1) = 101 and (1,0) = 104 → 102.5 → 103.
        assert_eq!(take(Channel::G), [103, 105]);
        let mut dst = vec![MaybeUninit::<u16>::uninit(); 2];
        let e = decode_channel(PixelFormat::Mono8, 4, 2, &raw, Channel::G, &mut dst).unwrap_err();
        assert!(e.to_string().contains("not a colour mosaic"), "{e}");
    }

    #[test]
    fn codes_name_their_depth_and_mosaic() {
        assert_eq!(PixelFormat::from_pfnc(0x010C_0006).unwrap().bit_depth(), 12);
        assert_eq!(PixelFormat::from_pfnc(0x010A_0046).unwrap().bit_depth(), 10);
        let bayer = PixelFormat::from_pfnc(0x0108_0009).unwrap();
        assert_eq!((bayer.bayer(), bayer.bit_depth()), (Some("RGGB"), 8));
        assert_eq!(PixelFormat::from_pfnc(0x0108_0001).unwrap().bayer(), None);
    }
}
