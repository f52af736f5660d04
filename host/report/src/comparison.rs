//! The truth beside reconstructions of a simulated dataset, as one picture.

use std::path::Path;

use anyhow::{bail, Context, Result};
use fpm_host::dataset::{image_io, DatasetInfo};
use fpm_host::truth::Truth;
use ndarray::Array2;
use rustfft::num_complex::Complex32;

use crate::text;

/// Write `path`, a PNG of the truth beside each of `panels` (a title and a
/// reconstruction `upsample` × the camera grid of dataset `ds`): amplitude above phase,
/// each reconstruction resampled onto the truth's grid and brought to the truth's mean
/// amplitude and global phase (both arbitrary in a reconstruction), all on the truth's
/// grey scales, with a scale bar on the truth.
/// An extra: the caller only warns when it fails.
pub fn write_comparison(
    ds: &(impl DatasetInfo + ?Sized),
    panels: &[(&str, &Array2<Complex32>)],
    upsample: usize,
    path: &Path,
) -> Result<()> {
    let truth = Truth::find(ds.dir())?.context("no truth.json beside the dataset")?;
    let pitch = truth
        .object_pixel_um
        .context("truth.json gives no object_pixel_um")?;
    let t = image_io::read_complex(
        &ds.dir().join("truth_amplitude.tif"),
        &ds.dir().join("truth_phase.tif"),
    )?;
    let (h, w) = t.dim();
    let rec_pitch = ds.manifest().system().sample_pixel_um() / upsample.max(1) as f64;
    let mut fields = vec![("Truth", t.clone())];
    for (title, r) in panels {
        let (rh, rw) = r.dim();
        if rh * w != rw * h {
            bail!("{title}: {rw}x{rh} is not the truth's field of view ({w}x{h})");
        }
        fields.push((title, onto_truth(r, rec_pitch, &t)));
    }
    let (cw, ch, canvas) = picture(&fields, &t, pitch);
    let rgb: Vec<u8> = canvas.iter().flat_map(|&v| [v, v, v]).collect();
    image_io::write_png_rgb(path, cw, ch, &rgb)?;
    Ok(())
}

/// Reconstruction `r` (pixel `pitch_um`) resampled onto the truth `t`'s grid and brought
/// to its global phase (the best rotation) and mean amplitude (a least-squares scale
/// goes to zero for an image unlike the truth, and the picture is there to show such
/// an image).
fn onto_truth(r: &Array2<Complex32>, pitch_um: f64, t: &Array2<Complex32>) -> Array2<Complex32> {
    let mut r = fpm_physics::metrics::resample_to(r, pitch_um, t.dim(), |_, _| true);
    let c: rustfft::num_complex::Complex64 = r
        .iter()
        .zip(t.iter())
        .map(|(a, b)| {
            let z = a.conj() * b;
            rustfft::num_complex::Complex64::new(z.re as f64, z.im as f64)
        })
        .sum();
    let mean = |f: &Array2<Complex32>| f.iter().map(|v| v.norm() as f64).sum::<f64>();
    let (mr, mt) = (mean(&r), mean(t));
    if c.norm() > 0.0 && mr > 0.0 {
        let factor = c / c.norm() * (mt / mr);
        r.mapv_inplace(|v| v * Complex32::new(factor.re as f32, factor.im as f32));
    }
    r
}

/// The titled panels, amplitude above phase, on the truth's grey scales (its 0.5–99.5 %
/// range, the phase with a quarter margin), the truth with a scale bar (pixel
/// `pitch_um`): (width, height, grey levels).
fn picture(
    fields: &[(&str, Array2<Complex32>)],
    t: &Array2<Complex32>,
    pitch_um: f64,
) -> (usize, usize, Vec<u8>) {
    let (h, w) = t.dim();
    let pitch = pitch_um;
    // Grey scales from the truth: its 0.5–99.5 % range, phase with a quarter margin.
    let range = |v: Vec<f32>, margin: f32| {
        let mut v = v;
        v.sort_by(f32::total_cmp);
        let (lo, hi) = (v[v.len() / 200], v[v.len() - 1 - v.len() / 200]);
        let span = (hi - lo).max(1e-3);
        (lo - margin * span, hi + margin * span)
    };
    let amp_range = range(t.iter().map(|c| c.norm()).collect(), 0.05);
    let phase_range = range(t.iter().map(|c| c.arg()).collect(), 0.25);
    let s = (w.min(h) / 160).max(1);
    let gap = 4 * s;
    let header = text::height(s) + 2 * gap;
    let (cw, ch) = (
        fields.len() * w + (fields.len() + 1) * gap,
        header + 2 * h + 2 * gap,
    );
    let mut canvas = vec![40u8; cw * ch];
    let grey = |v: f32, (lo, hi): (f32, f32)| {
        (((v - lo) / (hi - lo)).clamp(0.0, 1.0) * 255.0).round() as u8
    };
    for (k, (title, f)) in fields.iter().enumerate() {
        let x0 = gap + k * (w + gap);
        text::draw(&mut canvas, cw, ch, (x0, gap), title, s, 255);
        for (row, (name, part)) in [("Amplitude", 0usize), ("Phase", 1)]
            .into_iter()
            .enumerate()
        {
            let mut panel: Vec<u8> = f
                .iter()
                .map(|c| match part {
                    0 => grey(c.norm(), amp_range),
                    _ => grey(c.arg(), phase_range),
                })
                .collect();
            if k == 0 {
                crate::scale_bar::draw(&mut panel, w, h, pitch);
                let plate = (text::width(name, s) + 2 * s, text::height(s) + 2 * s);
                text::fill(&mut panel, w, h, (0, 0), plate, 0);
                text::draw(&mut panel, w, h, (s, s), name, s, 255);
            }
            let y0 = header + row * (h + gap);
            for r in 0..h {
                let at = (y0 + r) * cw + x0;
                canvas[at..at + w].copy_from_slice(&panel[r * w..(r + 1) * w]);
            }
        }
    }
    (cw, ch, canvas)
}
