//! Differential phase contrast (L. Tian and L. Waller, "Quantitative differential phase
//! contrast imaging in an LED array microscope", Opt. Express 23(9):11394, 2015): a
//! weak object's phase and absorption from four frames, each lit by one half of the
//! bright-field LEDs, by Tikhonov deconvolution with the patterns' weak-object transfer
//! functions. Four frames instead of a whole scan: a first look, and a focus measure.
//!
//! The model (docs/dataset.md §1.3 conventions). A weak object o ≈ 1 − μ + iφ lit by an
//! LED at pupil frequency f_j (inside the pupil P) images, to first order, with the
//! spectrum Ĩ(u) = B + H_A(u)·M(u) + H_φ(u)·Φ(u), where
//! H_A = −[P(f_j + u) + P(f_j − u)] and H_φ = i·[P(f_j + u) − P(f_j − u)]. A pattern's
//! LEDs add incoherently: their transfer functions add, and dividing the frame by its
//! mean divides them by the pattern's bright-field count B. The absorption and phase
//! spectra then minimise Σ_k |Ĩ_k − H_A,k·M − H_φ,k·Φ|² + α_A|M|² + α_φ|Φ|² at each
//! frequency: a 2 × 2 solve. Like the transfer functions the solution reaches 2·NA/λ.

use rustfft::num_complex::{Complex32, Complex64};

use crate::fft::{bin_frequency, Fft2};
use crate::optics::{LedGeometry, LedIndex, System};
use crate::Image;

/// The half of the bright-field disc a pattern lights, named by where its LEDs sit in
/// the image (x along the columns, y along the rows, so "bottom" is +y).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Half {
    /// LEDs at −y.
    Top,
    /// LEDs at +y.
    Bottom,
    /// LEDs at −x.
    Left,
    /// LEDs at +x.
    Right,
}

impl Half {
    /// The four, in the order frames are taken.
    pub const ALL: [Half; 4] = [Half::Top, Half::Bottom, Half::Left, Half::Right];

    /// Its name.
    pub fn name(self) -> &'static str {
        match self {
            Half::Top => "top",
            Half::Bottom => "bottom",
            Half::Left => "left",
            Half::Right => "right",
        }
    }

    /// Whether an LED whose light reaches the field's centre at pupil frequency
    /// `f` (cycles/µm) is in this half: the LED sits opposite its light's direction.
    /// LEDs on the dividing line are in neither.
    fn holds(self, f: (f64, f64)) -> bool {
        const LINE: f64 = 1e-9;
        match self {
            Half::Top => f.1 > LINE,
            Half::Bottom => f.1 < -LINE,
            Half::Left => f.0 > LINE,
            Half::Right => f.0 < -LINE,
        }
    }
}

/// The bright-field LEDs (at the field's centre) of `half`, among `leds`.
pub fn half_circle(
    geometry: &LedGeometry,
    system: &System,
    leds: &[LedIndex],
    half: Half,
) -> Vec<LedIndex> {
    leds.iter()
        .copied()
        .filter(|&led| geometry.is_bright_field(led, 0.0, 0.0, system))
        .filter(|&led| half.holds(geometry.pupil_frequency(led, 0.0, 0.0, system)))
        .collect()
}

/// One pattern's weak-object transfer functions on a `width × height` grid of
/// `pixel_um` (FFT order), already divided by its bright-field count.
#[derive(Debug, Clone)]
pub struct Transfer {
    /// H_A per bin.
    pub absorption: Vec<Complex64>,
    /// H_φ per bin.
    pub phase: Vec<Complex64>,
}

impl Transfer {
    /// The transfer functions of a pattern whose LEDs light the field's centre at
    /// pupil frequencies `lit` (cycles/µm), through a pupil of radius `cutoff`.
    pub fn new(
        lit: &[(f64, f64)],
        cutoff: f64,
        (width, height): (usize, usize),
        pixel_um: f64,
    ) -> Self {
        let inside = |fx: f64, fy: f64| {
            if fx * fx + fy * fy < cutoff * cutoff {
                1.0
            } else {
                0.0
            }
        };
        let bright: Vec<(f64, f64)> = lit
            .iter()
            .copied()
            .filter(|&(x, y)| inside(x, y) > 0.0)
            .collect();
        let count = bright.len().max(1) as f64;
        let mut absorption = vec![Complex64::default(); width * height];
        let mut phase = vec![Complex64::default(); width * height];
        for r in 0..height {
            let uy = bin_frequency(r, height, pixel_um);
            for c in 0..width {
                let ux = bin_frequency(c, width, pixel_um);
                let (mut a, mut p) = (0.0, 0.0);
                for &(fx, fy) in &bright {
                    let (plus, minus) = (inside(fx + ux, fy + uy), inside(fx - ux, fy - uy));
                    a -= plus + minus;
                    p += plus - minus;
                }
                absorption[r * width + c] = Complex64::new(a / count, 0.0);
                phase[r * width + c] = Complex64::new(0.0, p / count);
            }
        }
        Self { absorption, phase }
    }
}

/// Tikhonov weights: how strongly absorption and phase are held to zero where the
/// frames say little of them (relative to a transfer function's peak, 2).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Regularisation {
    /// α_A.
    pub absorption: f64,
    /// α_φ.
    pub phase: f64,
}

impl Default for Regularisation {
    /// 10⁻³ for both: on a simulated weak phase object (128², 12-bit, 19 LEDs per
    /// half) the phase's detail came closest to the truth from 10⁻⁴ to 10⁻³ (NRMSE
    /// with the slow phase fitted out 0.277, 0.279) and fell off above (0.304 at 10⁻²,
    /// 0.369 at 3·10⁻², 0.525 at 10⁻¹); the slowest phase, where H_φ → 0, is left to
    /// wander (it is what DPC cannot see).
    fn default() -> Self {
        Self {
            absorption: 1e-3,
            phase: 1e-3,
        }
    }
}

/// The DPC solver for one grid and one set of patterns, planned once (transfer
/// functions, the 2 × 2 inverse per bin, the FFT), then applied to every set of frames
/// as fast as the camera delivers them.
pub struct Dpc {
    width: usize,
    height: usize,
    fft: Fft2,
    /// Per pattern and bin: the weights of Ĩ_k in M and in Φ.
    to_absorption: Vec<Vec<Complex32>>,
    to_phase: Vec<Vec<Complex32>>,
    /// Work buffers kept between updates (a live preview solves at the camera's rate):
    /// the absorption and phase spectra, and one frame's.
    m: Vec<Complex32>,
    p: Vec<Complex32>,
    spectrum: Vec<Complex32>,
}

/// Absorption μ and phase φ (radians) of a weak object, on the frames' grid; both
/// without their mean (DPC does not see it).
#[derive(Debug, Clone)]
pub struct WeakObject {
    /// μ (o ≈ 1 − μ + iφ).
    pub absorption: Image,
    /// φ, radians.
    pub phase: Image,
}

impl Dpc {
    /// Plan for `transfers` (one per pattern, in the order frames will come).
    pub fn new(
        transfers: &[Transfer],
        (width, height): (usize, usize),
        reg: Regularisation,
    ) -> Self {
        let n = width * height;
        let k = transfers.len();
        let mut to_absorption = vec![vec![Complex32::default(); n]; k];
        let mut to_phase = vec![vec![Complex32::default(); n]; k];
        for b in 0..n {
            // Normal equations [a b; c d]·[M; Φ] = Σ_k [H_A,k*; H_φ,k*]·Ĩ_k.
            let (mut a, mut bb, mut d) = (reg.absorption, Complex64::default(), reg.phase);
            for t in transfers {
                let (ha, hp) = (t.absorption[b], t.phase[b]);
                a += ha.norm_sqr();
                d += hp.norm_sqr();
                bb += ha.conj() * hp;
            }
            let det = a * d - bb.norm_sqr();
            if det.abs() < 1e-300 {
                continue;
            }
            // Inverse [d −b; −c a]/det, c = b*.
            for (j, t) in transfers.iter().enumerate() {
                let (ha, hp) = (t.absorption[b].conj(), t.phase[b].conj());
                let m = (d * ha - bb * hp) / det;
                let p = (-bb.conj() * ha + a * hp) / det;
                to_absorption[j][b] = Complex32::new(m.re as f32, m.im as f32);
                to_phase[j][b] = Complex32::new(p.re as f32, p.im as f32);
            }
        }
        Self {
            width,
            height,
            fft: Fft2::new(width, height),
            to_absorption,
            to_phase,
            m: vec![Complex32::default(); n],
            p: vec![Complex32::default(); n],
            spectrum: vec![Complex32::default(); n],
        }
    }

    /// The weak object from one frame per pattern (intensities of any scale, in the
    /// planned order); None if their number or size is not the plan's.
    pub fn solve(&mut self, frames: &[&Image]) -> Option<WeakObject> {
        let (w, h) = (self.width, self.height);
        if frames.len() != self.to_phase.len() || frames.iter().any(|f| f.dim() != (h, w)) {
            return None;
        }
        let n = w * h;
        let (m, p, spectrum) = (&mut self.m, &mut self.p, &mut self.spectrum);
        m.fill(Complex32::default());
        p.fill(Complex32::default());
        for (j, frame) in frames.iter().enumerate() {
            let mean = frame.iter().map(|&v| v as f64).sum::<f64>() / n as f64;
            let scale = if mean.abs() > 0.0 { 1.0 / mean } else { 0.0 } as f32;
            for (s, &v) in spectrum.iter_mut().zip(frame.iter()) {
                *s = Complex32::new(v * scale - 1.0, 0.0);
            }
            self.fft.forward(spectrum);
            for b in 0..n {
                m[b] += self.to_absorption[j][b] * spectrum[b];
                p[b] += self.to_phase[j][b] * spectrum[b];
            }
        }
        m[0] = Complex32::default();
        p[0] = Complex32::default();
        self.fft.inverse(m);
        self.fft.inverse(p);
        let real = |v: &[Complex32]| Image::from_shape_fn((h, w), |(r, c)| v[r * w + c].re);
        Some(WeakObject {
            absorption: real(m),
            phase: real(p),
        })
    }
}

/// The four half-circle frames, each the sum of the frames (intensities per ms) lit
/// only by LEDs of its half's bright-field disc: single-LED frames summed as the
/// pattern would light them at once (LEDs add incoherently), or a frame the pattern
/// itself lit (several LEDs, all of that half). `frames` pairs each frame's LEDs with
/// its image; a frame with LEDs in more than one half, or outside the bright field,
/// takes no part. Returns each half with the LEDs its sum holds.
pub fn half_circle_frames(
    geometry: &LedGeometry,
    system: &System,
    frames: &[(Vec<LedIndex>, Image)],
) -> Vec<(Half, Vec<LedIndex>, Image)> {
    let mut every: Vec<LedIndex> = frames.iter().flat_map(|f| f.0.iter().copied()).collect();
    every.sort();
    every.dedup();
    Half::ALL
        .iter()
        .filter_map(|&half| {
            let disc = half_circle(geometry, system, &every, half);
            let first = frames.first()?;
            let mut sum = Image::zeros(first.1.dim());
            let mut lit = vec![];
            for (leds, img) in frames {
                if !leds.is_empty() && leds.iter().all(|l| disc.contains(l)) {
                    sum += img;
                    lit.extend_from_slice(leds);
                }
            }
            lit.sort();
            lit.dedup();
            Some((half, lit, sum))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mirrored_patterns_see_the_phase_with_opposite_signs_and_the_absorption_alike() {
        let (size, pixel, cutoff) = ((32, 32), 0.6, 0.2);
        let left = Transfer::new(&[(0.1, 0.0), (0.1, 0.05)], cutoff, size, pixel);
        let right = Transfer::new(&[(-0.1, 0.0), (-0.1, -0.05)], cutoff, size, pixel);
        for b in 0..32 * 32 {
            assert!((left.phase[b] + right.phase[b]).norm() < 1e-12, "bin {b}");
            assert!(
                (left.absorption[b] - right.absorption[b]).norm() < 1e-12,
                "bin {b}"
            );
        }
        // At DC no phase is seen, and the absorption's weight is −2 (both terms).
        assert_eq!(left.phase[0].norm(), 0.0);
        assert!((left.absorption[0].re + 2.0).abs() < 1e-12);
        // Beyond 2·NA/λ neither is seen.
        let far = 27; // bin −5 of 32 at 0.6 µm: −0.26 cycles/µm along x, plus the LEDs' 0.1
        assert!(left.phase[far].norm() > 0.0 || left.absorption[far].norm() > 0.0);
        let beyond = Transfer::new(&[(0.1, 0.0)], cutoff, (64, 64), 0.25);
        let edge = 64 / 2 - 1; // 0.06·31 = 1.94 cycles/µm, far past 2·0.2 + 0.1
        assert_eq!(
            beyond.phase[edge].norm() + beyond.absorption[edge].norm(),
            0.0
        );
    }
}
