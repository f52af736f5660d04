//! Offline EPRY over one square field: every frame at hand, nearest-first passes.

use crate::optics::LedIndex;
use rustfft::num_complex::Complex32;

use super::schedule::{passes_over, PassFrame};
use super::{amplitude, Epry, Settings};
use crate::optics::{LedGeometry, System};
use crate::Image;

/// One frame for [`run`]: the LED and its intensity, normalised by exposure (any common
/// scale).
pub struct Shot<'a> {
    /// LED (row, col).
    pub led: LedIndex,
    /// The other LEDs lit in the same frame (multiplexed illumination); empty for one.
    pub also: &'a [LedIndex],
    /// Intensity.
    pub image: &'a Image,
}

/// The outcome of [`run`] or [`Streaming::finish`].
pub struct Outcome {
    /// The solver, for the object and pupil.
    pub epry: Epry,
    /// Mean relative amplitude error per pass.
    pub errors: Vec<f64>,
    /// Index into the shots of the frame nearest the axis (the initial guess).
    pub initial: usize,
    /// Each shot's illumination frequency at the end (cycles/µm, in the shots' order):
    /// refined when the settings ask for it ([`super::refine`]), else the geometry's.
    pub frequencies: Vec<(f64, f64)>,
    /// How far the refinement found LEDs off its board model (τ, 1σ per axis),
    /// cycles/µm (None unrefined).
    pub led_scatter: Option<f64>,
}

impl Outcome {
    /// The sample's HR transmission ([`Epry::sample`]: the illumination's curvature
    /// divided out).
    pub fn sample(&mut self) -> ndarray::Array2<Complex32> {
        self.epry.sample()
    }

    /// Put each frame's frequency (in the order the passes saw them, `order[j]` being
    /// the shot of frame `j`) back in the shots' order.
    pub(crate) fn unordered(order: &[usize], frequencies: Vec<(f64, f64)>) -> Vec<(f64, f64)> {
        let mut out = vec![(0.0, 0.0); order.len()];
        for (&k, f) in order.iter().zip(frequencies) {
            out[k] = f;
        }
        out
    }
}

/// The radius (µm) of the curvature EPRY's object is seeded with at `centre_um`: the
/// distance R from `led` to that point (its spherical wave's radius), combined with
/// the entrance pupil's distance p as 1/(1/R + 1/p). Across the field the chief ray
/// turns by x/p just as the illumination turns by x/R, and both move every frame's
/// window the same way, so the object carries both curvatures (and sheds them again).
pub(crate) fn illumination_radius_um(
    system: &System,
    geometry: &LedGeometry,
    led: LedIndex,
    centre_um: (f64, f64),
) -> f64 {
    let (lx, ly, lh) = geometry.led_position_3d_mm(led);
    let r =
        ((lx * 1e3 - centre_um.0).powi(2) + (ly * 1e3 - centre_um.1).powi(2) + (lh * 1e3).powi(2))
            .sqrt();
    match system.entrance_pupil_mm {
        Some(p_mm) => 1.0 / (1.0 / r + 1.0 / (p_mm * 1e3)),
        None => r,
    }
}

/// Where a square field sits in the camera frame and how its intensities are scaled.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Field {
    /// Sample-plane position of the field's centre pixel, µm: the wave vectors are
    /// taken there (a tile off the axis sees every LED at a different angle).
    pub centre_um: (f64, f64),
    /// The intensity of a clear sample under the initial (nearest-axis) LED, in the
    /// frames' units. `None`: the initial frame's own mean. Tiles of one frame share
    /// the whole frame's level so that their amplitudes agree.
    pub clear_level: Option<f32>,
    /// Pixels along [left, right, top, bottom] where the measurement is not imposed
    /// (see [`Epry::set_free_border`]): tiles leave their inner sides free.
    pub free_border: [usize; 4],
}

/// Reconstruct a square field from `shots` with the wave vectors of `geometry` at the
/// field's centre: frames sorted nearest-first by |f_i| (which also copes with a wrongly
/// chosen centre LED), the nearest one as the initial guess, the pupil learned from the
/// second pass on (bright-field frames), adaptive steps. `progress(done, total)` is
/// called after every update. `None` when no frame can seed the object (no frames, or a
/// black clear level).
pub fn run(
    system: &System,
    geometry: &LedGeometry,
    field: Field,
    shots: &[Shot<'_>],
    settings: Settings,
    passes: usize,
    progress: impl FnMut(usize, usize),
) -> Option<Outcome> {
    let leds: Vec<LedIndex> = shots.iter().map(|s| s.led).collect();
    let also: Vec<Vec<LedIndex>> = shots.iter().map(|s| s.also.to_vec()).collect();
    let lit = Lit {
        leds: &leds,
        also: &also,
    };
    let order = lit.nearest_first(geometry, field.centre_um, system);
    let initial = *order.first()?;
    let scale = match field.clear_level {
        Some(level) => Some(level).filter(|l| *l > 0.0)?,
        None => {
            let mean = shots[initial].image.mean().filter(|m| *m > 0.0)?;
            mean / lit.bright_field_count(initial, geometry, field.centre_um, system) as f32
        }
    };
    let amplitudes: Vec<Image> = shots
        .iter()
        .map(|s| amplitude(&(s.image / scale)))
        .collect();
    let frames = Amplitudes {
        leds: &leds,
        also: &also,
        images: &amplitudes,
        bands: &[],
    };
    run_amplitudes(system, geometry, field, frames, settings, passes, progress)
}

/// Which LEDs lit each frame: `leds[k]` and, for a multiplexed frame, `also[k]`
/// (`also` empty, or an empty entry: one LED).
#[derive(Debug, Clone, Copy)]
pub struct Lit<'a> {
    /// One LED of each frame (the first listed).
    pub leds: &'a [LedIndex],
    /// The other LEDs of each frame, in the same order (empty: none has any).
    pub also: &'a [Vec<LedIndex>],
}

impl Lit<'_> {
    /// Every LED of frame `k`.
    pub fn of(&self, k: usize) -> impl Iterator<Item = LedIndex> + '_ {
        let also: &[LedIndex] = self.also.get(k).map(Vec::as_slice).unwrap_or(&[]);
        std::iter::once(self.leds[k]).chain(also.iter().copied())
    }

    /// Frame `k`'s LED nearest the axis seen from `at_um`: the one that places a
    /// multiplexed frame in the nearest-first order and seeds the object.
    pub fn nearest(
        &self,
        k: usize,
        geometry: &LedGeometry,
        at_um: (f64, f64),
        system: &System,
    ) -> LedIndex {
        let radius = |led: &LedIndex| {
            let f = geometry.pupil_frequency(*led, at_um.0, at_um.1, system);
            f.0.hypot(f.1)
        };
        self.of(k)
            .min_by(|a, b| radius(a).total_cmp(&radius(b)).then(a.cmp(b)))
            .unwrap_or(self.leds[k])
    }

    /// The frames' indices nearest-first ([`LedGeometry::nearest_first`]), a
    /// multiplexed frame placed by its LED nearest the axis.
    pub fn nearest_first(
        &self,
        geometry: &LedGeometry,
        at_um: (f64, f64),
        system: &System,
    ) -> Vec<usize> {
        let nearest: Vec<LedIndex> = (0..self.leds.len())
            .map(|k| self.nearest(k, geometry, at_um, system))
            .collect();
        geometry.nearest_first(&nearest, at_um, system)
    }

    /// How many of frame `k`'s LEDs light the bright field seen from `at_um` (at least
    /// one): over clear glass a multiplexed frame is that many single-LED frames'
    /// intensity, so its level divided by this is the clear level.
    pub fn bright_field_count(
        &self,
        k: usize,
        geometry: &LedGeometry,
        at_um: (f64, f64),
        system: &System,
    ) -> usize {
        self.of(k)
            .filter(|&led| {
                let f = geometry.pupil_frequency(led, at_um.0, at_um.1, system);
                f.0.hypot(f.1) < system.cutoff()
            })
            .count()
            .max(1)
    }
}

/// Amplitudes already normalised to the clear level (√(I / clear)), one per LED: the
/// form in which tiles hand over their share of each frame.
#[derive(Debug, Clone, Copy)]
pub struct Amplitudes<'a> {
    /// The LEDs (the first of a multiplexed frame's).
    pub leds: &'a [LedIndex],
    /// The other LEDs of each multiplexed frame, in the same order (empty: none).
    pub also: &'a [Vec<LedIndex>],
    /// Their amplitudes, in the same order.
    pub images: &'a [Image],
    /// The intensity band each one's noise allows, I / clear level
    /// ([`Epry::update_within`]), in the same order (empty: none).
    pub bands: &'a [f32],
}

/// [`run`] on [`Amplitudes`].
pub fn run_amplitudes(
    system: &System,
    geometry: &LedGeometry,
    field: Field,
    frames: Amplitudes<'_>,
    settings: Settings,
    passes: usize,
    mut progress: impl FnMut(usize, usize),
) -> Option<Outcome> {
    let Amplitudes {
        leds,
        also,
        images: amplitudes,
        bands,
    } = frames;
    let lit = Lit { leds, also };
    let order = lit.nearest_first(geometry, field.centre_um, system);
    let initial = *order.first()?;
    // A multiplexed first frame seeds the object with its intensity per bright LED.
    let per_led = 1.0 / lit.bright_field_count(initial, geometry, field.centre_um, system) as f32;
    let seed = amplitudes[initial].mapv(|a| a * a * per_led);
    let mut epry = Epry::new(system, &seed, settings);
    epry.set_free_border(field.free_border);
    let seed_led = lit.nearest(initial, geometry, field.centre_um, system);
    epry.apply_illumination_curvature(
        system.wavelength_um,
        illumination_radius_um(system, geometry, seed_led, field.centre_um),
    );
    let (cx, cy) = field.centre_um;
    let frequency = |led| geometry.pupil_frequency(led, cx, cy, system);
    let others: Vec<Vec<(f64, f64)>> = (0..leds.len())
        .map(|k| lit.of(k).skip(1).map(frequency).collect())
        .collect();
    let frames: Vec<PassFrame<'_>> = order
        .iter()
        .map(|&k| PassFrame {
            amplitude: &amplitudes[k],
            band: bands.get(k).copied().unwrap_or(0.0),
            frequency: frequency(leds[k]),
            also: &others[k],
        })
        .collect();
    // The pupil is learned from the second pass on, once the object has a first shape.
    let done = passes_over(&mut epry, system, &frames, passes, 1, &mut progress);
    Some(Outcome {
        epry,
        errors: done.errors,
        initial,
        frequencies: Outcome::unordered(&order, done.frequencies),
        led_scatter: done.led_scatter,
    })
}
