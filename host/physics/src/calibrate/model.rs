//! Model-based bias of the first moment.
//!
//! Under tilted light the pupil cuts the feature's spectrum off-centre, so the light
//! that reaches the camera travels, on average, slightly closer to the axis than the
//! chief ray: the first moment moves ~1–2 % less than z·(x_c − x)/h. The feature is
//! rebuilt from the focused reference (its support at half amplitude), imaged with the
//! full model — tilted plane wave at the feature, defocus, pupil — and measured with the
//! same estimator; the difference between that and the ideal shift is the bias, which
//! is subtracted from the measurement.

use std::ops::Range;

use rustfft::num_complex::Complex32;

use super::feature::{Feature, Polarity};
use super::shift::{first_moment_within, Bounds, Moment, RING_BAND};
use crate::fft::{bin_frequency, Fft2};
use crate::image::Image;
use crate::optics::System;

/// The feature rebuilt from the reference, on a small periodic grid at the camera's
/// sample-plane pixel, centred on the feature.
///
/// Each image is computed in the feature's own frequency frame: a tilted plane wave
/// moves the spectrum by the illumination frequency `f`, which is the same, for the
/// intensity, as leaving the spectrum in place and moving the pupil by `−f`. So the
/// feature is transformed once, and each LED costs one pruned inverse transform (the
/// pupil's columns, then only the rows the moment window reads).
pub struct FeatureModel {
    /// The transmission's spectrum (unnormalised forward transform).
    spectrum: Vec<Complex32>,
    n: usize,
    /// Frequency of each bin along either axis, cycles/µm at the sample.
    bin_freq: Vec<f64>,
    /// Sample-plane pixel the grid was built for, µm.
    pixel_um: f64,
    polarity: Polarity,
    fft: Fft2,
    buf: Vec<Complex32>,
    /// Moment window half-size used for the defocused frames.
    pub half_window: usize,
    /// Moment window half-size used for the focused reference.
    pub reference_half_window: usize,
    /// Feature centre on the model grid, (col, row).
    origin: (f64, f64),
    /// The focused reference's moment for the last reference frequency asked for.
    reference: Option<((f64, f64), (f64, f64))>,
    /// The defocus transfer for the last defocus asked for.
    defocus: Option<DefocusTable>,
    /// Where the pupil is centred at the feature, cycles/µm: the chief ray's frequency
    /// there ([`System::chief_ray_frequency`]), zero for a telecentric objective.
    pub pupil_centre: (f64, f64),
    /// The frame pixel of the grid's (0, 0), for a model rebuilt from a frame.
    grid_in_frame: Option<(i64, i64)>,
    /// The frame's pixels on the grid: a moment the frame's edge cut is cut here too.
    frame: Option<Bounds>,
}

/// The defocus transfer inside the pupil as a function of the squared frequency ρ²,
/// tabulated once per defocus: its phase, less the 2π·z/λ every component shares (the
/// intensity does not see it), runs smoothly over a few tens of radians, so linear
/// interpolation between steps of ≤ 2 mrad (up to 65 536 of them) is good to ~1e-6
/// and an LED costs no sine or cosine.
struct DefocusTable {
    z_um: f64,
    /// The largest frequency tabulated, cycles/µm.
    reach: f64,
    /// ρ² per step, cycles²/µm².
    step: f64,
    values: Vec<Complex32>,
}

impl DefocusTable {
    fn new(z_um: f64, reach: f64, wavelength_um: f64) -> Self {
        let k0 = 1.0 / wavelength_um;
        let phase = |rho2: f64| {
            let axial = (k0 * k0 - rho2).max(0.0).sqrt();
            -2.0 * std::f64::consts::PI * z_um * rho2 / (axial + k0)
        };
        let rho2_max = reach * reach;
        let steps = (phase(rho2_max).abs() / 2e-3).ceil().clamp(64.0, 65536.0) as usize;
        let step = rho2_max / steps as f64;
        let values = (0..=steps + 1)
            .map(|i| {
                let (s, c) = phase(i as f64 * step).sin_cos();
                Complex32::new(c as f32, s as f32)
            })
            .collect();
        Self {
            z_um,
            reach,
            step,
            values,
        }
    }

    /// The transfer at squared frequency `rho2` (within the reach).
    fn at(&self, rho2: f64) -> Complex32 {
        let x = (rho2 / self.step).max(0.0);
        let i = (x as usize).min(self.values.len() - 2);
        let t = (x - i as f64) as f32;
        self.values[i] * (1.0 - t) + self.values[i + 1] * t
    }
}

/// Rows beyond the moment window (and its background band) that an image is computed
/// for, so the window can follow the feature a few pixels before the model has to
/// compute the whole grid.
const ROW_SLACK: usize = 8;

impl FeatureModel {
    /// Rebuild the feature from `reference` (taken through `system`) around `feature`.
    /// `half_window` and `max_shift_px` size the grid so nothing wraps around.
    pub fn new(
        system: &System,
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
        let pixel_um = system.sample_pixel_um();
        Self {
            grid_in_frame: Some((fc - (n / 2) as i64, fr - (n / 2) as i64)),
            ..Self::from_field(field, n, feature.polarity, half_window, pixel_um)
        }
    }

    /// Cut the model's moments where a `width` × `height` frame ends (a model rebuilt
    /// from that frame's reference): a defocused window the frame's edge cuts gives the
    /// model's prediction the same cut, so its bias is modelled too.
    pub fn cut_at_frame(&mut self, width: usize, height: usize) {
        self.frame = self.grid_in_frame.map(|(x, y)| {
            Bounds {
                x0: 0,
                y0: 0,
                x1: width as i64,
                y1: height as i64,
            }
            .shifted(-x, -y)
        });
    }

    /// A model from a given transmission on an `n × n` grid of `pixel_um` (the
    /// camera's sample-plane pixel), centred on the feature.
    pub fn from_field(
        field: Vec<Complex32>,
        n: usize,
        polarity: Polarity,
        half_window: usize,
        pixel_um: f64,
    ) -> Self {
        let mut fft = Fft2::new(n, n);
        let mut spectrum = field;
        fft.forward(&mut spectrum);
        Self {
            spectrum,
            n,
            bin_freq: (0..n).map(|k| bin_frequency(k, n, pixel_um)).collect(),
            pixel_um,
            polarity,
            fft,
            buf: vec![Complex32::default(); n * n],
            half_window,
            reference_half_window: half_window,
            origin: ((n / 2) as f64, (n / 2) as f64),
            reference: None,
            defocus: None,
            pupil_centre: (0.0, 0.0),
            grid_in_frame: None,
            frame: None,
        }
    }

    /// Image the model under illumination frequency `f` (cycles/µm) at defocus `z`:
    /// the rows `rows` of the grid, as an image of `rows.len()` rows.
    pub fn image_rows(
        &mut self,
        system: &System,
        f: (f64, f64),
        z_um: f64,
        rows: Range<usize>,
    ) -> Image {
        let n = self.n;
        let cutoff = system.cutoff();
        // The pupil moved by −f: the bins whose frequency + f it passes (relative to
        // its centre), each with the defocus transfer of that tilted component.
        let c = self.pupil_centre;
        let reach = cutoff + c.0.hypot(c.1);
        if self
            .defocus
            .as_ref()
            .is_some_and(|t| t.z_um != z_um || t.reach != reach)
        {
            self.defocus = None;
        }
        let defocus = &*self
            .defocus
            .get_or_insert_with(|| DefocusTable::new(z_um, reach, system.wavelength_um));
        let pupil_cols: Vec<usize> = (0..n)
            .filter(|&k| (self.bin_freq[k] + f.0 - c.0).abs() <= cutoff)
            .collect();
        self.buf.fill(Complex32::default());
        for (r, &fy_bin) in self.bin_freq.iter().enumerate() {
            let fy = fy_bin + f.1;
            if (fy - c.1).abs() > cutoff {
                continue;
            }
            for &col in &pupil_cols {
                let fx = self.bin_freq[col] + f.0;
                if (fx - c.0).powi(2) + (fy - c.1).powi(2) > cutoff * cutoff {
                    continue;
                }
                self.buf[r * n + col] = self.spectrum[r * n + col] * defocus.at(fx * fx + fy * fy);
            }
        }
        self.fft
            .inverse_unnormalised_sparse_rows(&mut self.buf, &pupil_cols, rows.clone());
        let norm = 1.0 / ((n * n) as f32).powi(2);
        let mut image = Image::zeros((rows.len(), n));
        for (out, v) in image.iter_mut().zip(&self.buf[rows.start * n..]) {
            *out = v.norm_sqr() * norm;
        }
        image
    }

    /// The whole grid's image under illumination frequency `f` at defocus `z`.
    pub fn image(&mut self, system: &System, f: (f64, f64), z_um: f64) -> Image {
        self.image_rows(system, f, z_um, 0..self.n)
    }

    /// The first moment of the model's image under `f` at `z`, from `start` on the
    /// grid: computed on the rows around `start` only, and on the whole grid if the
    /// window (or its background band) wanders out of them.
    fn moment(
        &mut self,
        system: &System,
        f: (f64, f64),
        z_um: f64,
        start: (f64, f64),
        half: usize,
        iterations: usize,
    ) -> Option<Moment> {
        let n = self.n;
        let reach = (half + RING_BAND + ROW_SLACK) as i64;
        let row = start.1.round() as i64;
        let first = (row - reach).clamp(0, n as i64) as usize;
        let end = (row + reach + 1).clamp(first as i64, n as i64) as usize;
        let part = self.image_rows(system, f, z_um, first..end);
        let local = (start.0, start.1 - first as f64);
        // The frame's pixels on an image of the grid whose first row is `row0`.
        let frame = self.frame;
        let within = |img: &Image, row0: usize| {
            frame.map_or(Bounds::whole(img), |b| b.shifted(0, -(row0 as i64)))
        };
        let inside = |m: &Moment| {
            (first == 0 || m.window.y >= RING_BAND)
                && (end == n || m.window.y + m.window.h + RING_BAND <= part.nrows())
        };
        let polarity = self.polarity;
        match first_moment_within(
            &part,
            within(&part, first),
            polarity,
            local,
            half,
            iterations,
        ) {
            Some(m) if inside(&m) => Some(Moment {
                center_px: (m.center_px.0, m.center_px.1 + first as f64),
                ..m
            }),
            _ if first > 0 || end < n => {
                let whole = self.image(system, f, z_um);
                first_moment_within(&whole, within(&whole, 0), polarity, start, half, iterations)
            }
            other => other,
        }
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
                let half = self.reference_half_window;
                let m = self
                    .moment(system, f_ref, 0.0, self.origin, half, 3)?
                    .center_px;
                self.reference = Some((f_ref, m));
                m
            }
        };
        let start = (
            self.origin.0 + start_offset_px.0,
            self.origin.1 + start_offset_px.1,
        );
        let m1 = self.moment(system, f_led, z_um, start, self.half_window, 4)?;
        let d = self.pixel_um;
        Some(((m1.center_px.0 - m0.0) * d, (m1.center_px.1 - m0.1) * d))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibrate::shift::first_moment;
    use crate::optics::defocus_transfer;

    /// A square hole in a dark film: the calibration's usual feature.
    fn hole(n: usize, side: usize) -> Vec<Complex32> {
        let lo = n / 2 - side / 2;
        (0..n * n)
            .map(|i| {
                let (r, c) = (i / n, i % n);
                let inside = (lo..lo + side).contains(&r) && (lo..lo + side).contains(&c);
                Complex32::new(if inside { 1.0 } else { 0.3 }, 0.0)
            })
            .collect()
    }

    /// The direct model: the field times the tilted plane wave, through the pupil and
    /// the defocus, on the same grid.
    fn direct_image(
        field: &[Complex32],
        n: usize,
        system: &System,
        f: (f64, f64),
        z: f64,
    ) -> Vec<f32> {
        let d = system.sample_pixel_um();
        let mut buf: Vec<Complex32> = (0..n * n)
            .map(|i| {
                let (r, c) = ((i / n) as f64, (i % n) as f64);
                let ph = 2.0 * std::f64::consts::PI * (f.0 * c + f.1 * r) * d;
                field[i] * Complex32::new(ph.cos() as f32, ph.sin() as f32)
            })
            .collect();
        let mut fft = Fft2::new(n, n);
        fft.forward(&mut buf);
        for (i, v) in buf.iter_mut().enumerate() {
            let (fx, fy) = (bin_frequency(i % n, n, d), bin_frequency(i / n, n, d));
            *v *= if fx.hypot(fy) <= system.cutoff() {
                let (hr, hi) = defocus_transfer(fx, fy, z, system.wavelength_um);
                Complex32::new(hr as f32, hi as f32)
            } else {
                Complex32::default()
            };
        }
        fft.inverse(&mut buf);
        buf.iter().map(|v| v.norm_sqr()).collect()
    }

    #[test]
    fn moving_the_pupil_images_like_tilting_the_light() {
        // On whole bins the tilted plane wave is periodic on the grid, so the direct
        // model is exact there and both must agree to rounding.
        let system = System::paper();
        let n = 96;
        let d = system.sample_pixel_um();
        let field = hole(n, 14);
        let mut model = FeatureModel::from_field(field.clone(), n, Polarity::Bright, 20, d);
        for (bins, z) in [
            ((0.0, 0.0), 0.0),
            ((5.0, -3.0), 150.0),
            ((-9.0, 4.0), -220.0),
        ] {
            let f = (bins.0 / (n as f64 * d), bins.1 / (n as f64 * d));
            let want = direct_image(&field, n, &system, f, z);
            let got = model.image(&system, f, z);
            let peak = want.iter().copied().fold(0.0, f32::max);
            for (g, w) in got.iter().zip(&want) {
                assert!((g - w).abs() < 1e-4 * peak, "{bins:?} z {z}: {g} vs {w}");
            }
        }
    }

    #[test]
    fn the_moment_on_a_few_rows_is_the_moment_on_the_whole_grid() {
        let system = System::paper();
        let n = 128;
        let d = system.sample_pixel_um();
        let mut model = FeatureModel::from_field(hole(n, 16), n, Polarity::Bright, 22, d);
        let f = (0.031, -0.047);
        for start in [
            (64.0, 64.0),
            (70.0, 55.0),
            (64.0, 82.0),
            (64.0, 30.0),
            (64.0, 100.0),
        ] {
            let whole = model.image(&system, f, 200.0);
            let want = first_moment(&whole, Polarity::Bright, start, 22, 4).map(|m| m.center_px);
            let got = model
                .moment(&system, f, 200.0, start, 22, 4)
                .map(|m| m.center_px);
            match (got, want) {
                (Some(g), Some(w)) => assert!(
                    (g.0 - w.0).abs() < 1e-9 && (g.1 - w.1).abs() < 1e-9,
                    "from {start:?}: {g:?} vs {w:?}"
                ),
                other => assert_eq!(other.0.is_some(), other.1.is_some(), "from {start:?}"),
            }
        }
    }
}
