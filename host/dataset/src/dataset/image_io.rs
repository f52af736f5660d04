//! Frames on disk: grey-scale TIFF (8/16-bit integer or 32-bit float) and PNG (8/16-bit).

use std::fs::File;
use std::io::{BufReader, BufWriter};
use std::path::{Path, PathBuf};

use ndarray::Array2;

pub use fpm_physics::frame::Pixels;

/// Why an image could not be read or written; every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    /// The file could not be opened or created.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        #[source]
        source: std::io::Error,
    },
    /// The content is not an image we read (type, colour, depth, corrupt data).
    #[error("{}: {reason}", path.display())]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// Encoding or writing failed.
    #[error("{}: cannot write: {reason}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        reason: String,
    },
}

impl ImageError {
    /// The reason alone, without the file (for messages that name the file already).
    pub fn reason(&self) -> String {
        match self {
            ImageError::Io { source, .. } => source.to_string(),
            ImageError::Format { reason, .. } | ImageError::Write { reason, .. } => reason.clone(),
        }
    }
}

fn open(path: &Path) -> Result<File, ImageError> {
    File::open(path).map_err(|source| ImageError::Io {
        path: path.to_path_buf(),
        source,
    })
}

fn create(path: &Path) -> Result<BufWriter<File>, ImageError> {
    File::create(path)
        .map(BufWriter::new)
        .map_err(|source| ImageError::Io {
            path: path.to_path_buf(),
            source,
        })
}

fn format(path: &Path) -> impl Fn(String) -> ImageError + '_ {
    move |reason| ImageError::Format {
        path: path.to_path_buf(),
        reason,
    }
}

fn write_failed<E: std::fmt::Display>(path: &Path) -> impl Fn(E) -> ImageError + '_ {
    move |e| ImageError::Write {
        path: path.to_path_buf(),
        reason: e.to_string(),
    }
}

/// A path's extension, lower case ("" without one).
fn extension(path: &Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase()
}

/// Read a TIFF or PNG by its extension.
pub fn read(path: &Path) -> Result<Pixels, ImageError> {
    let ext = extension(path);
    match ext.as_str() {
        "tif" | "tiff" => read_tiff(open(path)?).map_err(format(path)),
        "png" => read_png(open(path)?).map_err(format(path)),
        _ => Err(format(path)(format!(
            "unsupported image type '.{ext}' (use .tif, .tiff or .png)"
        ))),
    }
}

type TiffDecoder = tiff::decoder::Decoder<BufReader<File>>;

/// A decoder for a grey-scale TIFF, and the image's (rows, cols).
fn grey_tiff(file: File) -> Result<(TiffDecoder, (usize, usize)), String> {
    let mut dec = tiff::decoder::Decoder::new(BufReader::new(file))
        .map_err(|e| format!("not a readable TIFF: {e}"))?;
    let (w, h) = dec.dimensions().map_err(|e| e.to_string())?;
    let color = dec.colortype().map_err(|e| e.to_string())?;
    if !matches!(color, tiff::ColorType::Gray(_)) {
        return Err(format!("expected a grey-scale TIFF, found {color:?}"));
    }
    Ok((dec, (h as usize, w as usize)))
}

/// Decoded samples as a `shape` (rows, cols) image of the types fpm takes.
fn pixels_of(
    decoded: tiff::decoder::DecodingResult,
    shape: (usize, usize),
) -> Result<Pixels, String> {
    use tiff::decoder::DecodingResult;
    let bad = |e: ndarray::ShapeError| e.to_string();
    match decoded {
        DecodingResult::U8(v) => Array2::from_shape_vec(shape, v)
            .map(Pixels::U8)
            .map_err(bad),
        DecodingResult::U16(v) => Array2::from_shape_vec(shape, v)
            .map(Pixels::U16)
            .map_err(bad),
        DecodingResult::F32(v) => Array2::from_shape_vec(shape, v)
            .map(Pixels::F32)
            .map_err(bad),
        other => Err(format!(
            "unsupported TIFF sample type ({})",
            sample_name(&other)
        )),
    }
}

fn read_tiff(file: File) -> Result<Pixels, String> {
    let (mut dec, shape) = grey_tiff(file)?;
    let decoded = dec
        .read_image()
        .map_err(|e| format!("cannot decode: {e}"))?;
    pixels_of(decoded, shape)
}

/// Some rows of an image, with the whole image's (rows, cols).
pub type Rows = (Pixels, (usize, usize));

/// Rows `rows` of a grey-scale TIFF stored in strips, decoding only the strips that
/// hold them, with the whole image's (rows, cols). `None` when the file is not a TIFF
/// in strips (a PNG, a tiled TIFF): read it whole then.
pub fn read_rows(path: &Path, rows: std::ops::Range<usize>) -> Result<Option<Rows>, ImageError> {
    if !matches!(extension(path).as_str(), "tif" | "tiff") {
        return Ok(None);
    }
    read_tiff_rows(open(path)?, rows).map_err(format(path))
}

fn read_tiff_rows(file: File, rows: std::ops::Range<usize>) -> Result<Option<Rows>, String> {
    use tiff::decoder::{ChunkType, DecodingResult};
    let (mut dec, (h, w)) = grey_tiff(file)?;
    if dec.get_chunk_type() != ChunkType::Strip {
        return Ok(None);
    }
    if rows.start >= rows.end || rows.end > h {
        return Err(format!(
            "rows {}..{} are not within its {h} rows",
            rows.start, rows.end
        ));
    }
    let per_strip = dec
        .find_tag_unsigned::<u64>(tiff::tags::Tag::RowsPerStrip)
        .map_err(|e| e.to_string())?
        .map_or(h, |r| r.min(h as u64) as usize)
        .max(1);
    // The strips' samples for these rows, appended in order (of the file's one type).
    fn append<T: Clone>(acc: &mut Vec<T>, strip: &[T], span: std::ops::Range<usize>) -> bool {
        strip.get(span).map(|s| acc.extend_from_slice(s)).is_some()
    }
    let mut out: Option<DecodingResult> = None;
    for strip in rows.start / per_strip..=(rows.end - 1) / per_strip {
        let first = strip * per_strip;
        let span =
            (rows.start.max(first) - first) * w..(rows.end.min(first + per_strip) - first) * w;
        let chunk = dec
            .read_chunk(strip as u32)
            .map_err(|e| format!("cannot decode strip {strip}: {e}"))?;
        let acc = out.get_or_insert_with(|| match &chunk {
            DecodingResult::U8(_) => DecodingResult::U8(vec![]),
            DecodingResult::U16(_) => DecodingResult::U16(vec![]),
            _ => DecodingResult::F32(vec![]),
        });
        let fits = match (acc, &chunk) {
            (DecodingResult::U8(a), DecodingResult::U8(v)) => append(a, v, span.clone()),
            (DecodingResult::U16(a), DecodingResult::U16(v)) => append(a, v, span.clone()),
            (DecodingResult::F32(a), DecodingResult::F32(v)) => append(a, v, span.clone()),
            _ => {
                return Err(format!(
                    "unsupported TIFF sample type ({})",
                    sample_name(&chunk)
                ))
            }
        };
        if !fits {
            return Err(format!(
                "strip {strip} holds fewer than the {} samples its rows need",
                span.end
            ));
        }
    }
    let decoded = out.ok_or("no strips")?;
    Ok(Some((pixels_of(decoded, (rows.len(), w))?, (h, w))))
}

fn sample_name(d: &tiff::decoder::DecodingResult) -> &'static str {
    use tiff::decoder::DecodingResult::*;
    match d {
        U32(_) => "32-bit integer",
        U64(_) => "64-bit integer",
        F64(_) => "64-bit float",
        I8(_) | I16(_) | I32(_) | I64(_) => "signed integer",
        _ => "other",
    }
}

fn read_png(file: File) -> Result<Pixels, String> {
    let mut dec = png::Decoder::new(BufReader::new(file));
    dec.set_transformations(png::Transformations::IDENTITY);
    let mut reader = dec
        .read_info()
        .map_err(|e| format!("not a readable PNG: {e}"))?;
    let info = reader.info();
    let (w, h) = (info.width as usize, info.height as usize);
    if info.color_type != png::ColorType::Grayscale {
        return Err(format!(
            "expected a grey-scale PNG, found {:?}",
            info.color_type
        ));
    }
    let depth = info.bit_depth;
    let mut buf = vec![0; reader.output_buffer_size().ok_or("PNG too large")?];
    reader
        .next_frame(&mut buf)
        .map_err(|e| format!("cannot decode: {e}"))?;
    match depth {
        png::BitDepth::Eight => Array2::from_shape_vec((h, w), buf[..w * h].to_vec())
            .map(Pixels::U8)
            .map_err(|e| e.to_string()),
        png::BitDepth::Sixteen => {
            let v: Vec<u16> = buf[..2 * w * h]
                .chunks_exact(2)
                .map(|b| u16::from_be_bytes([b[0], b[1]]))
                .collect();
            Array2::from_shape_vec((h, w), v)
                .map(Pixels::U16)
                .map_err(|e| e.to_string())
        }
        other => Err(format!("unsupported PNG bit depth {other:?}")),
    }
}

/// Write a 16-bit grey TIFF.
pub fn write_tiff_u16(path: &Path, img: ndarray::ArrayView2<u16>) -> Result<(), ImageError> {
    use tiff::encoder::{colortype, TiffEncoder};
    let (h, w) = img.dim();
    let mut enc = TiffEncoder::new(create(path)?).map_err(write_failed(path))?;
    let standard = img.as_standard_layout();
    let data = standard.as_slice().unwrap_or_default();
    enc.write_image::<colortype::Gray16>(w as u32, h as u32, data)
        .map_err(write_failed(path))
}

/// Write a 32-bit float grey TIFF.
pub fn write_tiff_f32(path: &Path, img: &Array2<f32>) -> Result<(), ImageError> {
    use tiff::encoder::{colortype, TiffEncoder};
    let (h, w) = img.dim();
    let mut enc = TiffEncoder::new(create(path)?).map_err(write_failed(path))?;
    let standard = img.as_standard_layout();
    let data = standard.as_slice().unwrap_or_default();
    enc.write_image::<colortype::Gray32Float>(w as u32, h as u32, data)
        .map_err(write_failed(path))
}

/// How a described float32 TIFF is written.
#[derive(Debug, Clone, Copy, Default)]
pub struct TiffOptions {
    /// Deflate-compress the pixels (lossless; float images of noisy data shrink little).
    pub compress: bool,
    /// BigTIFF even below 4 GB (above, always).
    pub big: bool,
}

/// TIFF's 32-bit offsets end at 4 GiB: above this many bytes of pixels (and room for
/// the directory and description), BigTIFF.
const BIG_TIFF_ABOVE_BYTES: u64 = 4_000_000_000;

/// Write a float32 TIFF that describes itself: `description` in the ImageDescription
/// (OME-XML, say) and the pixel size as the resolution (pixels per centimetre, for
/// readers that take no OME), BigTIFF when the pixels pass 4 GB.
pub fn write_tiff_f32_described(
    path: &Path,
    img: &Array2<f32>,
    description: &str,
    pixel_um: f64,
    options: TiffOptions,
) -> Result<(), ImageError> {
    write_tiff_f32_planes_described(path, &[img], description, pixel_um, options)
}

/// [`write_tiff_f32_described`] for several planes of one size (an OME-TIFF's
/// channels, one IFD each; the description goes into the first).
pub fn write_tiff_f32_planes_described(
    path: &Path,
    planes: &[&Array2<f32>],
    description: &str,
    pixel_um: f64,
    options: TiffOptions,
) -> Result<(), ImageError> {
    use tiff::encoder::{Compression, DeflateLevel, TiffEncoder, TiffKind};
    fn write<K: TiffKind>(
        mut enc: TiffEncoder<BufWriter<File>, K>,
        planes: &[&Array2<f32>],
        description: &str,
        pixel_um: f64,
    ) -> tiff::TiffResult<()> {
        use tiff::encoder::{colortype, Rational};
        use tiff::tags::{ResolutionUnit, Tag};
        for (k, img) in planes.iter().enumerate() {
            let (h, w) = img.dim();
            let standard = img.as_standard_layout();
            let data = standard.as_slice().unwrap_or_default();
            let mut image = enc.new_image::<colortype::Gray32Float>(w as u32, h as u32)?;
            if k == 0 {
                image
                    .encoder()
                    .write_tag(Tag::ImageDescription, description)?;
            }
            if pixel_um.is_finite() && pixel_um > 0.0 {
                let per_cm = Rational {
                    n: (1e7 / pixel_um).round().min(u32::MAX as f64) as u32,
                    d: 1000,
                };
                image.resolution(ResolutionUnit::Centimeter, per_cm);
            }
            image.write_data(data)?;
        }
        Ok(())
    }
    let compression = if options.compress {
        Compression::Deflate(DeflateLevel::Balanced)
    } else {
        Compression::Uncompressed
    };
    let bytes: u64 = planes.iter().map(|p| p.len() as u64 * 4).sum();
    let big = bytes > BIG_TIFF_ABOVE_BYTES || options.big;
    let file = create(path)?;
    if big {
        let enc = TiffEncoder::new_big(file).map_err(write_failed(path))?;
        write(
            enc.with_compression(compression),
            planes,
            description,
            pixel_um,
        )
    } else {
        let enc = TiffEncoder::new(file).map_err(write_failed(path))?;
        write(
            enc.with_compression(compression),
            planes,
            description,
            pixel_um,
        )
    }
    .map_err(write_failed(path))
}

/// Write an RGB8 PNG (plots, previews).
pub fn write_png_rgb(
    path: &Path,
    width: usize,
    height: usize,
    rgb: &[u8],
) -> Result<(), ImageError> {
    let mut enc = png::Encoder::new(create(path)?, width as u32, height as u32);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc.write_header().map_err(write_failed(path))?;
    w.write_image_data(rgb).map_err(write_failed(path))
}

/// Read an amplitude/phase pair of float32 TIFFs (a reconstruction's `amplitude.tif`
/// and `phase.tif`, or a simulation's truth) as one complex field.
pub fn read_complex(
    amplitude: &Path,
    phase: &Path,
) -> Result<Array2<rustfft::num_complex::Complex32>, ImageError> {
    let read_f32 = |path: &Path| match read(path)? {
        Pixels::F32(a) => Ok(a),
        other => Err(format(path)(format!(
            "expected a float32 TIFF, found {}-bit samples",
            other.bits()
        ))),
    };
    let (amp, ph) = (read_f32(amplitude)?, read_f32(phase)?);
    if amp.dim() != ph.dim() {
        return Err(format(phase)(format!(
            "{}x{} differs from {} ({}x{})",
            ph.dim().1,
            ph.dim().0,
            amplitude.display(),
            amp.dim().1,
            amp.dim().0
        )));
    }
    Ok(Array2::from_shape_fn(amp.dim(), |i| {
        rustfft::num_complex::Complex32::from_polar(amp[i], ph[i])
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp() -> Array2<f32> {
        Array2::from_shape_fn((48, 64), |(r, c)| (r * 64 + c) as f32 * 0.25 - 100.0)
    }

    /// Every way a described TIFF is written (plain, deflate, BigTIFF) reads back
    /// bit for bit, with the description and the resolution where readers look.
    #[test]
    fn described_tiffs_read_back_in_every_form() {
        let dir = std::env::temp_dir().join(format!("fpm-described-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let img = ramp();
        for (name, compress, big) in [
            ("plain.tif", false, false),
            ("deflate.tif", true, false),
            ("big.tif", false, true),
            ("big-deflate.tif", true, true),
        ] {
            let path = dir.join(name);
            let options = TiffOptions { compress, big };
            write_tiff_f32_described(&path, &img, "<OME>x</OME>", 0.4, options).unwrap();
            let bytes = std::fs::read(&path).unwrap();
            assert_eq!(&bytes[..2], b"II", "{name}");
            assert_eq!(bytes[2], if big { 43 } else { 42 }, "{name}: TIFF kind");
            match read(&path).unwrap() {
                Pixels::F32(back) => assert_eq!(back, img, "{name}"),
                other => panic!("{name}: read back as {}-bit", other.bits()),
            }
            let mut decoder = tiff::decoder::Decoder::new(File::open(&path).unwrap()).unwrap();
            let description = decoder
                .get_tag_ascii_string(tiff::tags::Tag::ImageDescription)
                .unwrap();
            assert_eq!(description, "<OME>x</OME>", "{name}");
            let unit = decoder
                .get_tag_u32(tiff::tags::Tag::ResolutionUnit)
                .unwrap();
            assert_eq!(unit, 3, "{name}: centimetres");
            if compress {
                let plain = std::fs::metadata(dir.join("plain.tif")).unwrap().len();
                assert!(
                    (bytes.len() as u64) < plain,
                    "{name}: deflate shrinks a ramp"
                );
            }
        }
        std::fs::remove_dir_all(&dir).ok();
    }
}
