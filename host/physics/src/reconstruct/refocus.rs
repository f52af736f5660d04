//! How far out of focus the frames were taken, read from the frames themselves.
//!
//! Under defocus z a thin sample's image moves by z·(s_x, s_y)/s_z when it is lit along
//! the direction s (docs/dataset.md §3): bright-field frames lit from opposite sides
//! disagree by twice that, and in focus they agree. Each bright-field frame's shift
//! against the reference (axial) frame is measured by phase correlation over the
//! field's centre, and one z through the origin is fitted to the shifts against the
//! LEDs' directions, outliers (a frame whose contrast changed too much to correlate)
//! rejected. The fit's scatter and what the shifts cannot tell from a defocus
//! ([`SYSTEMATIC_DOF`]) give z its σ. This needs no solver run and no search: about
//! one FFT per bright-field frame.

use rustfft::num_complex::Complex32;

use crate::fft::Fft2;
use crate::frame::{LitFrame, Region};
use crate::optics::{LedGeometry, LedIndex, System};

/// The side of the central square the shifts are measured over, at most (camera
/// pixels): a few hundred pixels of texture pin a shift to a tenth of a pixel.
pub const CROP_PX: usize = 384;

/// What the shifts cannot tell from a defocus, as a share of the objective's depth of
/// field λ/NA²: under oblique light a sample whose phase and absorption go together
/// shows relief on one side of each feature, which moves the correlation's peak the
/// way a defocus would, in proportion to the angle. On the simulated test sample in
/// focus (cells of 0.4–1.6 rad that also absorb) the shifts read −11 µm (±0.4 µm of
/// scatter) at λ/NA² = 47 µm; away from focus within 3 % (tests/refocus.rs).
pub const SYSTEMATIC_DOF: f64 = 0.25;

/// One bright-field frame's shift against the reference frame.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct LedShift {
    /// The LED.
    pub led: LedIndex,
    /// Its direction at the field's centre, (s_x/s_z, s_y/s_z), minus the reference
    /// LED's: the shift per µm of defocus.
    pub slope: (f64, f64),
    /// The frame's shift against the reference frame's, µm in the sample plane.
    pub shift_um: (f64, f64),
    /// Whether the fit kept it (false: an outlier, beyond 3.5 robust σ).
    pub kept: bool,
}

/// The defocus the frames show.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DefocusEstimate {
    /// The defocus, µm (toward the LEDs positive, as a dataset's `defocus_um`).
    pub z_um: f64,
    /// Its 1σ, µm: the scatter's ([`Self::sigma_scatter_um`]) and
    /// [`SYSTEMATIC_DOF`] of the depth of field, added in quadrature.
    pub sigma_um: f64,
    /// The part of the 1σ from the scatter of the shifts about the fit, µm.
    pub sigma_scatter_um: f64,
    /// The rms of the kept shifts about the fit, µm.
    pub residual_um: f64,
    /// The reference frame's LED.
    pub reference: LedIndex,
    /// Every bright-field frame's shift (the curve the fit is a line through).
    pub shifts: Vec<LedShift>,
}

impl DefocusEstimate {
    /// Whether the frames clearly show a defocus: beyond 3σ of zero.
    pub fn is_clear(&self) -> bool {
        self.z_um.abs() > 3.0 * self.sigma_um
    }

    /// Frames the fit kept.
    pub fn kept(&self) -> usize {
        self.shifts.iter().filter(|s| s.kept).count()
    }
}

/// Shifts gathered frame by frame (a dataset on disk is read one frame at a time):
/// the reference frame first, then any frames; [`Self::estimate`] fits them.
pub struct ShiftReader {
    system: System,
    geometry: LedGeometry,
    region: Region,
    fft: Fft2,
    window: Vec<f32>,
    /// Per frequency bin, the phase correlation's weight: a Gaussian roll-off past
    /// the objective's cutoff (σ = the cutoff: narrower windows, tried down to 0.15 of
    /// it, read simulated defocus worse).
    rolloff: Vec<f32>,
    reference: LedIndex,
    /// The reference's spectrum, conjugated.
    reference_spectrum: Vec<Complex32>,
    shifts: Vec<(LedIndex, (f64, f64))>,
}

impl ShiftReader {
    /// Start from `reference` (the frame lit nearest the axis), over the central square
    /// of at most [`CROP_PX`] pixels. None for frames under 32 px or without texture.
    pub fn new(system: &System, geometry: &LedGeometry, reference: &LitFrame<'_>) -> Option<Self> {
        let (h, w) = reference.measured.dim();
        let side = h.min(w).min(CROP_PX) & !1;
        if side < 32 {
            return None;
        }
        let region = Region {
            y0: (h - side) / 2,
            x0: (w - side) / 2,
            height: side,
            width: side,
        };
        let hann = |i: usize| 0.5 - 0.5 * (std::f32::consts::TAU * i as f32 / side as f32).cos();
        let window = (0..side * side)
            .map(|i| hann(i % side) * hann(i / side))
            .collect();
        let cutoff_bins = (system.cutoff() * side as f64 * system.sample_pixel_um()) as f32;
        let rolloff = (0..side * side)
            .map(|i| {
                let (kx, ky) = (signed(i % side, side) as f32, signed(i / side, side) as f32);
                (-(kx * kx + ky * ky) / (2.0 * cutoff_bins * cutoff_bins)).exp()
            })
            .collect();
        let mut reader = Self {
            system: *system,
            geometry: *geometry,
            region,
            fft: Fft2::new(side, side),
            window,
            rolloff,
            reference: reference.led,
            reference_spectrum: vec![],
            shifts: vec![],
        };
        let mut spectrum = reader.spectrum(reference)?;
        spectrum.iter_mut().for_each(|v| *v = v.conj());
        reader.reference_spectrum = spectrum;
        Some(reader)
    }

    /// The spectrum over the region of the frame divided by its slow level (a plane:
    /// an oblique LED lights one side of the field more), less one, windowed (None for
    /// a frame with no light there).
    fn spectrum(&mut self, frame: &LitFrame<'_>) -> Option<Vec<Complex32>> {
        let image = frame.measured.dark_subtracted(self.region);
        let plane = Plane::fit(&image)?;
        let n = self.region.width;
        let mut data: Vec<Complex32> = image
            .iter()
            .zip(&self.window)
            .enumerate()
            .map(|(i, (&v, &w))| {
                let level = plane.at(i % n, i / n);
                Complex32::new((v / level - 1.0) * w, 0.0)
            })
            .collect();
        self.fft.forward(&mut data);
        Some(data)
    }

    /// Measure `frame`'s shift against the reference, if its LED is bright-field at the
    /// field's centre (others are skipped: their frames hold other frequencies, and a
    /// frame lit by several LEDs holds several shifts).
    pub fn read(&mut self, frame: &LitFrame<'_>) {
        if frame.led == self.reference
            || frame.is_multiplexed()
            || !self
                .geometry
                .is_bright_field(frame.led, 0.0, 0.0, &self.system)
        {
            return;
        }
        let Some(mut cross) = self.spectrum(frame) else {
            return;
        };
        let n = self.region.width;
        // Phase correlation, rolled off past the objective's cutoff.
        let weights = self.reference_spectrum.iter().zip(&self.rolloff);
        for (c, (r, w)) in cross.iter_mut().zip(weights) {
            let p = *c * *r;
            let m = p.norm();
            *c = if m > 0.0 {
                p * (w / m)
            } else {
                Complex32::default()
            };
        }
        self.fft.inverse(&mut cross);
        if let Some((dx, dy)) = peak(&cross, n) {
            let pixel = self.system.sample_pixel_um();
            self.shifts.push((frame.led, (dx * pixel, dy * pixel)));
        }
    }

    /// The defocus fitted to the shifts read (None with fewer than 3).
    pub fn estimate(&self) -> Option<DefocusEstimate> {
        let direction = |led: LedIndex| {
            let (x, y, h) = self.geometry.led_position_3d_mm(led);
            (-x / h, -y / h)
        };
        let d0 = direction(self.reference);
        let mut shifts: Vec<LedShift> = self
            .shifts
            .iter()
            .map(|&(led, shift_um)| {
                let d = direction(led);
                LedShift {
                    led,
                    slope: (d.0 - d0.0, d.1 - d0.1),
                    shift_um,
                    kept: true,
                }
            })
            .collect();
        if shifts.len() < 3 {
            return None;
        }
        let fit = |shifts: &[LedShift]| {
            let (mut sd, mut dd) = (0.0, 0.0);
            for s in shifts.iter().filter(|s| s.kept) {
                sd += s.shift_um.0 * s.slope.0 + s.shift_um.1 * s.slope.1;
                dd += s.slope.0 * s.slope.0 + s.slope.1 * s.slope.1;
            }
            (dd > 0.0).then(|| (sd / dd, dd))
        };
        let residual = |s: &LedShift, z: f64| {
            (s.shift_um.0 - z * s.slope.0).hypot(s.shift_um.1 - z * s.slope.1)
        };
        let (mut z, _) = fit(&shifts)?;
        // Reject what lies beyond 3.5 robust σ of the fit, twice (a start pulled by an
        // outlier may flag a good frame the first time).
        for _ in 0..2 {
            let mut r: Vec<f64> = shifts.iter().map(|s| residual(s, z)).collect();
            r.sort_by(f64::total_cmp);
            // A 2-D residual's median is 1.1774 σ of each component.
            let robust = r[r.len() / 2] / 1.1774;
            let limit = 3.5 * robust.max(1e-3);
            for s in shifts.iter_mut() {
                s.kept = residual(s, z) <= limit;
            }
            z = fit(&shifts)?.0;
        }
        let (z, dd) = fit(&shifts)?;
        let kept: Vec<&LedShift> = shifts.iter().filter(|s| s.kept).collect();
        // Two components per frame, one parameter.
        let dof = (2 * kept.len()).saturating_sub(1).max(1) as f64;
        let rss: f64 = kept.iter().map(|s| residual(s, z).powi(2)).sum();
        let scatter = (rss / dof / dd).sqrt();
        let systematic = SYSTEMATIC_DOF * self.system.wavelength_um / self.system.na.powi(2);
        Some(DefocusEstimate {
            z_um: z,
            sigma_um: scatter.hypot(systematic),
            sigma_scatter_um: scatter,
            residual_um: (rss / (kept.len().max(1)) as f64).sqrt(),
            reference: self.reference,
            shifts,
        })
    }
}

/// The defocus `frames` (in focus as stored) show, read against the frame lit nearest
/// the axis ([`ShiftReader`]).
pub fn estimate(
    system: &System,
    geometry: &LedGeometry,
    frames: &[LitFrame<'_>],
) -> Option<DefocusEstimate> {
    // A shift is one LED's: frames lit by several take no part.
    let single: Vec<&LitFrame<'_>> = frames.iter().filter(|f| !f.is_multiplexed()).collect();
    let leds: Vec<LedIndex> = single.iter().map(|f| f.led).collect();
    let first = *geometry.nearest_first(&leds, (0.0, 0.0), system).first()?;
    let mut reader = ShiftReader::new(system, geometry, single[first])?;
    for f in frames {
        reader.read(f);
    }
    reader.estimate()
}

/// The light's slow level over a frame: a plane a + b·x + c·y, least squares.
struct Plane {
    a: f64,
    b: f64,
    c: f64,
    centre: f64,
}

impl Plane {
    /// The plane through `image` (square); None if it is not positive over the image.
    fn fit(image: &crate::Image) -> Option<Self> {
        let (h, w) = image.dim();
        let centre = (w as f64 - 1.0) / 2.0;
        let (mut s, mut sx, mut sy, mut xx, mut yy) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for ((r, c), &v) in image.indexed_iter() {
            let (x, y, v) = (c as f64 - centre, r as f64 - centre, v as f64);
            s += v;
            sx += v * x;
            sy += v * y;
            xx += x * x;
            yy += y * y;
        }
        let n = (h * w) as f64;
        let plane = Self {
            a: s / n,
            b: sx / xx.max(1.0),
            c: sy / yy.max(1.0),
            centre,
        };
        let corner = plane.b.abs() * centre + plane.c.abs() * centre;
        (plane.a > corner).then_some(plane)
    }

    fn at(&self, col: usize, row: usize) -> f32 {
        (self.a + self.b * (col as f64 - self.centre) + self.c * (row as f64 - self.centre)) as f32
    }
}

/// The correlation's peak, sub-pixel (a parabola through it and its neighbours along
/// each axis), as the frame's shift in pixels (signed).
pub(crate) fn peak(correlation: &[Complex32], n: usize) -> Option<(f64, f64)> {
    let (best, _) = correlation
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.re.total_cmp(&b.1.re))?;
    let (c, r) = (best % n, best / n);
    let at = |r: usize, c: usize| correlation[(r % n) * n + c % n].re as f64;
    let vertex = |minus: f64, centre: f64, plus: f64| {
        let curvature = minus - 2.0 * centre + plus;
        if curvature < 0.0 {
            (0.5 * (minus - plus) / curvature).clamp(-0.5, 0.5)
        } else {
            0.0
        }
    };
    let dx = vertex(at(r, c + n - 1), at(r, c), at(r, c + 1));
    let dy = vertex(at(r + n - 1, c), at(r, c), at(r + 1, c));
    Some((signed(c, n) as f64 + dx, signed(r, n) as f64 + dy))
}

/// FFT bin `k` of an `n`-point grid as a signed index.
pub(crate) fn signed(k: usize, n: usize) -> i64 {
    if k < n / 2 {
        k as i64
    } else {
        k as i64 - n as i64
    }
}
