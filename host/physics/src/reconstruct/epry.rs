//! EPRY (Ou, Zheng & Yang 2014): the object spectrum on the high-resolution grid and the
//! pupil on the low-resolution grid, recovered together from the frames (docs/dataset.md §4).
//!
//! * Grids: the HR grid is the camera grid × `upsample`, same field of view, optical axis
//!   at (W·U/2, H·U/2). Spectra are kept in FFT order; both grids share the frequency
//!   step 1/(W·Δ), so a frame's spectrum is a window of the object spectrum.
//! * A frame lit with illumination frequency f_i sees the disc of O centred at −f_i.
//!   Sub-bin positions: with f_i = (s + δ)·df, s whole bins, the frame's exit wave times
//!   exp(−i2π δ·x) — same intensity — has spectrum P(k + δ)·O(k − s). So the object is
//!   read at whole-bin offsets and the pupil disc is shifted by −δ (|δ| ≤ ½ bin); the
//!   pupil's aberrations are smooth, so only its edge moves. Plain rounding instead
//!   biased the result toward whichever geometry rounds the discs best (tested).
//! * Update, per frame: ψ = P·O[window]; φ = F⁻¹ψ; keep φ's phase, take √I for its
//!   amplitude; Δ = Fφ' − ψ; O[window] += α·P*·Δ/max|P|²; P += β·O*·Δ/max|O|² inside
//!   the (shifted) pupil support |f + δ·df| ≤ NA/λ, P = 0 outside.
//! * Steps: α = β = 0.5 to start, halved whenever a pass improves the misfit by < 1 %
//!   ([`StepSchedule`], Zuo et al. 2016). The pupil is learned from the second pass on
//!   and only from bright-field frames: their window holds the strong DC term, while a
//!   dark-field window holds weak scattering, and learning from it let noise into the
//!   pupil (in 128-px tiles NRMSE went from 0.095 to 0.45).
//! * The measured amplitude can be left unimposed near a tile's inner edges
//!   ([`Epry::set_free_border`]), where the FFT's periodic wrap has no counterpart in
//!   the data.
//! * The illumination's common spherical curvature, exp(+iπ·|x|²/(λ·R)), is put into
//!   the first object estimate ([`Epry::apply_illumination_curvature`]) and divided out
//!   of the result ([`remove_illumination_curvature`]): the recovered object is the
//!   sample's transmission at any field size.
//! * The object is normalised so that a clear sample under on-axis light has |o| = 1
//!   when frames are given as intensity per ms relative to that level.

use rayon::prelude::*;
use rustfft::num_complex::Complex32;

use super::contrast::ContrastSums;
use super::flatten::Flatten;
use super::refine::Refine;
use crate::background::Correction;
use crate::fft::{bin_frequency, Fft2};
use crate::optics::{defocus_transfer, System};
use crate::Image;

/// Step sizes and options.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settings {
    /// HR pixels per camera pixel.
    pub upsample: usize,
    /// Object step α (1 = the full ePIE step). The starting value; [`StepSchedule`]
    /// halves it as the passes stall. 0.5: on the simulated 441-frame set, starting at 1
    /// ended at NRMSE 0.066 after 10 passes, starting at 0.5 at 0.046.
    pub alpha: f32,
    /// Pupil step β. 0.5 rather than 1: with β = 1 the learned pupil chased the noise
    /// of the last frames, and reconstructions with geometries a few µm apart drifted
    /// up to 40 % apart in NRMSE (`fpm bench geometry`); at 0.5 they stay within ~15 %.
    pub beta: f32,
    /// Learn the pupil (from the second pass on, bright-field frames only); false:
    /// keep the ideal pupil.
    pub update_pupil: bool,
    /// What is taken off each frame before it is imposed (tiled runs, offline and
    /// streamed: they see whole frames).
    pub background: Correction,
    /// Refine each LED's illumination frequency inside the passes (None: the
    /// geometry's frequencies are taken as exact).
    pub refine_leds: Option<Refine>,
    /// Whether the clear background's low-order phase is taken off each tile's
    /// object before it is blended ([`super::flatten`]).
    pub flatten: Flatten,
    /// How far the sample sat from focus when the frames were taken, µm (toward the
    /// LEDs positive, as a dataset's `defocus_um`): the pupil starts as the disc times
    /// that defocus (docs/dataset.md §2), so the object comes out refocused onto the
    /// sample. A defocus the pupil does not start with is left for pupil learning,
    /// which cannot follow more than about a wave from the bright-field frames alone.
    pub defocus_um: f64,
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            upsample: defaults::UPSAMPLE,
            alpha: 0.5,
            beta: 0.5,
            update_pupil: true,
            background: Correction::PerFrame {
                floor_sigma: defaults::FLOOR_SIGMA,
                soft: true,
                band_sigma: NOISE_BAND_SIGMA,
            },
            refine_leds: None,
            flatten: Flatten::Keep,
            defocus_um: 0.0,
        }
    }
}

/// The default noise band ([`Correction::PerFrame`]'s `band_sigma`), in standard
/// deviations of a dark-field frame's background noise, for the frames that are mostly
/// noise ([`crate::background::FrameBackground::is_mostly_noise`]). 7.5σ cleaned the
/// real ring-array frame's glass from 5.4× to 2.7× its raw frame's variation, keeping
/// group 8's bars, halved an 8-bit simulated set's complex NRMSE, left the USAF set's
/// glass a little cleaner (1.16× → 1.12×) and the 12-bit sets as they were
/// (docs/results.md, "Noise band"). The gamma scan compares its candidates without it.
pub const NOISE_BAND_SIGMA: f32 = 7.5;

/// The defaults of a reconstruction, in one place: the CLI's flags, the service's
/// requests, the Python functions and the napari widget take theirs from here (Python's
/// signatures spell them out for `help()`: a change here fails the Python crate's build
/// until they follow, and its tests compare the two).
pub mod defaults {
    /// HR pixels per camera pixel: enough for the synthetic apertures of the usual
    /// arrays (an NA of illumination up to about 3× the objective's).
    pub const UPSAMPLE: usize = 4;
    /// Passes over all frames of an offline run.
    pub const PASSES: usize = 10;
    /// The per-frame floor, in standard deviations of a dark-field frame's background
    /// noise ([`super::Correction::PerFrame`]).
    pub const FLOOR_SIGMA: f32 = 3.0;
    pub use super::NOISE_BAND_SIGMA;
}

/// The ranges a reconstruction's settings must be in (a job's, a stream's, an
/// acquisition's): beyond them a run is refused up front, naming the setting.
pub mod limits {
    /// HR pixels per camera pixel (a generous bound: at 64 a 1024² frame's object is
    /// already 34 GB, and few synthetic apertures need more than 10).
    pub const UPSAMPLE: std::ops::RangeInclusive<usize> = 1..=64;
    /// Passes over all frames.
    pub const PASSES: std::ops::RangeInclusive<usize> = 1..=10_000;
    /// Object and pupil step sizes (1 = the full ePIE step).
    pub const STEP: std::ops::RangeInclusive<f32> = 0.0..=2.0;
    /// Tile side, camera pixels.
    pub const TILE: std::ops::RangeInclusive<usize> = 16..=16_384;
    /// Refocus distance, µm.
    pub const REFOCUS_UM: f64 = 10_000.0;

    /// `passes` and `tile` (None: from the physics) in their ranges, or what is not.
    pub fn check_run(passes: usize, tile: Option<usize>) -> Result<(), crate::Invalid> {
        if !PASSES.contains(&passes) {
            return Err(crate::Invalid::new(
                "passes",
                format!(
                    "passes {passes}: must be {}-{}",
                    PASSES.start(),
                    PASSES.end()
                ),
            ));
        }
        match tile.filter(|t| !TILE.contains(t)) {
            Some(t) => Err(crate::Invalid::new(
                "tile",
                format!(
                    "tile {t}: must be {}-{} camera pixels",
                    TILE.start(),
                    TILE.end()
                ),
            )),
            None => Ok(()),
        }
    }
}

impl Settings {
    /// Every setting in its range ([`limits`]), or what is not, named as the CLI and
    /// Python name it.
    pub fn validate(&self) -> Result<(), crate::Invalid> {
        use crate::Invalid;
        if !limits::UPSAMPLE.contains(&self.upsample) {
            return Err(Invalid::new(
                "upsample",
                format!(
                    "upsample {}: must be {}-{}",
                    self.upsample,
                    limits::UPSAMPLE.start(),
                    limits::UPSAMPLE.end()
                ),
            ));
        }
        for (name, step) in [("alpha", self.alpha), ("beta", self.beta)] {
            if !(limits::STEP.contains(&step) && step > 0.0) {
                return Err(Invalid::new(
                    name,
                    format!(
                        "{name} {step}: must be above 0 and at most {}",
                        limits::STEP.end()
                    ),
                ));
            }
        }
        if !(self.defocus_um.is_finite() && self.defocus_um.abs() <= limits::REFOCUS_UM) {
            return Err(Invalid::new(
                "refocus_um",
                format!(
                    "refocus_um {}: must be a distance within ±{} µm",
                    self.defocus_um,
                    limits::REFOCUS_UM
                ),
            ));
        }
        if let Correction::PerFrame {
            floor_sigma,
            band_sigma,
            ..
        } = self.background
        {
            if !(floor_sigma.is_finite() && floor_sigma >= 0.0) {
                return Err(Invalid::new(
                    "floor_sigma",
                    format!("floor_sigma {floor_sigma}: must be 0 or more"),
                ));
            }
            if !(band_sigma.is_finite() && band_sigma >= 0.0) {
                return Err(Invalid::new(
                    "noise_band_sigma",
                    format!("noise_band_sigma {band_sigma}: must be 0 or more"),
                ));
            }
        }
        if let Flatten::BlockUm(um) = self.flatten {
            if !(um.is_finite() && um > 0.0) {
                return Err(Invalid::new(
                    "background_block_um",
                    format!("background_block_um {um}: must be a positive size in µm"),
                ));
            }
        }
        Ok(())
    }
}

/// The reconstruction state.
pub struct Epry {
    n: usize,
    upsample: usize,
    settings: Settings,
    /// Object spectrum on the HR grid, FFT order, `(n·U)²`.
    object: Vec<Complex32>,
    /// Pupil on the LR grid, FFT order, `n²`.
    pupil: Vec<Complex32>,
    /// Bin step of the frequency grid, cycles/µm.
    df: f64,
    fft: Fft2,
    /// ψ = P·O(k − s) on the active bins, in the order of `active`.
    psi: Vec<Complex32>,
    /// The exit wave's spectrum on the whole LR grid, then its update.
    phi: Vec<Complex32>,
    /// Pupil bins: (LR index, signed kx, signed ky).
    pupil_bins: Vec<(u32, i64, i64)>,
    /// Per frame: the pupil bins inside the sub-bin shifted disc, each with the HR
    /// object bin it reads (LR index, HR index).
    active: Vec<(usize, usize)>,
    /// LR columns that the pupil disc (with its sub-bin reach) touches, ascending.
    disc_cols: Vec<usize>,
    /// Where the measured amplitude is imposed: columns c0..c1, rows r0..r1.
    constrained: [usize; 4],
    /// Multiplies α and β (the adaptive step size, see [`StepSchedule`]).
    step_scale: f32,
    cutoff: f64,
    /// (λ, R) of the illumination curvature the object was seeded with, µm.
    curvature: Option<(f64, f64)>,
    /// Whether one update is spread over rayon's pool ([`Self::set_parallel`]).
    parallel: bool,
    /// The exit waves of a multiplexed frame's LEDs ([`Self::update_multiplexed`]),
    /// kept between frames so that their buffers are allocated once.
    waves: Vec<Wave>,
    /// Σ_j |P|² over the waves reading each object bin, and Σ_j |O|² over the waves
    /// through each pupil bin, of one multiplexed update (zero between updates).
    object_weight: Vec<f32>,
    pupil_weight: Vec<f32>,
}

/// One LED's exit wave within a multiplexed frame: what [`Epry::exit_wave`] leaves in
/// `phi`, `psi` and `active`, set aside while the other LEDs' waves are computed.
#[derive(Default)]
struct Wave {
    phi: Vec<Complex32>,
    psi: Vec<Complex32>,
    active: Vec<(usize, usize)>,
}

/// Fields from this many LR pixels up spread each update over the cores
/// ([`Epry::set_parallel`]).
const PARALLEL_FROM: usize = 384 * 384;

impl Epry {
    /// Start from an in-focus frame near the axis (`intensity`, normalised) for a
    /// square camera field of `n × n` pixels: its amplitude, up-sampled, is the first
    /// object estimate; the pupil starts as the ideal disc.
    pub fn new(system: &System, intensity: &Image, settings: Settings) -> Self {
        let (h, w) = intensity.dim();
        assert_eq!(h, w, "square fields only");
        let n = w;
        let u = settings.upsample.max(1);
        let nh = n * u;
        let d = system.sample_pixel_um();
        let df = 1.0 / (n as f64 * d);
        let cutoff = system.cutoff();
        // Every bin a sub-bin shifted pupil disc can reach (see `update_amplitude`).
        let reach = cutoff + 1.5 * df;
        let reachable: Vec<bool> = (0..n * n)
            .map(|i| {
                let (fx, fy) = (bin_frequency(i % n, n, d), bin_frequency(i / n, n, d));
                fx * fx + fy * fy <= reach * reach
            })
            .collect();
        let pupil_bins = (0..n * n)
            .filter(|&i| reachable[i])
            .map(|i| (i as u32, signed(i % n, n), signed(i / n, n)))
            .collect();
        // The defocus's phase relative to the axial wave's (a global phase); pupil bins
        // lie inside 1/λ, so none is evanescent.
        let z = settings.defocus_um;
        let (ax, ay) = defocus_transfer(0.0, 0.0, z, system.wavelength_um);
        let axial = Complex32::new(ax as f32, -ay as f32);
        let pupil = reachable
            .iter()
            .enumerate()
            .map(|(i, &s)| match (s, z == 0.0) {
                (false, _) => Complex32::default(),
                (true, true) => Complex32::new(1.0, 0.0),
                (true, false) => {
                    let (fx, fy) = (bin_frequency(i % n, n, d), bin_frequency(i / n, n, d));
                    let (re, im) = defocus_transfer(fx, fy, z, system.wavelength_um);
                    Complex32::new(re as f32, im as f32) * axial
                }
            })
            .collect();
        // Initial object: the frame's amplitude, its spectrum zero-padded to the HR grid.
        let mut fft = Fft2::new(n, n);
        let mut lr: Vec<Complex32> = intensity
            .iter()
            .map(|&v| Complex32::new(v.max(0.0).sqrt(), 0.0))
            .collect();
        fft.forward(&mut lr);
        let mut object = vec![Complex32::default(); nh * nh];
        let scale = (u * u) as f32;
        for ky in 0..n {
            for kx in 0..n {
                let (hy, hx) = (wrap(signed(ky, n), nh), wrap(signed(kx, n), nh));
                object[hy * nh + hx] = lr[ky * n + kx] * scale;
            }
        }
        let mut epry = Self {
            n,
            upsample: u,
            settings: Settings {
                upsample: u,
                ..settings
            },
            object,
            pupil,
            df,
            fft,
            psi: Vec::new(),
            phi: vec![Complex32::default(); n * n],
            pupil_bins,
            active: Vec::new(),
            disc_cols: (0..n)
                .filter(|&c| (0..n).any(|r| reachable[r * n + c]))
                .collect(),
            constrained: [0, n, 0, n],
            step_scale: 1.0,
            cutoff,
            curvature: None,
            parallel: false,
            waves: Vec::new(),
            object_weight: Vec::new(),
            pupil_weight: Vec::new(),
        };
        epry.set_parallel(n * n >= PARALLEL_FROM);
        epry
    }

    /// Impose the measured amplitude only `free` = [left, right, top, bottom] pixels
    /// away from the field's edges. A tile cut out of a larger frame is not periodic,
    /// but the FFT model makes it so: the wrap-around edge then scatters into the
    /// dark-field frames as light that was never measured. Left free, the border
    /// absorbs that mismatch instead of the object and the pupil.
    pub fn set_free_border(&mut self, free: [usize; 4]) {
        let n = self.n;
        let c0 = free[0].min(n / 2);
        let c1 = n - free[1].min(n / 2);
        let r0 = free[2].min(n / 2);
        let r1 = n - free[3].min(n / 2);
        self.constrained = [c0, c1.max(c0), r0, r1.max(r0)];
    }

    /// Spread each update over rayon's pool: the pruned transforms' rows and columns
    /// and the amplitude constraint's rows. On by default from 384² LR pixels. Smaller
    /// fields gain too when the cores are idle (up to 1.48× at 256² on two), but they are
    /// the demo's live field, whose camera and controller share those cores, and the
    /// tiles that already run side by side. Tiles run in parallel either way.
    pub fn set_parallel(&mut self, parallel: bool) {
        self.parallel = parallel;
        self.fft.set_parallel(parallel);
    }

    /// Scale both step sizes (1 = as in the settings).
    pub fn set_step_scale(&mut self, scale: f32) {
        self.step_scale = scale;
    }

    /// HR grid size.
    pub fn hr_size(&self) -> usize {
        self.n * self.upsample
    }

    /// The HR bin shift for illumination frequency `f` (cycles/µm), rounded.
    pub fn bin_shift(&self, f: (f64, f64)) -> (i64, i64) {
        (
            (f.0 / self.df).round() as i64,
            (f.1 / self.df).round() as i64,
        )
    }

    /// One EPRY update with a frame (normalised intensity) lit at frequency `f`.
    /// Returns the frame's relative amplitude error before the update (NaN when the
    /// frame has no measured light in the window: a dark-field frame over clear glass).
    pub fn update(&mut self, intensity: &Image, f: (f64, f64), update_pupil: bool) -> f64 {
        let amplitude = amplitude(intensity);
        self.update_amplitude(&amplitude, f, update_pupil)
    }

    /// [`Self::update`] with the frame's amplitude √I already taken (frames are used
    /// once per pass; taking the root once saves a square root per pixel per pass).
    pub fn update_amplitude(
        &mut self,
        amplitude: &Image,
        f: (f64, f64),
        update_pupil: bool,
    ) -> f64 {
        self.update_within(amplitude, 0.0, f, update_pupil)
    }

    /// [`Self::update_amplitude`] with the frame's noise allowed for: where the model's
    /// intensity lies within ±`band` of the measured one (normalised as the amplitude
    /// is, I / clear level), the model keeps it; beyond, it is brought to the band's
    /// nearer edge. A dim dark-field frame's pixels within their noise then do not
    /// pull the object toward that noise (0: the measured amplitude exactly).
    pub fn update_within(
        &mut self,
        amplitude: &Image,
        band: f32,
        f: (f64, f64),
        update_pupil: bool,
    ) -> f64 {
        let (pmax, omax) = self.exit_wave(f);
        let unnormalise = (self.n * self.n) as f32;
        // Amplitude constraint inside the constrained window (outside it the exit wave
        // floats); the HR/LR size ratio scales amplitudes by U².
        let gain = (self.upsample * self.upsample) as f32;
        let [c0, c1, r0, r1] = self.constrained;
        let n = self.n;
        let impose_row = |k: usize, row: &mut [Complex32]| {
            row_error::<true>(row, amplitude, r0 + k, (c0, c1), gain, unnormalise, band)
        };
        let add = |a: (f64, f64), b: (f64, f64)| (a.0 + b.0, a.1 + b.1);
        let window = &mut self.phi[r0 * n..r1 * n];
        let (err, norm) = if self.parallel {
            window
                .par_chunks_mut(n)
                .enumerate()
                .with_min_len(8)
                .map(|(k, row)| impose_row(k, row))
                .reduce(|| (0.0, 0.0), add)
        } else {
            window
                .chunks_mut(n)
                .enumerate()
                .map(|(k, row)| impose_row(k, row))
                .fold((0.0, 0.0), add)
        };
        // The free border keeps the model's exit wave, brought to scale.
        if self.constrained != [0, n, 0, n] {
            let norm = 1.0 / unnormalise;
            for (r, row) in self.phi.chunks_mut(n).enumerate() {
                if r < r0 || r >= r1 {
                    row.iter_mut().for_each(|v| *v *= norm);
                } else {
                    row[..c0].iter_mut().for_each(|v| *v *= norm);
                    row[c1..].iter_mut().for_each(|v| *v *= norm);
                }
            }
        }
        self.fft.forward_wanted_cols(&mut self.phi, &self.disc_cols);
        let (a_step, b_step) = (
            self.step_scale * self.settings.alpha / pmax.max(1e-12),
            self.step_scale * self.settings.beta / omax.max(1e-12),
        );
        for (&(i, o), &psi) in self.active.iter().zip(&self.psi) {
            let d = self.phi[i] - psi;
            let o_old = self.object[o];
            self.object[o] += self.pupil[i].conj() * d * a_step;
            if update_pupil {
                self.pupil[i] += o_old.conj() * d * b_step;
            }
        }
        relative_error(err, norm)
    }

    /// One update with a frame lit by several LEDs at once (multiplexed illumination,
    /// Tian et al., Biomed. Opt. Express 5, 2376, 2014): the LEDs are mutually
    /// incoherent, so the model's intensity is the sum of their exit waves'
    /// intensities, Σ|φ_j|². Each φ_j keeps its phase and is scaled by the one factor
    /// √I_measured / √Σ|φ_j|² (the measured amplitude shared among the waves in
    /// proportion to their own), then each LED's spectrum window updates the object
    /// and, for bright-field LEDs when `learn_pupil`, the pupil, as in
    /// [`Self::update_within`]. Where the LEDs' windows overlap, their corrections add
    /// up, so the steps are normalised by the largest Σ_j |P_j|² over the object's
    /// bins and Σ_j |O_j|² over the pupil's (as mixed-state ptychography normalises
    /// by the sum over its modes): without it eight bright-field LEDs, whose windows
    /// all hold the object's low frequencies, overshot eightfold and diverged.
    /// `band` as there, on the summed intensity. Returns the frame's relative
    /// amplitude error before the update. One frequency is [`Self::update_within`]
    /// exactly.
    pub fn update_multiplexed(
        &mut self,
        amplitude: &Image,
        band: f32,
        fs: &[(f64, f64)],
        learn_pupil: bool,
    ) -> f64 {
        let bright = |f: &(f64, f64)| f.0.hypot(f.1) < self.cutoff;
        match fs {
            [] => return f64::NAN,
            [f] => return self.update_within(amplitude, band, *f, learn_pupil && bright(f)),
            _ => {}
        }
        let n = self.n;
        while self.waves.len() < fs.len() {
            self.waves.push(Wave {
                phi: vec![Complex32::default(); n * n],
                ..Wave::default()
            });
        }
        for (j, &f) in fs.iter().enumerate() {
            self.exit_wave(f);
            let w = &mut self.waves[j];
            std::mem::swap(&mut w.phi, &mut self.phi);
            std::mem::swap(&mut w.psi, &mut self.psi);
            std::mem::swap(&mut w.active, &mut self.active);
        }
        let k = fs.len();
        let unnormalise = (n * n) as f32;
        let inv = 1.0 / unnormalise;
        let gain = (self.upsample * self.upsample) as f32;
        let [c0, c1, r0, r1] = self.constrained;
        let share = 1.0 / (k as f32).sqrt();
        let (mut err, mut norm) = (0.0f64, 0.0f64);
        let waves = &mut self.waves[..k];
        for r in 0..n {
            let inside_rows = r >= r0 && r < r1;
            for c in 0..n {
                let i = r * n + c;
                if !(inside_rows && c >= c0 && c < c1) {
                    // The free border keeps the model's exit waves, brought to scale.
                    waves.iter_mut().for_each(|w| w.phi[i] *= inv);
                    continue;
                }
                let m = amplitude[[r, c]];
                let target = m * gain;
                let a = waves
                    .iter()
                    .map(|w| w.phi[i].norm_sqr())
                    .sum::<f32>()
                    .sqrt()
                    * inv;
                err += ((a - target) * (a - target)) as f64;
                norm += (target * target) as f64;
                let wanted = if band > 0.0 {
                    let m2 = m * m;
                    a.clamp(
                        (m2 - band).max(0.0).sqrt() * gain,
                        (m2 + band).sqrt() * gain,
                    )
                } else {
                    target
                };
                if a > 1e-12 {
                    let factor = wanted / (a * unnormalise);
                    waves.iter_mut().for_each(|w| w.phi[i] *= factor);
                } else {
                    let even = Complex32::new(wanted * share, 0.0);
                    waves.iter_mut().for_each(|w| w.phi[i] = even);
                }
            }
        }
        let nh = self.hr_size();
        self.object_weight.resize(nh * nh, 0.0);
        self.pupil_weight.resize(n * n, 0.0);
        let learns: Vec<bool> = fs
            .iter()
            .map(|f| learn_pupil && f.0.hypot(f.1) < self.cutoff)
            .collect();
        let (mut pmax, mut omax) = (0.0f32, 0.0f32);
        for (w, &learn) in self.waves[..k].iter().zip(&learns) {
            for &(i, o) in &w.active {
                let weight = &mut self.object_weight[o];
                *weight += self.pupil[i].norm_sqr();
                pmax = pmax.max(*weight);
                if learn {
                    let weight = &mut self.pupil_weight[i];
                    *weight += self.object[o].norm_sqr();
                    omax = omax.max(*weight);
                }
            }
        }
        // Tried instead (k = 4 / 8, 128², docs/results.md): per-bin Σ_j |P_j|² 0.19 /
        // 0.24 (small weights at the pupil's edge), per bin floored at one wave's
        // largest 0.136 / 0.276, one wave's largest alone 0.115 / 0.97 (diverged); this
        // one 0.123 / 0.212.
        let a_step = self.step_scale * self.settings.alpha / pmax.max(1e-12);
        let b_step = self.step_scale * self.settings.beta / omax.max(1e-12);
        for (j, &learn) in learns.iter().enumerate() {
            let w = &mut self.waves[j];
            self.fft.forward_wanted_cols(&mut w.phi, &self.disc_cols);
            for (&(i, o), &psi) in w.active.iter().zip(&w.psi) {
                let d = w.phi[i] - psi;
                let o_old = self.object[o];
                self.object[o] += self.pupil[i].conj() * d * a_step;
                if learn {
                    self.pupil[i] += o_old.conj() * d * b_step;
                }
            }
        }
        for w in &self.waves[..k] {
            for &(i, o) in &w.active {
                self.object_weight[o] = 0.0;
                self.pupil_weight[i] = 0.0;
            }
        }
        relative_error(err, norm)
    }

    /// The model's exit wave for a frame lit at `f`, left unnormalised in `phi` (ψ on
    /// the active bins in `psi`). Returns max |P|² and max |O|² over the active bins.
    fn exit_wave(&mut self, f: (f64, f64)) -> (f32, f32) {
        let nh = self.hr_size() as i64;
        let (sx, sy) = self.bin_shift(f);
        // Sub-bin remainder δ = f/df − s: the exit wave times exp(−i2π δ·x) (same
        // intensity) has spectrum P(k + δ)·O(k − s), so the object is read on its grid
        // and the pupil disc is shifted by −δ bins instead.
        let (rx, ry) = (f.0 / self.df - sx as f64, f.1 / self.df - sy as f64);
        let radius2 = (self.cutoff / self.df).powi(2);
        // Each bin inside the shifted disc reads the object at O(k − s), wrapped onto
        // the HR grid.
        self.active.clear();
        self.active.extend(
            self.pupil_bins
                .iter()
                .filter(|&&(_, kx, ky)| {
                    (kx as f64 + rx).powi(2) + (ky as f64 + ry).powi(2) <= radius2
                })
                .map(|&(i, kx, ky)| {
                    let o = (ky - sy).rem_euclid(nh) * nh + (kx - sx).rem_euclid(nh);
                    (i as usize, o as usize)
                }),
        );
        // ψ = P · O(k − s) on the pupil, zero elsewhere.
        self.psi.clear();
        if self.parallel {
            self.phi
                .par_chunks_mut(self.n * 8)
                .for_each(|rows| rows.fill(Complex32::default()));
        } else {
            self.phi.fill(Complex32::default());
        }
        let mut omax = 0.0f32;
        let mut pmax = 0.0f32;
        for &(i, o) in &self.active {
            let (p, ob) = (self.pupil[i], self.object[o]);
            self.psi.push(p * ob);
            self.phi[i] = p * ob;
            omax = omax.max(ob.norm_sqr());
            pmax = pmax.max(p.norm_sqr());
        }
        // ψ lives on the pupil disc's columns only, and only those columns of the
        // forward transform are used: both FFTs skip the other columns' transforms
        // (unnormalised inverse; the amplitude constraint below is scale-free apart
        // from the error).
        self.fft
            .inverse_unnormalised_sparse_cols(&mut self.phi, &self.disc_cols);
        (pmax, omax)
    }

    /// The frame's relative amplitude error, ‖|φ| − √I‖ / ‖√I‖ over the constrained
    /// window, if it were lit at `f`: what [`Self::update_amplitude`] returns, without
    /// the update (LED refinement compares candidate positions with it).
    pub fn misfit(&mut self, amplitude: &Image, f: (f64, f64)) -> f64 {
        self.exit_wave(f);
        let unnormalise = (self.n * self.n) as f32;
        let gain = (self.upsample * self.upsample) as f32;
        let [c0, c1, r0, r1] = self.constrained;
        let n = self.n;
        let (mut err, mut norm) = (0.0f64, 0.0f64);
        for r in r0..r1 {
            let row = &mut self.phi[r * n..(r + 1) * n];
            let (e, m) = row_error::<false>(row, amplitude, r, (c0, c1), gain, unnormalise, 0.0);
            err += e;
            norm += m;
        }
        relative_error(err, norm)
    }

    /// [`Self::misfit`]'s unnormalised squared error Σ(|φ| − √I)² split over a
    /// `blocks` × `blocks` grid of the constrained window, row-major (LED refinement
    /// measures a frame's place in each block: their scatter is the place's
    /// uncertainty).
    pub fn misfit_blocks(&mut self, amplitude: &Image, f: (f64, f64), blocks: usize) -> Vec<f64> {
        self.exit_wave(f);
        let unnormalise = (self.n * self.n) as f32;
        let gain = (self.upsample * self.upsample) as f32;
        let [c0, c1, r0, r1] = self.constrained;
        let n = self.n;
        let blocks = blocks.max(1);
        let edge = |lo: usize, hi: usize, j: usize| lo + (hi - lo) * j / blocks;
        let mut out = vec![0.0; blocks * blocks];
        for r in r0..r1 {
            let by = ((r - r0) * blocks / (r1 - r0).max(1)).min(blocks - 1);
            let row = &mut self.phi[r * n..(r + 1) * n];
            for bx in 0..blocks {
                let (a, b) = (edge(c0, c1, bx), edge(c0, c1, bx + 1));
                if b > a {
                    out[by * blocks + bx] +=
                        row_error::<false>(row, amplitude, r, (a, b), gain, unnormalise, 0.0).0;
                }
            }
        }
        out
    }

    /// Add the frame lit at `f` to `sums`: its measured intensity against the
    /// intensity the current object and pupil predict, pixel by pixel over the
    /// constrained window ([`super::contrast`]).
    pub fn add_contrast(&mut self, amplitude: &Image, f: (f64, f64), sums: &mut ContrastSums) {
        self.exit_wave(f);
        // The model's amplitude in the measurement's units (see `update_amplitude`).
        let scale = 1.0 / ((self.n * self.n) as f32 * (self.upsample * self.upsample) as f32);
        let [c0, c1, r0, r1] = self.constrained;
        for r in r0..r1 {
            for c in c0..c1 {
                let model = (self.phi[r * self.n + c].norm() * scale) as f64;
                let measured = amplitude[[r, c]] as f64;
                sums.push(model * model, measured * measured);
            }
        }
        sums.frames += 1;
    }

    /// Multiply the current object by the illumination's curvature,
    /// exp(+iπ·|x − x_c|²/(λ·R)), x_c the field's centre pixel (see
    /// [`remove_illumination_curvature`], which undoes it). Seeding with it is what
    /// makes the curvature's removal hold at any field size: the curvature is nearly
    /// invisible in the intensities (a slowly varying phase shared by every LED), so
    /// from a flat start EPRY builds it in only where it amounts to well under a
    /// frequency bin across the field (measured on 441 simulated frames at
    /// h = 92 mm: a 154 µm field carried it, a 307 µm field carried 1.5 % of it, and
    /// dividing it out then left a bowl of −1.7 rad at the edges).
    pub fn apply_illumination_curvature(&mut self, wavelength_um: f64, distance_um: f64) {
        let nh = self.hr_size();
        let pitch_um = 1.0 / (nh as f64 * self.df);
        let mut fft = Fft2::new(nh, nh);
        fft.inverse(&mut self.object);
        let k = std::f64::consts::PI / (wavelength_um * distance_um);
        for (i, v) in self.object.iter_mut().enumerate() {
            let x = ((i % nh) as f64 - (nh / 2) as f64) * pitch_um;
            let y = ((i / nh) as f64 - (nh / 2) as f64) * pitch_um;
            *v *= Complex32::from_polar(1.0, (k * (x * x + y * y)) as f32);
        }
        fft.forward(&mut self.object);
        self.curvature = Some((wavelength_um, distance_um));
    }

    /// The sample's HR transmission: the object with the curvature it was seeded with
    /// divided out again (the object as is, if it was not seeded with one).
    pub fn sample(&mut self) -> ndarray::Array2<Complex32> {
        let mut field = self.object();
        if let Some((wavelength_um, distance_um)) = self.curvature {
            let pitch_um = 1.0 / (self.hr_size() as f64 * self.df);
            remove_illumination_curvature(&mut field, pitch_um, wavelength_um, distance_um);
        }
        field
    }

    /// The HR object (complex transmission), row-major `(n·U)²`.
    pub fn object(&mut self) -> ndarray::Array2<Complex32> {
        let nh = self.hr_size();
        let mut field = self.object.clone();
        let mut fft = Fft2::new(nh, nh);
        fft.inverse(&mut field);
        let norm = 1.0 / (self.upsample * self.upsample) as f32;
        ndarray::Array2::from_shape_fn((nh, nh), |(r, c)| field[r * nh + c] * norm)
    }

    /// The pupil on the LR grid, centred (zero frequency in the middle).
    pub fn pupil_centered(&self) -> ndarray::Array2<Complex32> {
        let n = self.n;
        ndarray::Array2::from_shape_fn((n, n), |(r, c)| {
            self.pupil[((r + n / 2) % n) * n + (c + n / 2) % n]
        })
    }

    /// Whether the pupil is being learned.
    pub fn settings(&self) -> Settings {
        self.settings
    }

    /// The frequency grid's bin step, cycles/µm.
    pub fn bin_step(&self) -> f64 {
        self.df
    }
}

/// Remove the curvature of the illumination from a reconstructed field. An LED at a
/// finite distance R lights the sample with a spherical wave: across the field its
/// phase is a tilt (the wave vector, known to EPRY) plus ≈ π·|x − x_c|²/(λ·R), which is
/// nearly the same for every LED and therefore belongs in the recovered object (EPRY
/// is seeded with it: [`Epry::apply_illumination_curvature`]). Over a 150 µm field at
/// R = 92 mm that is 0.4 rad at the edge; this divides it out, with R the distance
/// from the nearest-axis LED to the field centre. `pitch_um` is the field's pixel; its
/// centre pixel (n/2, n/2) is x_c.
pub fn remove_illumination_curvature(
    field: &mut ndarray::Array2<Complex32>,
    pitch_um: f64,
    wavelength_um: f64,
    distance_um: f64,
) {
    let (h, w) = field.dim();
    let k = std::f64::consts::PI / (wavelength_um * distance_um);
    for ((r, c), v) in field.indexed_iter_mut() {
        let (x, y) = (
            (c as f64 - (w / 2) as f64) * pitch_um,
            (r as f64 - (h / 2) as f64) * pitch_um,
        );
        *v *= Complex32::from_polar(1.0, (-k * (x * x + y * y)) as f32);
    }
}

/// [`amplitude_error`] over columns `c0..c1` of LR row `r` (`row` the whole row of the
/// exit wave), against the same pixels of `amplitude`.
fn row_error<const IMPOSE: bool>(
    row: &mut [Complex32],
    amplitude: &Image,
    r: usize,
    (c0, c1): (usize, usize),
    gain: f32,
    unnormalise: f32,
    band: f32,
) -> (f64, f64) {
    let measured = amplitude.row(r);
    let row = &mut row[c0..c1];
    let owned: Vec<f32>;
    let m = match measured.as_slice() {
        Some(m) => &m[c0..c1],
        None => {
            owned = measured.iter().skip(c0).take(c1 - c0).copied().collect();
            &owned
        }
    };
    // The band is chosen once per row, not per pixel: this loop is the update's hot one.
    if band > 0.0 {
        amplitude_error::<IMPOSE, true>(row, m, gain, unnormalise, band)
    } else {
        amplitude_error::<IMPOSE, false>(row, m, gain, unnormalise, 0.0)
    }
}

/// Σ(|ψ| − measured)² and Σ measured² over a row of the exit wave (unnormalised by
/// `unnormalise`; measured amplitudes times `gain`). With `IMPOSE`, each value's
/// modulus is then replaced by the measured amplitude, keeping its phase (a value with
/// no modulus becomes the measured amplitude itself), or, `BANDED`, clamped into
/// [√(m² − band), √(m² + band)] (`band` in squared measured amplitude); without, the
/// row is left as it is (LED refinement's misfit). Eight independent lanes keep the
/// sums from chaining every pixel to the last, so the loop vectorises; this is the only
/// per-pixel work of an update besides the FFTs.
fn amplitude_error<const IMPOSE: bool, const BANDED: bool>(
    row: &mut [Complex32],
    measured: &[f32],
    gain: f32,
    unnormalise: f32,
    band: f32,
) -> (f64, f64) {
    const LANES: usize = 8;
    let (mut err, mut norm) = ([0.0f32; LANES], [0.0f32; LANES]);
    let inv = 1.0 / unnormalise;
    let one = |p: &mut Complex32, m: f32, err: &mut f32, norm: &mut f32| {
        let target = m * gain;
        let a = p.norm_sqr().sqrt() * inv;
        *err += (a - target) * (a - target);
        *norm += target * target;
        if IMPOSE {
            let wanted = if BANDED {
                let m2 = m * m;
                a.clamp(
                    (m2 - band).max(0.0).sqrt() * gain,
                    (m2 + band).sqrt() * gain,
                )
            } else {
                target
            };
            *p = if a > 1e-12 {
                *p * (wanted / (a * unnormalise))
            } else {
                Complex32::new(wanted, 0.0)
            };
        }
    };
    let mut rows = row.chunks_exact_mut(LANES);
    let mut values = measured.chunks_exact(LANES);
    for (ps, ms) in (&mut rows).zip(&mut values) {
        for l in 0..LANES {
            one(&mut ps[l], ms[l], &mut err[l], &mut norm[l]);
        }
    }
    for (p, &m) in rows.into_remainder().iter_mut().zip(values.remainder()) {
        one(p, m, &mut err[0], &mut norm[0]);
    }
    let sum = |v: [f32; LANES]| v.iter().map(|&x| x as f64).sum::<f64>();
    (sum(err), sum(norm))
}

/// √(err / norm), or NaN without a norm: relative to nothing, an error means nothing
/// (and 1e-300 in its place made pass errors of 1e146 from tiles over clear glass).
fn relative_error(err: f64, norm: f64) -> f64 {
    if norm > 0.0 {
        (err / norm).sqrt()
    } else {
        f64::NAN
    }
}

/// √I, with negative (noise) intensities taken as zero.
pub fn amplitude(intensity: &Image) -> Image {
    intensity.mapv(|v| v.max(0.0).sqrt())
}

/// FFT bin `k` of an `n`-point grid as a signed frequency index.
fn signed(k: usize, n: usize) -> i64 {
    if k < n / 2 {
        k as i64
    } else {
        k as i64 - n as i64
    }
}

/// A signed index wrapped onto an `m`-point grid.
fn wrap(k: i64, m: usize) -> usize {
    k.rem_euclid(m as i64) as usize
}

/// Complex NRMSE (docs/dataset.md §6): min over complex c of ‖c·a − b‖/‖b‖.
pub fn complex_nrmse(a: &[Complex32], b: &[Complex32]) -> f64 {
    let (mut ab, mut aa, mut bb) = (rustfft::num_complex::Complex64::default(), 0.0f64, 0.0f64);
    for (x, y) in a.iter().zip(b) {
        let (x, y) = (x.to_f64(), y.to_f64());
        ab += x.conj() * y;
        aa += x.norm_sqr();
        bb += y.norm_sqr();
    }
    if aa == 0.0 || bb == 0.0 {
        return 1.0;
    }
    // ‖c a − b‖² minimised at c = ⟨a, b⟩/⟨a, a⟩: ‖b‖² − |⟨a, b⟩|²/‖a‖².
    ((bb - ab.norm_sqr() / aa).max(0.0) / bb).sqrt()
}

trait ToF64 {
    fn to_f64(self) -> rustfft::num_complex::Complex64;
}

impl ToF64 for Complex32 {
    fn to_f64(self) -> rustfft::num_complex::Complex64 {
        rustfft::num_complex::Complex64::new(self.re as f64, self.im as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optics::{LedGeometry, LedIndex};

    /// Within the noise band the model's amplitude is kept (its phase always is);
    /// beyond, it goes to the band's nearer edge; with no band, to the measurement.
    #[test]
    fn a_noise_band_keeps_the_model_within_it_and_clamps_it_beyond() {
        let measured = [1.0f32; 3];
        let model = [
            Complex32::new(0.9, 0.0),
            Complex32::new(0.0, 1.5),
            Complex32::new(0.1, 0.0),
        ];
        let mut banded = model;
        let (err, norm) = amplitude_error::<true, true>(&mut banded, &measured, 1.0, 1.0, 0.5);
        assert!((err - (0.01 + 0.25 + 0.81)).abs() < 1e-5 && (norm - 3.0).abs() < 1e-6);
        // Intensities 0.81 (within 1 ± 0.5), 2.25 (above) and 0.01 (below).
        let expected = [
            Complex32::new(0.9, 0.0),
            Complex32::new(0.0, 1.5f32.sqrt()),
            Complex32::new(0.5f32.sqrt(), 0.0),
        ];
        for (got, want) in banded.iter().zip(&expected) {
            assert!((got - want).norm() < 1e-6, "{got} against {want}");
        }
        let mut exact = model;
        amplitude_error::<true, false>(&mut exact, &measured, 1.0, 1.0, 0.0);
        assert!(exact.iter().all(|v| (v.norm() - 1.0).abs() < 1e-6));
    }

    /// Spreading an update over the pool changes only the order of the error's sums:
    /// the object and the pupil come out the same.
    #[test]
    fn a_parallel_update_equals_the_serial_one() {
        let system = System::paper();
        let geometry = LedGeometry::paper();
        let n = 64;
        let frame = Image::from_shape_fn((n, n), |(r, c)| {
            1.0 + 0.3 * ((r * 7 + c * 3) % 17) as f32 / 17.0
        });
        let settings = Settings {
            upsample: 2,
            ..Settings::default()
        };
        let run = |parallel: bool| {
            let mut epry = Epry::new(&system, &frame, settings);
            epry.set_parallel(parallel);
            epry.set_free_border([3, 0, 5, 0]);
            for led in geometry.leds().into_iter().step_by(7) {
                let f = geometry.illumination_frequency(led, 0.0, 0.0, system.wavelength_um);
                epry.update_amplitude(&frame, f, true);
            }
            (epry.object(), epry.pupil_centered())
        };
        let (serial, parallel) = (run(false), run(true));
        let close = |a: &ndarray::Array2<Complex32>, b: &ndarray::Array2<Complex32>| {
            let scale = a.iter().map(|v| v.norm()).fold(0.0f32, f32::max);
            a.iter().zip(b).all(|(x, y)| (x - y).norm() <= 1e-4 * scale)
        };
        assert!(close(&serial.0, &parallel.0), "objects differ");
        assert!(close(&serial.1, &parallel.1), "pupils differ");
    }

    /// The model's own multiplexed amplitude is a fixed point: nothing to correct,
    /// however the waves overlap; and one LED is the single-LED update exactly.
    #[test]
    fn a_multiplexed_update_keeps_a_frame_the_model_explains_and_reduces_to_one_led() {
        let system = System::paper();
        let geometry = LedGeometry::paper();
        let n = 32;
        let frame = Image::from_shape_fn((n, n), |(r, c)| {
            1.0 + 0.3 * ((r * 5 + c * 11) % 13) as f32 / 13.0
        });
        let settings = Settings {
            upsample: 2,
            ..Settings::default()
        };
        let f = |r, c| {
            geometry.illumination_frequency(LedIndex::new(r, c), 0.0, 0.0, system.wavelength_um)
        };
        let fs = [f(10, 10), f(10, 11), f(4, 13), f(17, 3)];
        let mut epry = Epry::new(&system, &frame, settings);
        let scale = 1.0 / ((n * n) as f32 * 4.0);
        let mut intensity = Image::zeros((n, n));
        for &fj in &fs {
            epry.exit_wave(fj);
            for (v, p) in intensity.iter_mut().zip(&epry.phi) {
                *v += (p.norm() * scale).powi(2);
            }
        }
        let before = epry.object();
        let error = epry.update_multiplexed(&amplitude(&intensity), 0.0, &fs, true);
        assert!(error < 1e-5, "error {error}");
        let after = epry.object();
        let peak = before.iter().map(|v| v.norm()).fold(0.0f32, f32::max);
        let moved = before
            .iter()
            .zip(&after)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0f32, f32::max);
        assert!(moved < 1e-4 * peak, "moved {moved} of {peak}");

        let one = |multiplexed: bool| {
            let mut epry = Epry::new(&system, &frame, settings);
            let e = if multiplexed {
                epry.update_multiplexed(&frame, 0.0, &[fs[2]], true)
            } else {
                epry.update_within(&frame, 0.0, fs[2], false)
            };
            (e, epry.object())
        };
        // (4, 13) is dark field: the pupil is not learned from it either way.
        let (a, b) = (one(true), one(false));
        assert_eq!(a.0, b.0);
        assert_eq!(a.1, b.1);
    }
}
