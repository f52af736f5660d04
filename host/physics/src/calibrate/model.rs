//! Model-based bias of the first moment.
//!
//! Under tilted light the pupil cuts the feature's spectrum off-centre, so the light
//! that reaches the camera travels, on average, slightly closer to the axis than the
//! chief ray: the first moment moves ~1–2 % less than z·(x_c − x)/h. The feature is
//! rebuilt from the focused reference (its support at half amplitude), imaged with the
//! full model — tilted plane wave at the feature, defocus, pupil — and measured with the
//! same estimator; the difference between that and the ideal shift is the bias, which
//! is subtracted from the measurement.

use rustfft::num_complex::Complex32;

use super::feature::{Feature, Polarity};
use super::shift::first_moment;
use crate::fft::{bin_frequency, Fft2};
use crate::image::Image;
use crate::optics::{defocus_transfer, System};

/// The feature rebuilt from the reference, on a small periodic grid at the camera's
/// sample-plane pixel, centred on the feature.
pub struct FeatureModel {
    field: Vec<Complex32>,
    n: usize,
    polarity: Polarity,
    fft: Fft2,
    buf: Vec<Complex32>,
    /// Moment window half-size used for the defocused frames.
    pub half_window: usize,
    /// Moment window half-size used for the focused reference.
    pub reference_half_window: usize,
    /// Feature centre on the model grid, (col, row).
    origin: (f64, f64),
    /// Pupil × defocus transfer for the last defocus asked for, and the columns the
    /// pupil passes (the transforms skip the rest).
    transfer: Option<(f64, Vec<Complex32>, Vec<usize>)>,
    /// The focused reference's moment for the last reference frequency asked for.
    reference: Option<((f64, f64), (f64, f64))>,
}

impl FeatureModel {
    /// Rebuild the feature from `reference` around `feature`. `half_window` and
    /// `max_shift_px` size the grid so nothing wraps around.
    pub fn new(
        reference: &Image,
        feature: &Feature,
        half_window: usize,
        max_shift_px: f64,
    ) -> Self {
        let need = 2 * (half_window + max_shift_px.ceil() as usize) + 16;
        // A multiple of 32 keeps the FFT fast (2⁵ times a small factor) without
        // doubling the grid the way a power of two would.
        let n = need.next_multiple_of(32).max(32);
        let (h, w) = reference.dim();
        let (fc, fr) = (
            feature.center_px.0.round() as i64,
            feature.center_px.1.round() as i64,
        );
        let sign = if feature.polarity == Polarity::Bright {
            1.0
        } else {
            -1.0
        };
        // Half amplitude = quarter intensity contrast: where a coherent image puts an edge.
        let threshold = 0.25 * feature.contrast;
        let bg = feature.background;
        let peak = match feature.polarity {
            Polarity::Bright => bg + feature.contrast,
            Polarity::Dark => bg,
        };
        let (amp_in, amp_out) = match feature.polarity {
            Polarity::Bright => (1.0, (bg.max(0.0) / peak.max(1e-12)).sqrt()),
            Polarity::Dark => (
                ((bg - feature.contrast).max(0.0) / bg.max(1e-12)).sqrt(),
                1.0,
            ),
        };
        let mut field = vec![Complex32::new(amp_out, 0.0); n * n];
        for r in 0..n {
            for c in 0..n {
                let (ir, ic) = (
                    fr + r as i64 - (n / 2) as i64,
                    fc + c as i64 - (n / 2) as i64,
                );
                if ir < 0 || ic < 0 || ir >= h as i64 || ic >= w as i64 {
                    continue;
                }
                // Only the feature's own neighbourhood, not other objects in the frame.
                let near = (ic - fc).unsigned_abs() as usize <= feature.bbox.w / 2 + 3
                    && (ir - fr).unsigned_abs() as usize <= feature.bbox.h / 2 + 3;
                if near && sign * (reference[[ir as usize, ic as usize]] - bg) > threshold {
                    field[r * n + c] = Complex32::new(amp_in, 0.0);
                }
            }
        }
        Self::from_field(field, n, feature.polarity, half_window)
    }

    /// A model from a given transmission on an `n × n` grid at the camera's
    /// sample-plane pixel, centred on the feature.
    pub fn from_field(
        field: Vec<Complex32>,
        n: usize,
        polarity: Polarity,
        half_window: usize,
    ) -> Self {
        Self {
            field,
            n,
            polarity,
            fft: Fft2::new(n, n),
            buf: vec![Complex32::default(); n * n],
            half_window,
            reference_half_window: half_window,
            origin: ((n / 2) as f64, (n / 2) as f64),
            transfer: None,
            reference: None,
        }
    }

    /// Image the model under illumination frequency `f` (cycles/µm) at defocus `z`.
    pub fn image(&mut self, system: &System, f: (f64, f64), z_um: f64) -> Image {
        let n = self.n;
        let d = system.sample_pixel_um();
        if self.transfer.as_ref().is_none_or(|(z, _, _)| *z != z_um) {
            let cutoff2 = system.cutoff().powi(2);
            let pupil_cols: Vec<usize> = (0..n)
                .filter(|&k| bin_frequency(k, n, d).abs() <= system.cutoff())
                .collect();
            let t = (0..n * n)
                .map(|i| {
                    let (fx, fy) = (bin_frequency(i % n, n, d), bin_frequency(i / n, n, d));
                    if fx * fx + fy * fy <= cutoff2 {
                        let (hr, hi) = defocus_transfer(fx, fy, z_um, system.wavelength_um);
                        Complex32::new(hr as f32, hi as f32)
                    } else {
                        Complex32::default()
                    }
                })
                .collect();
            self.transfer = Some((z_um, t, pupil_cols));
        }
        // The tilt exp(i2π f·x) separates into a row and a column factor.
        let tilt = |freq: f64, k: usize| {
            let ph = 2.0 * std::f64::consts::PI * freq * (k as f64 - self.origin.0) * d;
            let (s, c) = ph.sin_cos();
            Complex32::new(c as f32, s as f32)
        };
        let cols: Vec<Complex32> = (0..n).map(|k| tilt(f.0, k)).collect();
        let rows: Vec<Complex32> = (0..n).map(|k| tilt(f.1, k)).collect();
        for (r, row_tilt) in rows.iter().enumerate() {
            let span = r * n..(r + 1) * n;
            for ((out, obj), col_tilt) in self.buf[span.clone()]
                .iter_mut()
                .zip(&self.field[span])
                .zip(&cols)
            {
                *out = obj * row_tilt * col_tilt;
            }
        }
        // Only the pupil's columns of the spectrum are needed, and only they are
        // non-zero on the way back: the transforms skip the others (the transfer is zero
        // there, clearing what the forward pass left in them).
        if let Some((_, t, pupil_cols)) = &self.transfer {
            self.fft.forward_wanted_cols(&mut self.buf, pupil_cols);
            for (v, h) in self.buf.iter_mut().zip(t) {
                *v *= h;
            }
            self.fft
                .inverse_unnormalised_sparse_cols(&mut self.buf, pupil_cols);
        }
        let norm = 1.0 / ((n * n) as f32).powi(2);
        Image::from_shape_fn((n, n), |(r, c)| self.buf[r * n + c].norm_sqr() * norm)
    }

    /// The first-moment shift (µm) the estimator reports for a defocused frame under
    /// `f_led` relative to the focused reference under `f_ref`.
    pub fn predicted_shift_um(
        &mut self,
        system: &System,
        f_ref: (f64, f64),
        f_led: (f64, f64),
        z_um: f64,
        start_offset_px: (f64, f64),
    ) -> Option<(f64, f64)> {
        let m0 = match self.reference {
            Some((f, m)) if f == f_ref => m,
            _ => {
                let reference = self.image(system, f_ref, 0.0);
                let m = first_moment(
                    &reference,
                    self.polarity,
                    self.origin,
                    self.reference_half_window,
                    3,
                )?
                .center_px;
                self.reference = Some((f_ref, m));
                m
            }
        };
        let defocused = self.image(system, f_led, z_um);
        let start = (
            self.origin.0 + start_offset_px.0,
            self.origin.1 + start_offset_px.1,
        );
        let m1 = first_moment(&defocused, self.polarity, start, self.half_window, 4)?;
        let d = system.sample_pixel_um();
        Some(((m1.center_px.0 - m0.0) * d, (m1.center_px.1 - m0.1) * d))
    }
}
