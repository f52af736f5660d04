//! Frames on disk: grey-scale TIFF (8/16-bit integer or 32-bit float) and PNG (8/16-bit).

use std::fs::File;
use std::io::{BufReader, BufWriter};
use std::path::Path;

use fpm_physics::Image;
use ndarray::Array2;

/// A frame as stored.
#[derive(Debug, Clone, PartialEq)]
pub enum Pixels {
    /// 8-bit integers.
    U8(Array2<u8>),
    /// 16-bit integers.
    U16(Array2<u16>),
    /// 32-bit floats.
    F32(Array2<f32>),
}

impl Pixels {
    /// Width × height as (rows, cols).
    pub fn dim(&self) -> (usize, usize) {
        match self {
            Pixels::U8(a) => a.dim(),
            Pixels::U16(a) => a.dim(),
            Pixels::F32(a) => a.dim(),
        }
    }

    /// As floats.
    pub fn to_f32(&self) -> Image {
        match self {
            Pixels::U8(a) => a.mapv(f32::from),
            Pixels::U16(a) => a.mapv(f32::from),
            Pixels::F32(a) => a.clone(),
        }
    }

    /// Bits per sample.
    pub fn bits(&self) -> u32 {
        match self {
            Pixels::U8(_) => 8,
            Pixels::U16(_) => 16,
            Pixels::F32(_) => 32,
        }
    }
}

/// Read a TIFF or PNG by its extension.
pub fn read(path: &Path) -> Result<Pixels, String> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    match ext.as_str() {
        "tif" | "tiff" => read_tiff(path),
        "png" => read_png(path),
        _ => Err(format!(
            "unsupported image type '.{ext}' (use .tif, .tiff or .png)"
        )),
    }
}

fn read_tiff(path: &Path) -> Result<Pixels, String> {
    use tiff::decoder::{Decoder, DecodingResult};
    let file = File::open(path).map_err(|e| e.to_string())?;
    let mut dec =
        Decoder::new(BufReader::new(file)).map_err(|e| format!("not a readable TIFF: {e}"))?;
    let (w, h) = dec.dimensions().map_err(|e| e.to_string())?;
    let color = dec.colortype().map_err(|e| e.to_string())?;
    if !matches!(color, tiff::ColorType::Gray(_)) {
        return Err(format!("expected a grey-scale TIFF, found {color:?}"));
    }
    let shape = (h as usize, w as usize);
    let bad = |e: ndarray::ShapeError| e.to_string();
    match dec
        .read_image()
        .map_err(|e| format!("cannot decode: {e}"))?
    {
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

fn read_png(path: &Path) -> Result<Pixels, String> {
    let file = File::open(path).map_err(|e| e.to_string())?;
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
pub fn write_tiff_u16(path: &Path, img: &Array2<u16>) -> Result<(), String> {
    use tiff::encoder::{colortype, TiffEncoder};
    let (h, w) = img.dim();
    let file = BufWriter::new(File::create(path).map_err(|e| e.to_string())?);
    let mut enc = TiffEncoder::new(file).map_err(|e| e.to_string())?;
    let data: Vec<u16> = img.iter().copied().collect();
    enc.write_image::<colortype::Gray16>(w as u32, h as u32, &data)
        .map_err(|e| e.to_string())
}

/// Write a 32-bit float grey TIFF.
pub fn write_tiff_f32(path: &Path, img: &Array2<f32>) -> Result<(), String> {
    use tiff::encoder::{colortype, TiffEncoder};
    let (h, w) = img.dim();
    let file = BufWriter::new(File::create(path).map_err(|e| e.to_string())?);
    let mut enc = TiffEncoder::new(file).map_err(|e| e.to_string())?;
    let data: Vec<f32> = img.iter().copied().collect();
    enc.write_image::<colortype::Gray32Float>(w as u32, h as u32, &data)
        .map_err(|e| e.to_string())
}

/// Write an RGB8 PNG (plots, previews).
pub fn write_png_rgb(path: &Path, width: usize, height: usize, rgb: &[u8]) -> Result<(), String> {
    let file = BufWriter::new(File::create(path).map_err(|e| e.to_string())?);
    let mut enc = png::Encoder::new(file, width as u32, height as u32);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc.write_header().map_err(|e| e.to_string())?;
    w.write_image_data(rgb).map_err(|e| e.to_string())
}

/// Write an 8-bit grey PNG scaled from `lo` (black) to `hi` (white).
pub fn write_png_preview(path: &Path, img: &Array2<f32>, lo: f32, hi: f32) -> Result<(), String> {
    let (h, w) = img.dim();
    let span = (hi - lo).max(f32::EPSILON);
    let data: Vec<u8> = img
        .iter()
        .map(|&v| (((v - lo) / span).clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect();
    let file = BufWriter::new(File::create(path).map_err(|e| e.to_string())?);
    let mut enc = png::Encoder::new(file, w as u32, h as u32);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Eight);
    let mut wr = enc.write_header().map_err(|e| e.to_string())?;
    wr.write_image_data(&data).map_err(|e| e.to_string())
}
