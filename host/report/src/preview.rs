//! PNG previews for people: 8-bit grey, the object's with a scale bar, the phase with
//! a colour bar in radians.

use std::path::Path;

use anyhow::{Context, Result};
use fpm_host::reconstruction::Reconstruction;
use ndarray::Array2;

/// The reconstruction's previews in `out`: amplitude.png and phase.png (with a scale
/// bar), pupil_amplitude.png and pupil_phase.png (the Fourier plane: none).
pub fn reconstruction(r: &Reconstruction, out: &Path) -> Result<()> {
    let amplitude = r.object.mapv(|c| c.norm());
    let phase = r.object.mapv(|c| c.arg());
    object(
        &amplitude,
        &phase,
        r.report.pixel_um,
        &out.join("amplitude.png"),
        &out.join("phase.png"),
    )?;
    let pupil_amplitude = r.pupil.mapv(|c| c.norm());
    let pupil_phase = r.pupil.mapv(|c| c.arg());
    let pi = std::f32::consts::PI;
    let [pupil_max] = quantiles(&pupil_amplitude, [1.0]);
    write_png_preview(
        &out.join("pupil_amplitude.png"),
        &pupil_amplitude,
        0.0,
        pupil_max,
        None,
    )?;
    write_png_preview(&out.join("pupil_phase.png"), &pupil_phase, -pi, pi, None)
}

/// The values at fractions `qs` of `a`'s sorted order, selected from one copy.
fn quantiles<const N: usize>(a: &Array2<f32>, qs: [f64; N]) -> [f32; N] {
    let mut v: Vec<f32> = a.iter().copied().collect();
    fpm_physics::stats::quantiles(&mut v, qs).unwrap_or([0.0; N])
}

/// The object's PNG previews, each with a scale bar at `pixel_um`: the amplitude over
/// its 0.5–99.5 % range, the phase over ±π with a colour bar in radians.
pub fn object(
    amplitude: &Array2<f32>,
    phase: &Array2<f32>,
    pixel_um: f64,
    amplitude_png: &Path,
    phase_png: &Path,
) -> Result<()> {
    write(amplitude_png, &amplitude_png_bytes(amplitude, pixel_um)?)?;
    write(phase_png, &phase_png_bytes(phase, pixel_um)?)
}

fn write(path: &Path, bytes: &[u8]) -> Result<()> {
    std::fs::write(path, bytes).with_context(|| format!("writing {}", path.display()))
}

/// The amplitude's PNG preview (as [`object`] writes it): its 0.5–99.5 % range, with a
/// scale bar at `pixel_um`.
pub fn amplitude_png_bytes(amplitude: &Array2<f32>, pixel_um: f64) -> Result<Vec<u8>> {
    let [lo, hi] = quantiles(amplitude, [0.005, 0.995]);
    let (h, w) = amplitude.dim();
    encode_png_grey(w, h, &preview_bytes(amplitude, (lo, hi), Some(pixel_um)))
}

/// The phase's PNG preview (as [`object`] writes it): ±π with a colour bar in
/// radians, and a scale bar at `pixel_um`.
pub fn phase_png_bytes(phase: &Array2<f32>, pixel_um: f64) -> Result<Vec<u8>> {
    let pi = std::f32::consts::PI;
    let (h, w) = phase.dim();
    let data = preview_bytes(phase, (-pi, pi), Some(pixel_um));
    let (data, w) = crate::colour_bar::append(&data, w, h, (-pi, pi), "rad");
    encode_png_grey(w, h, &data)
}

/// 16-bit counts (a camera frame) as an 8-bit PNG over their 0.1–99.9 % range.
pub fn counts_png_bytes(counts: &ndarray::ArrayView2<u16>) -> Result<Vec<u8>> {
    let as_f32 = counts.mapv(f32::from);
    let [lo, hi] = quantiles(&as_f32, [0.001, 0.999]);
    let (h, w) = counts.dim();
    encode_png_grey(w, h, &preview_bytes(&as_f32, (lo, hi), None))
}

/// Write an 8-bit grey PNG scaled from `lo` (black) to `hi` (white), with a scale bar
/// when the image's pixel size in the sample plane (`pixel_um`) is given.
pub fn write_png_preview(
    path: &Path,
    img: &Array2<f32>,
    lo: f32,
    hi: f32,
    pixel_um: Option<f64>,
) -> Result<()> {
    let (h, w) = img.dim();
    let data = preview_bytes(img, (lo, hi), pixel_um);
    write_png_grey(path, w, h, &data)
}

/// Like [`write_png_preview`], with a colour bar on the right giving the values of
/// black (`lo`) and white (`hi`) in `unit` (a phase preview: radians).
pub fn write_png_preview_with_bar(
    path: &Path,
    img: &Array2<f32>,
    (lo, hi): (f32, f32),
    pixel_um: Option<f64>,
    unit: &str,
) -> Result<()> {
    let (h, w) = img.dim();
    let data = preview_bytes(img, (lo, hi), pixel_um);
    let (data, w) = crate::colour_bar::append(&data, w, h, (lo, hi), unit);
    write_png_grey(path, w, h, &data)
}

/// `img` scaled to 8-bit grey from `lo` (black) to `hi` (white), with a scale bar when
/// its pixel size in the sample plane is given.
fn preview_bytes(img: &Array2<f32>, (lo, hi): (f32, f32), pixel_um: Option<f64>) -> Vec<u8> {
    let (h, w) = img.dim();
    let span = (hi - lo).max(f32::EPSILON);
    let mut data: Vec<u8> = img
        .iter()
        .map(|&v| (((v - lo) / span).clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect();
    if let Some(pixel_um) = pixel_um {
        crate::scale_bar::draw(&mut data, w, h, pixel_um);
    }
    data
}

fn write_png_grey(path: &Path, w: usize, h: usize, data: &[u8]) -> Result<()> {
    write(path, &encode_png_grey(w, h, data)?)
}

/// 8-bit grey pixels, row-major, as a PNG file's bytes.
fn encode_png_grey(w: usize, h: usize, data: &[u8]) -> Result<Vec<u8>> {
    let mut bytes = Vec::new();
    let mut enc = png::Encoder::new(&mut bytes, w as u32, h as u32);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Eight);
    let mut wr = enc.write_header().context("encoding a PNG")?;
    wr.write_image_data(data).context("encoding a PNG")?;
    wr.finish().context("encoding a PNG")?;
    Ok(bytes)
}
