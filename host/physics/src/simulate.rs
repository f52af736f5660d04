//! The full wave-optics forward model (docs/dataset.md §2), used to make test data that the
//! calibrator and the reconstructor never share a shortcut with:
//! the sample is illuminated by the spherical wave of each LED (finite distance), the
//! exit field is propagated by the defocus with the angular spectrum, cut by the pupil,
//! sampled on the camera grid, and recorded with shot noise, read noise, an offset and
//! quantisation. The sample is larger than the field of view: a padded field is imaged
//! and the sensor region cropped.

use crate::frame::{Counts, LitFrame, Measured, Response};
use crate::optics::LedIndex;
use ndarray::Array2;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal, Poisson};
use rustfft::num_complex::Complex32;

use crate::fft::{bin_frequency, Fft2};
use crate::optics::{defocus_transfer, LedGeometry, System};
use crate::Image;

/// A complex sample transmission on the simulation grid, which covers the camera's
/// field plus a margin, `upsample` times finer than the camera's sample-plane pixel.
#[derive(Clone)]
pub struct ObjectField {
    /// Transmission, row-major `n × n`.
    pub field: Vec<Complex32>,
    /// Grid size (`(camera + 2·pad) · upsample`).
    pub n: usize,
    /// Camera width and height in pixels (square sensors only).
    pub camera: usize,
    /// Margin around the camera field, camera pixels.
    pub pad: usize,
    /// Simulation pixels per camera pixel.
    pub upsample: usize,
    /// Camera pixel in the sample plane, µm.
    pub camera_pixel_um: f64,
}

impl ObjectField {
    fn blank(
        system: &System,
        camera: usize,
        pad: usize,
        upsample: usize,
        value: Complex32,
    ) -> Self {
        let n = (camera + 2 * pad) * upsample;
        Self {
            field: vec![value; n * n],
            n,
            camera,
            pad,
            upsample,
            camera_pixel_um: system.sample_pixel_um(),
        }
    }

    /// Simulation pixel spacing, µm.
    pub fn pitch_um(&self) -> f64 {
        self.camera_pixel_um / self.upsample as f64
    }

    /// Sample-plane position of simulation pixel (i, j) = (row, col), µm.
    pub fn position(&self, row: usize, col: usize) -> (f64, f64) {
        let d = self.pitch_um();
        (
            (col as f64 - (self.n / 2) as f64) * d,
            (row as f64 - (self.n / 2) as f64) * d,
        )
    }

    /// An opaque mask with one square hole of side `side_um` centred at (x, y) µm;
    /// the mask transmits `background` in amplitude. Edges are anti-aliased by exact
    /// area coverage.
    pub fn square_hole(
        system: &System,
        camera: usize,
        pad: usize,
        upsample: usize,
        side_um: f64,
        center_um: (f64, f64),
        background: f32,
    ) -> Self {
        let mut o = Self::blank(
            system,
            camera,
            pad,
            upsample,
            Complex32::new(background, 0.0),
        );
        let d = o.pitch_um();
        let half = side_um / 2.0;
        let overlap =
            |c: f64, lo: f64, hi: f64| ((c + d / 2.0).min(hi) - (c - d / 2.0).max(lo)).max(0.0) / d;
        for r in 0..o.n {
            for c in 0..o.n {
                let (x, y) = o.position(r, c);
                let cover = overlap(x, center_um.0 - half, center_um.0 + half)
                    * overlap(y, center_um.1 - half, center_um.1 + half);
                if cover > 0.0 {
                    let t = background + (1.0 - background) * cover as f32;
                    o.field[r * o.n + c] = Complex32::new(t, 0.0);
                }
            }
        }
        o.taper_edges();
        o
    }

    /// A complex test sample with amplitude and phase: soft "cells" of varying
    /// absorption and optical thickness, and bar groups from coarse to finer than the
    /// objective resolves, so a reconstruction's resolution gain can be measured.
    pub fn test_sample(
        system: &System,
        camera: usize,
        pad: usize,
        upsample: usize,
        seed: u64,
    ) -> Self {
        Self::sample(system, camera, pad, upsample, seed, SampleKind::Cells)
    }

    /// A sample of `kind` (cells of random place and size from `seed`).
    pub fn sample(
        system: &System,
        camera: usize,
        pad: usize,
        upsample: usize,
        seed: u64,
        kind: SampleKind,
    ) -> Self {
        Self::sample_in_light(system, camera, pad, upsample, seed, kind, 0.47)
    }

    /// [`Self::sample`] as light of `wavelength_um` sees it: the same cells and bars,
    /// the cells' dye absorbing as [`crate::color::stain_absorption`] says and their
    /// phase scaled as 1/λ (a fixed optical path); the metal bars absorb alike at every
    /// wavelength. At 0.47 µm it is [`Self::sample`].
    pub fn sample_in_light(
        system: &System,
        camera: usize,
        pad: usize,
        upsample: usize,
        seed: u64,
        kind: SampleKind,
        wavelength_um: f64,
    ) -> Self {
        Self::cells_in_light(
            system,
            camera,
            pad,
            upsample,
            seed,
            kind,
            wavelength_um,
            kind.cells().0,
        )
    }

    /// A slide larger than one field (`side`² camera pixels): the cells of `kind` as
    /// densely as [`Self::sample`] places them on a 256² field, so that every field of
    /// a scan sees as much as a single-field sample does.
    pub fn slide(
        system: &System,
        side: usize,
        pad: usize,
        upsample: usize,
        seed: u64,
        kind: SampleKind,
    ) -> Self {
        let reference = (256.0 + 2.0 * 48.0) * system.sample_pixel_um();
        let extent = (side + 2 * pad) as f64 * system.sample_pixel_um();
        let count = (kind.cells().0 as f64 * (extent / reference).powi(2)).round() as usize;
        Self::cells_in_light(system, side, pad, upsample, seed, kind, 0.47, count.max(1))
    }

    #[allow(clippy::too_many_arguments)]
    fn cells_in_light(
        system: &System,
        camera: usize,
        pad: usize,
        upsample: usize,
        seed: u64,
        kind: SampleKind,
        wavelength_um: f64,
        count: usize,
    ) -> Self {
        let stain = crate::color::stain_absorption(wavelength_um);
        let phase_scale = crate::color::phase_at(1.0, wavelength_um);
        let mut o = Self::blank(system, camera, pad, upsample, Complex32::new(1.0, 0.0));
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let extent = (o.n as f64) * o.pitch_um() / 2.0;
        let (_, absorption, thickness) = kind.cells();
        let cells: Vec<(f64, f64, f64, f64, f64)> = (0..count)
            .map(|_| {
                (
                    rng.gen_range(-extent..extent),
                    rng.gen_range(-extent..extent),
                    rng.gen_range(4.0..14.0),
                    rng.gen_range(absorption.clone()),
                    rng.gen_range(thickness.clone()),
                )
            })
            .collect();
        let bars = kind != SampleKind::WeakPhase;
        let field_half = camera as f64 * o.camera_pixel_um / 2.0;
        // Bar groups inside the field: periods from 4 µm down to 0.9 µm (the objective
        // alone resolves λ/NA ≈ 4.7 µm at NA 0.1, λ 0.47).
        let periods = [4.0, 3.0, 2.2, 1.6, 1.2, 0.9];
        // Each cell over its own neighbourhood only (3 radii: its weight exp(−d⁴) is
        // below 1e-35 beyond), in the cells' order, so a slide of thousands of cells
        // costs what its area does.
        let mut absorbs = vec![0.0f64; o.n * o.n];
        let mut phases = vec![0.0f64; o.n * o.n];
        let d = o.pitch_um();
        let half = (o.n / 2) as f64;
        for &(cx, cy, rad, a, p) in &cells {
            let reach = 3.0 * rad / d;
            let (c0, c1) = (
                (cx / d + half - reach).floor().max(0.0) as usize,
                ((cx / d + half + reach).ceil() as usize + 1).min(o.n),
            );
            let (r0, r1) = (
                (cy / d + half - reach).floor().max(0.0) as usize,
                ((cy / d + half + reach).ceil() as usize + 1).min(o.n),
            );
            for r in r0..r1 {
                for c in c0..c1 {
                    let (x, y) = o.position(r, c);
                    let d2 = ((x - cx).powi(2) + (y - cy).powi(2)) / (rad * rad);
                    let w = (-d2 * d2).exp();
                    absorbs[r * o.n + c] += a * w * stain;
                    phases[r * o.n + c] += p * w * phase_scale;
                }
            }
        }
        for r in 0..o.n {
            for c in 0..o.n {
                let (x, y) = o.position(r, c);
                let mut absorb = absorbs[r * o.n + c];
                let phase = phases[r * o.n + c];
                // bars: a column of groups along x, in the upper-left quadrant
                let gx = x + field_half * 0.7;
                let gy = y + field_half * 0.7;
                for (k, &period) in periods.iter().enumerate() {
                    let y0 = k as f64 * 7.0;
                    let in_group = gy >= y0 && gy < y0 + 5.0 && gx >= 0.0 && gx < 5.0 * period;
                    if bars && in_group && (gx / period).fract() < 0.5 {
                        absorb += 0.6;
                    }
                }
                let amp = (-absorb).exp().max(0.05);
                o.field[r * o.n + c] = Complex32::from_polar(amp as f32, phase as f32);
            }
        }
        o.taper_edges();
        o
    }

    /// Fade the sample to opaque over the outer half of the margin (raised cosine). The
    /// grid is periodic; without this its boundary would be a sharp edge whose
    /// diffraction rings into the field. A smooth taper's spectrum stays inside the
    /// pupil, so the field sees a sample that simply continues beyond it.
    fn taper_edges(&mut self) {
        let width = (self.pad * self.upsample / 2).max(1);
        let n = self.n;
        let ramp: Vec<f32> = (0..n)
            .map(|i| {
                let d = i.min(n - 1 - i);
                if d >= width {
                    1.0
                } else {
                    0.5 * (1.0 - (std::f32::consts::PI * d as f32 / width as f32).cos())
                }
            })
            .collect();
        for r in 0..n {
            for c in 0..n {
                self.field[r * n + c] *= ramp[r] * ramp[c];
            }
        }
    }

    /// The part of this (larger) sample a `camera`² field with margin `pad` sees when
    /// its centre is at `centre_um` (the sample position of simulation pixel
    /// (n/2, n/2) is 0): the sample continues across the window's margin, which is
    /// faded as every sample's is. The centre is rounded to the simulation grid; the
    /// centre actually used is returned. `None` if the window leaves the sample.
    pub fn window(
        &self,
        centre_um: (f64, f64),
        camera: usize,
        pad: usize,
    ) -> Option<(Self, (f64, f64))> {
        let m = (camera + 2 * pad) * self.upsample;
        let d = self.pitch_um();
        let col = (centre_um.0 / d).round() as i64 + (self.n / 2) as i64;
        let row = (centre_um.1 / d).round() as i64 + (self.n / 2) as i64;
        let (c0, r0) = (col - (m / 2) as i64, row - (m / 2) as i64);
        if c0 < 0 || r0 < 0 || c0 as usize + m > self.n || r0 as usize + m > self.n {
            return None;
        }
        let (c0, r0) = (c0 as usize, r0 as usize);
        let mut field = Vec::with_capacity(m * m);
        for r in r0..r0 + m {
            field.extend_from_slice(&self.field[r * self.n + c0..r * self.n + c0 + m]);
        }
        let mut w = Self {
            field,
            n: m,
            camera,
            pad,
            upsample: self.upsample,
            camera_pixel_um: self.camera_pixel_um,
        };
        w.taper_edges();
        let used = (
            (col - (self.n / 2) as i64) as f64 * d,
            (row - (self.n / 2) as i64) as f64 * d,
        );
        Some((w, used))
    }

    /// The sample between `(x0, y0)` (its first pixel's position, µm) and `w × h`
    /// simulation pixels on, or `None` where that leaves the grid.
    pub fn region(&self, x0_um: f64, y0_um: f64, w: usize, h: usize) -> Option<Array2<Complex32>> {
        let d = self.pitch_um();
        let c0 = (x0_um / d).round() as i64 + (self.n / 2) as i64;
        let r0 = (y0_um / d).round() as i64 + (self.n / 2) as i64;
        if c0 < 0 || r0 < 0 || c0 as usize + w > self.n || r0 as usize + h > self.n {
            return None;
        }
        let (c0, r0) = (c0 as usize, r0 as usize);
        Some(Array2::from_shape_fn((h, w), |(r, c)| {
            self.field[(r0 + r) * self.n + c0 + c]
        }))
    }

    /// The ground truth on the camera field, cropped from the simulation grid.
    pub fn crop_to_camera(&self) -> Array2<Complex32> {
        let m = self.camera * self.upsample;
        let off = self.pad * self.upsample;
        Array2::from_shape_fn((m, m), |(r, c)| self.field[(r + off) * self.n + c + off])
    }
}

/// What a simulated sample is made of: the test sample and two extremes of what
/// microscopists image, so checks that judge the frames are tried on more than one.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SampleKind {
    /// Soft cells of moderate absorption (0.1–0.5) and thickness (0.4–1.6 rad), with
    /// bar groups from coarse to finer than the objective resolves.
    #[default]
    Cells,
    /// Unstained cells: phase only, 0.05–0.3 rad, no bars (frames of a few % contrast).
    WeakPhase,
    /// Stained tissue: twice as many cells, strongly absorbing (0.5–2), thin (0–0.3
    /// rad), with the bars.
    Stained,
}

impl SampleKind {
    /// Every kind, for sweeps.
    pub const ALL: [SampleKind; 3] = [Self::Cells, Self::WeakPhase, Self::Stained];

    /// Cells: how many, absorption range, phase range (rad).
    fn cells(self) -> (usize, std::ops::Range<f64>, std::ops::Range<f64>) {
        match self {
            Self::Cells => (40, 0.1..0.5, 0.4..1.6),
            // An empty absorption range would panic: an absorption this small is none.
            Self::WeakPhase => (40, 0.0..1e-9, 0.05..0.3),
            Self::Stained => (80, 0.5..2.0, 0.0..0.3),
        }
    }
}

/// Reusable FFT plans for one object grid.
pub struct Renderer {
    /// Spherical waves from each LED (true), or plane waves with the direction the LED
    /// has at the field centre (false; for comparisons only).
    pub spherical: bool,
    big: Fft2,
    small: Fft2,
    buf: Vec<Complex32>,
    low: Vec<Complex32>,
    /// The simulation grid's columns whose frequencies the camera grid holds (its low
    /// half, then its high half, ascending): the only ones the forward transform
    /// finishes, a quarter of them at 4× oversampling (37 % of that transform saved).
    kept_cols: Vec<usize>,
}

impl Renderer {
    /// Plans for `object`'s grid.
    pub fn new(object: &ObjectField) -> Self {
        let m = object.n / object.upsample;
        Self {
            spherical: true,
            big: Fft2::new(object.n, object.n),
            small: Fft2::new(m, m),
            buf: vec![Complex32::default(); object.n * object.n],
            low: vec![Complex32::default(); m * m],
            kept_cols: camera_band(object.n, m),
        }
    }

    /// Noise-free camera intensity for LED (`row`, `col`) with the sample moved by
    /// `defocus_um` toward the LEDs. 1.0 is the intensity a clear sample gives.
    pub fn render(
        &mut self,
        system: &System,
        geometry: &LedGeometry,
        object: &ObjectField,
        led: LedIndex,
        defocus_um: f64,
    ) -> Image {
        self.render_from(system, geometry.led_position_3d_mm(led), object, defocus_um)
    }

    /// Carry the exit field in `buf` over the defocus on the whole simulation grid,
    /// then put the pupil's chirp exp(i·`chirp`·|x|²) on it, at the focal plane.
    fn defocus_then_chirp(
        &mut self,
        object: &ObjectField,
        defocus_um: f64,
        wavelength_um: f64,
        chirp: f64,
    ) {
        let n = object.n;
        let d = object.pitch_um();
        self.big.forward(&mut self.buf);
        for ky in 0..n {
            let fy = bin_frequency(ky, n, d);
            for kx in 0..n {
                let fx = bin_frequency(kx, n, d);
                let (hr, hi) = defocus_transfer(fx, fy, defocus_um, wavelength_um);
                self.buf[ky * n + kx] *= Complex32::new(hr as f32, hi as f32);
            }
        }
        self.big.inverse(&mut self.buf);
        for r in 0..n {
            for c in 0..n {
                let (x, y) = object.position(r, c);
                let (s, co) = sin_cos(chirp * (x * x + y * y));
                self.buf[r * n + c] *= Complex32::new(co, s);
            }
        }
    }

    /// [`Self::render`] for an LED at `led_mm` = (x, y, distance below the sample), mm:
    /// a board whose LEDs are off their grid.
    pub fn render_from(
        &mut self,
        system: &System,
        led_mm: (f64, f64, f64),
        object: &ObjectField,
        defocus_um: f64,
    ) -> Image {
        let n = object.n;
        let k = 2.0 * std::f64::consts::PI / system.wavelength_um;
        let (lx, ly, h) = (led_mm.0 * 1e3, led_mm.1 * 1e3, led_mm.2 * 1e3);
        let r0 = (lx * lx + ly * ly + h * h).sqrt();
        // An entrance pupil at p above the sample: the exit field reaches it by Fresnel
        // propagation, ∝ F[u·exp(iπ|x|²/(λp))] at frequency ξ/(λp), where the
        // aperture of radius p·NA cuts it (the outer quadratic phases do not change
        // the intensity). So the chirp goes on the exit field before the pupil below.
        // A defocused sample's exit field first travels the defocus to the focal plane,
        // which the pupil's distance is measured from: defocus, then chirp (the other
        // order would carry the chirp's tilt x/p along the defocus, a magnification
        // the stage's move does not make).
        let to_pupil = system.entrance_pupil_mm.map_or(0.0, |p| 0.5 / (p * 1e3));
        let defocus_first = to_pupil != 0.0 && defocus_um != 0.0;
        // Spherical wave from the LED, phase relative to the field centre (f64, then
        // reduced: k·R is ~10⁶ rad).
        // Row by row: the phases first, from integer indices, in a loop the compiler
        // keeps in vector registers, then their sines and cosines (libm's). One loop
        // with the libm call in it ran one pixel at a time: this is 30 % of a frame.
        // The same sums in the same order as the plain loop: the same bits.
        let (d, centre) = (object.pitch_um(), (n / 2) as f64);
        let chirp = if defocus_first { 0.0 } else { to_pupil };
        let mut phases = vec![0.0f64; n];
        let rows = self
            .buf
            .chunks_exact_mut(n)
            .zip(object.field.chunks_exact(n));
        for (r, (row, field)) in rows.enumerate() {
            let y = (r as f64 - centre) * d;
            let (dy2, h2) = ((y - ly).powi(2), h * h);
            if self.spherical {
                for (c, p) in phases.iter_mut().enumerate() {
                    let x = (c as u32 as f64 - centre) * d;
                    *p = k * (((x - lx).powi(2) + dy2 + h2).sqrt() - r0 + chirp * (x * x + y * y));
                }
            } else {
                for (c, p) in phases.iter_mut().enumerate() {
                    let x = (c as u32 as f64 - centre) * d;
                    *p = k * ((x * (-lx) + y * (-ly)) / r0 + chirp * (x * x + y * y));
                }
            }
            for ((out, &f), &p) in row.iter_mut().zip(field).zip(&phases) {
                let (s, co) = sin_cos(p);
                *out = f * Complex32::new(co, s);
            }
        }
        if defocus_first {
            self.defocus_then_chirp(object, defocus_um, system.wavelength_um, k * to_pupil);
        }
        self.big.forward_wanted_cols(&mut self.buf, &self.kept_cols);
        // Keep the frequencies the camera grid can hold; apply pupil and defocus there.
        let m = n / object.upsample;
        let d_cam = object.camera_pixel_um;
        let cutoff2 = system.cutoff().powi(2);
        let scale = 1.0 / (object.upsample * object.upsample) as f32;
        for ky in 0..m {
            let fy = bin_frequency(ky, m, d_cam);
            let by = if ky < m / 2 { ky } else { n - (m - ky) };
            for kx in 0..m {
                let fx = bin_frequency(kx, m, d_cam);
                let bx = if kx < m / 2 { kx } else { n - (m - kx) };
                let v = if fx * fx + fy * fy <= cutoff2 {
                    let z = if defocus_first { 0.0 } else { defocus_um };
                    let (hr, hi) = defocus_transfer(fx, fy, z, system.wavelength_um);
                    self.buf[by * n + bx] * Complex32::new(hr as f32, hi as f32) * scale
                } else {
                    Complex32::default()
                };
                self.low[ky * m + kx] = v;
            }
        }
        self.small.inverse(&mut self.low);
        let (w, pad) = (object.camera, object.pad);
        Array2::from_shape_fn((w, w), |(r, c)| {
            self.low[(r + pad) * m + c + pad].norm_sqr()
        })
    }
}

/// The bins of an `n`-point transform that an `m`-point one holds, ascending: the
/// simulation grid's bin of each camera bin `k` is `k` below `m / 2`, else `n - (m - k)`.
fn camera_band(n: usize, m: usize) -> Vec<usize> {
    (0..m / 2).chain(n - (m - m / 2)..n).collect()
}

/// The sine and cosine of `phase` (f64: k·R is up to ~10⁶ rad), in f32, the field's own
/// precision: the phase is brought within ±π in f64 first, then f32's sine and cosine
/// (half the cost of f64's) take it. Rounding the turns off costs a multiply:
/// `rem_euclid` is a software `fmod`, and `round` a libm call on baseline x86-64;
/// adding and taking away 1.5·2⁵² rounds to a whole number in two additions (exact
/// below 2⁵¹ turns).
#[inline]
fn sin_cos(phase: f64) -> (f32, f32) {
    use std::f64::consts::TAU;
    const ROUND: f64 = 6_755_399_441_055_744.0;
    let turns = (phase * (1.0 / TAU) + ROUND) - ROUND;
    ((phase - turns * TAU) as f32).sin_cos()
}

/// A camera's response and noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Photo-electrons per ms at intensity 1.0.
    pub electrons_per_ms: f64,
    /// Read noise, electrons rms.
    pub read_noise_e: f64,
    /// Digital numbers per electron.
    pub gain_dn_per_e: f64,
    /// Offset added to every pixel, DN.
    pub dark_level_dn: f64,
    /// ADC bits.
    pub bit_depth: u32,
    /// Whether to add noise at all.
    pub noisy: bool,
    /// Light that reaches the sensor whatever the LED (room light, the glow of the
    /// board, reflections in the tube), as an intensity added to every pixel (1.0 = a
    /// clear sample under the on-axis LED). It adds up over long dark-field exposures
    /// into the few-count background that real dark-field frames sit on.
    pub stray_light: f64,
    /// Frames stored for display with this gamma, as camera software exporting 8-bit
    /// images for viewing does: the counts c (offset included) are stored as
    /// F·(c/F)^(1/γ), F full scale, rounded (None: raw counts).
    pub display_gamma: Option<f64>,
}

impl Camera {
    /// A typical 12-bit machine-vision sensor: 2.4 e⁻ read noise, 100 DN offset.
    pub fn realistic() -> Self {
        Self {
            electrons_per_ms: 1500.0,
            read_noise_e: 2.4,
            gain_dn_per_e: 0.2,
            dark_level_dn: 100.0,
            bit_depth: 12,
            noisy: true,
            stray_light: 0.0,
            display_gamma: None,
        }
    }

    /// The 8-bit camera of a home-built rig, modelled on the one behind the vendored
    /// USAF set (`data/zuo-usaf-11x11`): 3.5 DN read noise about an offset of 2 DN, so
    /// that clipping at zero leaves a dark frame skewed as that set's are (about a third
    /// of the pixels at 0, a mean of 2–3 counts, a tail to ~15). 0.1 DN per electron
    /// and 50 e⁻ per ms: a clear bright-field frame reaches 200 DN in ~40 ms with ~2 %
    /// shot noise (the 12-bit sensor's 1500 e⁻/ms would saturate 8 bits within the 2 ms
    /// auto-exposure minimum). With dim dark-field frames
    /// ([`Self::dim_dark_field_exposure`], ~25 counts at the peak, as in that set) the
    /// noise is a large part of every dark-field signal.
    pub fn eight_bit() -> Self {
        Self {
            electrons_per_ms: 50.0,
            read_noise_e: 35.0,
            gain_dn_per_e: 0.1,
            dark_level_dn: 2.0,
            bit_depth: 8,
            noisy: true,
            stray_light: 0.0,
            display_gamma: None,
        }
    }

    /// The same sensor without noise (quantisation still applies).
    pub fn noiseless() -> Self {
        Self {
            noisy: false,
            ..Self::realistic()
        }
    }

    /// Largest value the ADC gives.
    pub fn max_dn(&self) -> f64 {
        ((1u64 << self.bit_depth) - 1) as f64
    }

    /// Auto-exposure as a camera does it: the brightest pixel of `intensity` at 80 % of
    /// full scale, from 2 ms (bright field) up to 1 s (dark field).
    pub fn auto_exposure(&self, intensity: &Image) -> f64 {
        let peak = intensity.iter().copied().fold(0.0f32, f32::max) as f64;
        self.exposure_for(peak, 0.8, 2.0, 1000.0)
    }

    /// Auto-exposure with dim dark-field frames, as a camera set up for the bright
    /// field records them: frames whose brightest pixel is below half the clear level
    /// (dark field) get the exposure that brings that pixel to `dark_field_peak_dn`
    /// counts above the offset (at least 1 ms); bright-field frames as
    /// [`Self::auto_exposure`].
    pub fn dim_dark_field_exposure(&self, intensity: &Image, dark_field_peak_dn: f64) -> f64 {
        let peak = intensity.iter().copied().fold(0.0f32, f32::max) as f64;
        if peak >= 0.5 {
            return self.auto_exposure(intensity);
        }
        let fill = dark_field_peak_dn / (self.max_dn() - self.dark_level_dn);
        self.exposure_for(peak, fill, 1.0, 1000.0)
    }

    /// The longest exposure (ms, to 0.01 ms) that keeps `intensity`'s brightest
    /// pixel within 80 % of full scale, however short: a multiplexed frame whose LEDs
    /// together outshine the bright-field floor of [`Self::auto_exposure`].
    pub fn unsaturated_exposure(&self, intensity: &Image) -> f64 {
        let peak = intensity.iter().copied().fold(0.0f32, f32::max) as f64;
        let usable = (self.max_dn() - self.dark_level_dn) * 0.8;
        let ms = usable / (peak.max(1e-9) * self.electrons_per_ms * self.gain_dn_per_e);
        ((ms * 100.0).floor() / 100.0).clamp(0.01, 1000.0)
    }

    /// The dark-subtracted level at which pixels saturate.
    pub fn saturation(&self) -> f32 {
        (self.max_dn() - self.dark_level_dn) as f32
    }

    /// The exposure (ms) that brings a peak intensity to `fill` of full scale, in
    /// whole milliseconds within [min_ms, max_ms].
    pub fn exposure_for(&self, peak_intensity: f64, fill: f64, min_ms: f64, max_ms: f64) -> f64 {
        let usable = (self.max_dn() - self.dark_level_dn) * fill;
        let ms = usable / (peak_intensity.max(1e-9) * self.electrons_per_ms * self.gain_dn_per_e);
        ms.floor().clamp(min_ms, max_ms)
    }

    /// Record `intensity` for `exposure_ms`: shot noise, read noise, offset, rounding
    /// and clipping to the ADC range. Returns counts (DN).
    ///
    /// The noise stream is a concrete [`StdRng`], not any `Rng`: a generic would be
    /// compiled into each caller, at the caller's optimisation, and the virtual camera
    /// (an unoptimised crate in the test build) spent a third of its time on this
    /// function's arithmetic there.
    pub fn record(&self, intensity: &Image, exposure_ms: f64, rng: &mut StdRng) -> Array2<u16> {
        let read = Normal::new(0.0, self.read_noise_e.max(1e-12)).expect("finite read noise");
        let max = self.max_dn();
        intensity.mapv(|i| {
            let mean_e =
                ((i as f64).max(0.0) + self.stray_light) * self.electrons_per_ms * exposure_ms;
            let e = if self.noisy {
                let shot = if mean_e > 0.0 {
                    Poisson::new(mean_e)
                        .map(|p| p.sample(rng))
                        .unwrap_or(mean_e)
                } else {
                    0.0
                };
                shot + read.sample(rng)
            } else {
                mean_e
            };
            let counts = (e * self.gain_dn_per_e + self.dark_level_dn).clamp(0.0, max);
            let stored = match self.display_gamma {
                // The sensor's own ADC rounds first; the display encoding is applied
                // to its whole counts.
                Some(gamma) => max * (counts.round() / max).powf(1.0 / gamma),
                None => counts,
            };
            stored.round() as u16
        })
    }

    /// The offset as stored: encoded like the pixels when the frames are stored for
    /// display (a dataset states its dark level in stored counts).
    pub fn stored_dark_level(&self) -> f64 {
        match self.display_gamma {
            Some(gamma) => self.max_dn() * (self.dark_level_dn / self.max_dn()).powf(1.0 / gamma),
            None => self.dark_level_dn,
        }
    }

    /// How the stored counts stand for light ([`crate::frame::Response`]).
    pub fn response(&self) -> Response {
        match self.display_gamma {
            Some(gamma) => Response::Gamma {
                gamma: gamma as f32,
                full_scale: self.max_dn() as f32,
            },
            None => Response::Linear,
        }
    }
}

/// One simulated frame.
#[derive(Debug, Clone)]
pub struct SimFrame {
    /// LED (row, col) lit: the first of a multiplexed frame's.
    pub led: LedIndex,
    /// The other LEDs lit in the same frame (multiplexed illumination); empty for one.
    pub also: Vec<LedIndex>,
    /// Sample displacement toward the LEDs, µm.
    pub defocus_um: f64,
    /// Exposure, ms.
    pub exposure_ms: f64,
    /// Camera counts.
    pub counts: Array2<u16>,
}

impl SimFrame {
    /// The frame as measured by `camera` (its dark level), for the one conversion to
    /// intensity in [`crate::frame`].
    pub fn measured(&self, camera: &Camera) -> Measured<'_> {
        Measured {
            counts: Counts::U16(self.counts.view()),
            response: camera.response(),
            dark_level: camera.dark_level_dn as f32,
            exposure_ms: self.exposure_ms as f32,
            floor: 0.0,
            soft_floor: false,
            band: 0.0,
        }
    }

    /// The frame as measured by `camera`, with its LED: what a reconstruction takes.
    pub fn lit(&self, camera: &Camera) -> LitFrame<'_> {
        LitFrame {
            led: self.led,
            also: &self.also,
            measured: self.measured(camera),
        }
    }
}

/// Every LED of `geometry` once, in focus, each frame auto-exposed
/// ([`Camera::auto_exposure`]): the acquisition reconstructions are tested on.
pub fn acquire_in_focus(
    system: &System,
    geometry: &LedGeometry,
    object: &ObjectField,
    camera: &Camera,
    seed: u64,
) -> Vec<SimFrame> {
    let shots: Vec<(LedIndex, f64)> = geometry.leds().into_iter().map(|l| (l, 0.0)).collect();
    acquire(
        system,
        geometry,
        object,
        &shots,
        camera,
        |img| camera.auto_exposure(img),
        seed,
    )
}

/// Render and record `leds` (each with its defocus) in parallel, deterministically
/// for a given seed: frame `k` uses its own random stream.
pub fn acquire(
    system: &System,
    geometry: &LedGeometry,
    object: &ObjectField,
    shots: &[(LedIndex, f64)],
    camera: &Camera,
    exposure: impl Fn(&Image) -> f64 + Sync,
    seed: u64,
) -> Vec<SimFrame> {
    acquire_from(
        system,
        &|led| geometry.led_position_3d_mm(led),
        object,
        shots,
        camera,
        exposure,
        seed,
    )
}

/// [`acquire`] from a board that places each LED itself (x, y, distance below the
/// sample, mm): LEDs off their grid, as real boards have them.
pub fn acquire_from(
    system: &System,
    board: &(dyn Fn(LedIndex) -> (f64, f64, f64) + Sync),
    object: &ObjectField,
    shots: &[(LedIndex, f64)],
    camera: &Camera,
    exposure: impl Fn(&Image) -> f64 + Sync,
    seed: u64,
) -> Vec<SimFrame> {
    use rayon::prelude::*;
    shots
        .par_iter()
        .enumerate()
        .map_init(
            || Renderer::new(object),
            |renderer, (k, &(led, defocus_um))| {
                let intensity = renderer.render_from(system, board(led), object, defocus_um);
                let exposure_ms = exposure(&intensity);
                SimFrame {
                    led,
                    also: vec![],
                    defocus_um,
                    exposure_ms,
                    counts: record(camera, &intensity, exposure_ms, seed, k),
                }
            },
        )
        .collect()
}

/// `intensity` recorded by `camera` for `exposure_ms`, with the noise of frame `k`'s
/// own random stream of `seed` (frames rendered in parallel stay deterministic).
fn record(
    camera: &Camera,
    intensity: &Image,
    exposure_ms: f64,
    seed: u64,
    k: usize,
) -> Array2<u16> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(
        seed ^ (0x9E37_79B9_7F4A_7C15u64.wrapping_mul(k as u64 + 1)),
    );
    camera.record(intensity, exposure_ms, &mut rng)
}

/// Frames each lit by a set of LEDs at once (multiplexed illumination), in focus,
/// from a board that places each LED itself (as [`acquire_from`]): the LEDs are
/// mutually incoherent, so a frame's intensity is the sum of the intensities each LED
/// alone gives, each rendered by the full wave-optics model, and the sum is recorded
/// once with the camera's noise. `exposure(sum, each)` gives each frame's exposure
/// from the summed intensity and each LED's own.
pub fn acquire_sets(
    system: &System,
    board: &(dyn Fn(LedIndex) -> (f64, f64, f64) + Sync),
    object: &ObjectField,
    sets: &[Vec<LedIndex>],
    camera: &Camera,
    exposure: impl Fn(&Image, &[Image]) -> f64 + Sync,
    seed: u64,
) -> Vec<SimFrame> {
    use rayon::prelude::*;
    sets.par_iter()
        .enumerate()
        .filter(|(_, set)| !set.is_empty())
        .map_init(
            || Renderer::new(object),
            |renderer, (k, set)| {
                let each: Vec<Image> = set
                    .iter()
                    .map(|&led| renderer.render_from(system, board(led), object, 0.0))
                    .collect();
                let mut intensity = each[0].clone();
                for one in &each[1..] {
                    intensity += one;
                }
                let exposure_ms = exposure(&intensity, &each);
                SimFrame {
                    led: set[0],
                    also: set[1..].to_vec(),
                    defocus_um: 0.0,
                    exposure_ms,
                    counts: record(camera, &intensity, exposure_ms, seed, k),
                }
            },
        )
        .collect()
}

/// One colour channel's frames, one per shot (LED and defocus), from a board that
/// places each LED itself: the LED's light is not one line but a spectrum, so each
/// frame is the sum, weighted by the spectrum, of the full wave-optics model's
/// intensities at each of its wavelengths (`lights`: wavelength µm, weight, and the
/// sample as that wavelength sees it), recorded once with the camera's noise. Each
/// shot's defocus has `focal_shift_um` added (the objective's chromatic focal shift).
/// Deterministic for a seed, as [`acquire_from`].
#[allow(clippy::too_many_arguments)]
pub fn acquire_spectral(
    system: &System,
    board: &(dyn Fn(LedIndex) -> (f64, f64, f64) + Sync),
    lights: &[(f64, f64, ObjectField)],
    focal_shift_um: f64,
    shots: &[(LedIndex, f64)],
    camera: &Camera,
    exposure: impl Fn(&Image) -> f64 + Sync,
    seed: u64,
) -> Vec<SimFrame> {
    use rayon::prelude::*;
    let Some((_, _, first)) = lights.first() else {
        return vec![];
    };
    shots
        .par_iter()
        .enumerate()
        .map_init(
            || Renderer::new(first),
            |renderer, (k, &(led, defocus_um))| {
                let mut intensity: Option<Image> = None;
                for (wavelength_um, weight, object) in lights {
                    let at = System {
                        wavelength_um: *wavelength_um,
                        ..*system
                    };
                    let one =
                        renderer.render_from(&at, board(led), object, defocus_um + focal_shift_um)
                            * (*weight as f32);
                    intensity = Some(match intensity {
                        Some(sum) => sum + one,
                        None => one,
                    });
                }
                let intensity = intensity.unwrap_or_default();
                let exposure_ms = exposure(&intensity);
                SimFrame {
                    led,
                    also: vec![],
                    defocus_um,
                    exposure_ms,
                    counts: record(camera, &intensity, exposure_ms, seed, k),
                }
            },
        )
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sample_in_light_of_047_um_is_the_sample() {
        let s = System::paper();
        let a = ObjectField::sample(&s, 32, 8, 2, 3, SampleKind::Stained);
        let b = ObjectField::sample_in_light(&s, 32, 8, 2, 3, SampleKind::Stained, 0.47);
        assert_eq!(a.field, b.field);
        let red = ObjectField::sample_in_light(&s, 32, 8, 2, 3, SampleKind::Stained, 0.6225);
        let mean_amp = |o: &ObjectField| o.field.iter().map(|c| c.norm()).sum::<f32>();
        assert!(
            mean_amp(&red) > mean_amp(&a),
            "the stain absorbs less red than blue"
        );
    }

    fn system() -> System {
        System::paper()
    }

    fn geometry() -> LedGeometry {
        LedGeometry::paper()
    }

    #[test]
    fn a_clear_sample_images_to_unit_intensity() {
        let s = system();
        let o = ObjectField::square_hole(&s, 64, 48, 2, 1000.0, (0.0, 0.0), 1.0);
        let mut r = Renderer::new(&o);
        let img = r.render(&s, &geometry(), &o, LedIndex::new(10, 12), 0.0);
        for v in img.iter() {
            assert!((v - 1.0).abs() < 1e-2, "{v}");
        }
    }

    #[test]
    fn dark_field_leds_give_dark_frames() {
        let s = system();
        let o = ObjectField::square_hole(&s, 64, 48, 2, 1000.0, (0.0, 0.0), 1.0);
        let mut r = Renderer::new(&o);
        let img = r.render(&s, &geometry(), &o, LedIndex::new(10, 16), 0.0);
        assert!(
            img.iter().all(|&v| v < 1e-3),
            "an empty sample scatters nothing into the pupil"
        );
    }

    #[test]
    fn through_a_non_telecentric_objective_each_point_sees_the_leds_its_chief_ray_sees() {
        // The simulator cuts the Fresnel-propagated field at an entrance pupil 5 mm up;
        // the reconstruction's rule says a point x is lit by an LED within the NA of
        // its chief ray (aimed at that pupil). LED (10, 14), 10 mm off the axis, is
        // dark everywhere for a telecentric objective; here the rule puts its edge
        // inside the field. Two independent models: the edge the simulator draws (a
        // Fresnel knife edge, at intensity 1/4 where the geometric edge is) must sit
        // where the rule puts it.
        let s = System {
            entrance_pupil_mm: Some(5.0),
            ..system()
        };
        let g = geometry();
        let led = LedIndex::new(10, 14);
        let o = ObjectField::square_hole(&s, 256, 48, 2, 1000.0, (0.0, 0.0), 1.0);
        let img = Renderer::new(&o).render(&s, &g, &o, led, 0.0);
        let x_of = |col: f64| s.pixel_to_sample(col, 128.0, 256, 256).0;
        // The rule's edge along the middle row, by bisection.
        let (mut lo, mut hi) = (x_of(0.0), x_of(255.0));
        assert!(!g.is_bright_field(led, lo, 0.0, &s) && g.is_bright_field(led, hi, 0.0, &s));
        for _ in 0..40 {
            let mid = 0.5 * (lo + hi);
            if g.is_bright_field(led, mid, 0.0, &s) {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        let rule_um = 0.5 * (lo + hi);
        // The simulated edge: the first crossing of 1/4 from the dark side.
        let row: Vec<f32> = (0..256).map(|c| img[[128, c]]).collect();
        let k = row
            .windows(2)
            .position(|w| w[0] < 0.25 && w[1] >= 0.25)
            .expect("the frame turns bright somewhere");
        let frac = f64::from((0.25 - row[k]) / (row[k + 1] - row[k]));
        let simulated_um = x_of(k as f64 + frac);
        // The simulator's pupil is a disc of whole frequency bins (1/(352·0.6 µm)): its
        // edge is placed to half a bin, which the frequencies' slope across the field,
        // (1/p + 1/R)/λ, turns into µm.
        let half_bin = 0.5 / ((256 + 2 * 48) as f64 * s.sample_pixel_um());
        let slope = (1.0 / 5000.0 + 1.0 / 92_500.0) / s.wavelength_um;
        let tolerance_um = half_bin / slope + 1.0;
        assert!(
            (simulated_um - rule_um).abs() < tolerance_um,
            "edge: simulated {simulated_um:.1} µm, rule {rule_um:.1} µm (± {tolerance_um:.1})"
        );
        assert!(row[0] < 0.05 && row[255] > 0.8, "dark at −x, lit at +x");
        assert!(
            (0..256).all(|c| !g.is_bright_field(led, x_of(c as f64), 0.0, &system())),
            "a telecentric objective would see it dark everywhere"
        );
    }

    #[test]
    fn a_defocused_feature_moves_along_the_light() {
        // Centroid of a hole under a tilted LED moves by ≈ z·(x − x_led)/h.
        let s = system();
        let o = ObjectField::square_hole(&s, 128, 32, 2, 20.0, (0.0, 0.0), 0.0);
        let mut r = Renderer::new(&o);
        let g = geometry();
        let centroid = |img: &Image| {
            let (mut sx, mut sy, mut sw) = (0.0, 0.0, 0.0);
            for ((row, col), &v) in img.indexed_iter() {
                sx += v as f64 * col as f64;
                sy += v as f64 * row as f64;
                sw += v as f64;
            }
            (sx / sw, sy / sw)
        };
        let (c0, r0) = centroid(&r.render(&s, &g, &o, LedIndex::new(10, 10), 0.0));
        let (c1, r1) = centroid(&r.render(&s, &g, &o, LedIndex::new(10, 12), 200.0));
        let shift_um = (
            (c1 - c0) * s.sample_pixel_um(),
            (r1 - r0) * s.sample_pixel_um(),
        );
        let expect = g.defocus_shift_um(LedIndex::new(10, 12), 0.0, 0.0, 200.0);
        assert!(
            (shift_um.0 - expect.0).abs() < 0.05 * expect.0.abs(),
            "{shift_um:?} vs {expect:?}"
        );
        assert!(shift_um.1.abs() < 0.05);
    }

    #[test]
    fn the_camera_adds_offset_and_noise_and_clips() {
        let c = Camera::realistic();
        let img = Image::from_elem((32, 32), 0.5);
        let mut rng = rand::rngs::StdRng::seed_from_u64(1);
        let counts = c.record(&img, 4.0, &mut rng);
        let mean = counts.iter().map(|&v| v as f64).sum::<f64>() / 1024.0;
        let expect = 0.5 * 1500.0 * 4.0 * 0.2 + 100.0;
        assert!((mean - expect).abs() < 3.0, "{mean} vs {expect}");
        let var = counts
            .iter()
            .map(|&v| (v as f64 - mean).powi(2))
            .sum::<f64>()
            / 1023.0;
        // shot noise: σ² = gain² · electrons
        let expect_var = 0.2f64.powi(2) * (0.5 * 1500.0 * 4.0 + 2.4f64.powi(2)) + 1.0 / 12.0;
        assert!(
            (var / expect_var - 1.0).abs() < 0.2,
            "{var} vs {expect_var}"
        );
        let bright = c.record(&Image::from_elem((4, 4), 100.0), 100.0, &mut rng);
        assert!(bright.iter().all(|&v| v == 4095));
    }

    #[test]
    fn frames_stored_for_display_decode_to_the_sensors_counts() {
        let raw = Camera {
            noisy: false,
            ..Camera::eight_bit()
        };
        let encoded = Camera {
            display_gamma: Some(2.2),
            ..raw
        };
        // 1 ms of intensity 0.1 … 3 (5 … 15 DN above the 2 DN offset) and 40 ms of 1.0.
        let img = Image::from_shape_fn((1, 4), |(_, c)| [0.1f32, 1.0, 3.0, 0.0][c]);
        let mut rng = rand::rngs::StdRng::seed_from_u64(1);
        for ms in [1.0, 40.0] {
            let (linear, stored) = (
                raw.record(&img, ms, &mut rng),
                encoded.record(&img, ms, &mut rng),
            );
            let frame = |counts: Array2<u16>| SimFrame {
                led: LedIndex::new(0, 0),
                also: vec![],
                defocus_um: 0.0,
                exposure_ms: ms,
                counts,
            };
            let (a, b) = (frame(linear.clone()), frame(stored.clone()));
            let whole = crate::frame::Region::whole((1, 4));
            let (la, lb) = (
                a.measured(&raw).intensity(whole),
                b.measured(&encoded).intensity(whole),
            );
            for k in 0..4 {
                // Dim values are stored brighter (more levels for them) …
                assert!(
                    stored[[0, k]] >= linear[[0, k]],
                    "{stored} against {linear}"
                );
                // … and decode to the same light within the encoding's rounding: half a
                // stored step, γ·(c/F)^(1 − 1/γ)·½ sensor counts at c.
                let c = linear[[0, k]] as f32 + 1.0;
                let step = 2.2 * (c / 255.0).powf(1.0 - 1.0 / 2.2) * 0.5;
                assert!(
                    (la[[0, k]] - lb[[0, k]]).abs() * ms as f32 <= step,
                    "{la} against {lb} at {ms} ms"
                );
            }
        }
        assert!(
            (encoded
                .response()
                .decode(encoded.stored_dark_level() as f32)
                - 2.0)
                .abs()
                < 1e-3
        );
    }
}

/// A pdcFPM calibration acquisition: what the simulator needs to make one.
#[derive(Debug, Clone, Copy)]
pub struct CalibrationScene {
    /// Microscope.
    pub system: System,
    /// The real (hidden) LED array.
    pub truth: LedGeometry,
    /// Sample displacement for the defocused frames, µm.
    pub defocus_um: f64,
    /// Side of the square hole, µm.
    pub feature_um: f64,
    /// Its position, µm.
    pub feature_at_um: (f64, f64),
    /// Sensor size, pixels (square).
    pub camera_px: usize,
    /// LEDs around the nominal centre: (2·k+1)² defocused frames.
    pub half_grid: usize,
    /// Camera.
    pub camera: Camera,
    /// Peak counts of the brightest frame (the defocused hole's focus), if set; else
    /// a clear field at a third of full scale.
    pub peak_dn: Option<f64>,
    /// Random seed.
    pub seed: u64,
    /// Each LED off its place on the board by its own lateral move, N(0, σ = this)
    /// each way, mm (a hand-soldered board: bent legs, packages askew;
    /// [`Self::led_offset_mm`]); 0: every LED where `truth` puts it.
    pub led_jitter_mm: f64,
}

impl CalibrationScene {
    /// The paper's system: 21×21 LEDs at 2.5 mm, λ 0.47 µm, NA 0.1, 4×, 2.4 µm pixels, a
    /// 50 µm square hole, 200 µm defocus, 256² frames, a 5×5 bright-field grid.
    pub fn paper(truth: LedGeometry, seed: u64) -> Self {
        Self {
            system: System::paper(),
            truth,
            defocus_um: 200.0,
            feature_um: 50.0,
            feature_at_um: (0.0, 0.0),
            camera_px: 256,
            half_grid: crate::calibrate::GRID_HALF,
            camera: Camera::realistic(),
            peak_dn: None,
            seed,
            led_jitter_mm: 0.0,
        }
    }

    /// How far LED `led` sits off its place (x, y, mm): drawn from the seed and the
    /// LED, the same on every call.
    pub fn led_offset_mm(&self, led: LedIndex) -> (f64, f64) {
        // 0 (or a σ no normal law takes): every LED where `truth` puts it.
        let jitter = match Normal::new(0.0, self.led_jitter_mm) {
            Ok(j) if self.led_jitter_mm > 0.0 => j,
            _ => return (0.0, 0.0),
        };
        let stream = ((led.row as u64) << 32) | led.col as u64;
        let mut rng = rand::rngs::StdRng::seed_from_u64(self.seed ^ 0x1ED5_0FF5 ^ stream);
        (jitter.sample(&mut rng), jitter.sample(&mut rng))
    }

    /// The shots: the focused reference under the nominal centre LED, then every LED of
    /// the grid around it, defocused.
    pub fn shots(&self) -> Vec<(LedIndex, f64)> {
        let grid = crate::calibrate::calibration_grid(&self.truth, self.half_grid);
        std::iter::once((self.truth.center, 0.0))
            .chain(grid.into_iter().map(|led| (led, self.defocus_um)))
            .collect()
    }

    /// Render and record every shot, all at one exposure (as a user sets it once): a
    /// defocused hole focuses light to about twice the clear-field level, so a clear
    /// field is put at a third of full scale and nothing saturates.
    pub fn acquire(&self) -> Vec<SimFrame> {
        self.acquire_focused_off(0.0)
    }

    /// [`Self::acquire`] in light whose focus lies `focus_offset_um` from the one the
    /// stage's zero was set in (a colour other than the one focused: chromatic focal
    /// shift): every frame is rendered that much farther defocused, and labelled with
    /// the stage's defocus, as a rig records it.
    pub fn acquire_focused_off(&self, focus_offset_um: f64) -> Vec<SimFrame> {
        let px = self.system.sample_pixel_um();
        // Margin: the defocused feature moves and blurs by up to this much.
        let reach_um = self.defocus_um.abs() * (0.25 + self.system.na) + 10.0;
        let pad = ((reach_um / px).ceil() as usize + 24).next_multiple_of(8);
        let object = ObjectField::square_hole(
            &self.system,
            self.camera_px,
            pad,
            2,
            self.feature_um,
            self.feature_at_um,
            0.0,
        );
        // The defocused hole focuses light to about 2.5× the clear field.
        let peak_intensity = 2.5;
        let exposure = match self.peak_dn {
            Some(peak) => {
                peak / (peak_intensity * self.camera.electrons_per_ms * self.camera.gain_dn_per_e)
            }
            None => self.camera.exposure_for(peak_intensity, 0.85, 1.0, 1000.0),
        };
        let shots: Vec<(LedIndex, f64)> = self
            .shots()
            .into_iter()
            .map(|(led, z)| (led, z + focus_offset_um))
            .collect();
        let board = |led: LedIndex| {
            let (x, y, h) = self.truth.led_position_3d_mm(led);
            let (dx, dy) = self.led_offset_mm(led);
            (x + dx, y + dy, h)
        };
        let mut frames = acquire_from(
            &self.system,
            &board,
            &object,
            &shots,
            &self.camera,
            |_| exposure,
            self.seed,
        );
        for f in &mut frames {
            f.defocus_um -= focus_offset_um;
        }
        frames
    }
}
