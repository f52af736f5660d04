//! The pass loop shared by offline and streaming EPRY, with the adaptive step size.

use super::refine::Search;
use super::Epry;
use crate::optics::System;
use crate::Image;

/// The adaptive step size of Zuo, Sun & Chen (Opt. Express 24, 20724, 2016; the lab
/// whose USAF data is vendored in `data/`): full steps while the error falls, halved each
/// time a pass improves it by less than 1 %. Full steps converge fast but then keep
/// chasing the noise of the last frames; halving averages it out (on the simulated
/// 441-frame set: complex NRMSE 0.115 with fixed full steps, 0.05 with the schedule).
#[derive(Debug, Clone, Copy)]
pub struct StepSchedule {
    scale: f32,
    last_error: Option<f64>,
}

impl Default for StepSchedule {
    fn default() -> Self {
        Self {
            scale: 1.0,
            last_error: None,
        }
    }
}

impl StepSchedule {
    /// After a pass with mean error `error`: the step scale for the next pass.
    pub fn after_pass(&mut self, error: f64) -> f32 {
        if let Some(last) = self.last_error {
            if last > 0.0 && (last - error) / last < 0.01 {
                self.scale *= 0.5;
            }
        }
        self.last_error = Some(error);
        self.scale
    }
}

/// A rise of the frames' error that says the solver is not converging (a wrong
/// geometry, steps too large), told apart from the rise the schedule itself makes:
/// once the steps are halved the object fits the noise less, and the error against
/// the noisy frames grows (on simulated stained sets 7–10 % over the last passes, the
/// image as good as ever). So: a pass at full steps that raised the error by more than
/// [`DIVERGED_STEP_RISE`], or a last pass more than [`DIVERGED_OVER_LEAST`] times the
/// least error. Returns (the pass that shows it, counted from 1; its error; the error
/// it is compared with).
pub fn divergence(errors: &[f64]) -> Option<(usize, f64, f64)> {
    let mut schedule = StepSchedule::default();
    for (k, pair) in errors.windows(2).enumerate() {
        // The scale the pass after `pair[0]` ran with.
        let scale = schedule.after_pass(pair[0]);
        if scale == 1.0 && pair[1] > DIVERGED_STEP_RISE * pair[0] {
            return Some((k + 2, pair[1], pair[0]));
        }
    }
    let least = errors.iter().copied().fold(f64::INFINITY, f64::min);
    let last = *errors.last()?;
    (last > DIVERGED_OVER_LEAST * least).then_some((errors.len(), last, least))
}

/// See [`divergence`]: a full-step pass's rise beyond 5 % is not noise.
pub const DIVERGED_STEP_RISE: f64 = 1.05;
/// See [`divergence`].
pub const DIVERGED_OVER_LEAST: f64 = 1.5;

/// What [`passes_over`] leaves besides the solver's state.
pub(crate) struct Passes {
    /// Mean error per pass.
    pub errors: Vec<f64>,
    /// Each frame's illumination frequency at the end, in the order given: refined
    /// when the settings ask for it, else as given.
    pub frequencies: Vec<(f64, f64)>,
    /// How far the refinement found LEDs off its board model, cycles/µm (None
    /// unrefined).
    pub led_scatter: Option<f64>,
}

/// One frame as the passes impose it.
#[derive(Debug, Clone, Copy)]
pub(crate) struct PassFrame<'a> {
    /// √(I / clear level).
    pub amplitude: &'a Image,
    /// The intensity band its noise allows ([`Epry::update_within`]; 0: none).
    pub band: f32,
    /// The illumination frequency the geometry gives it, cycles/µm.
    pub frequency: (f64, f64),
    /// The other LEDs lit in the same frame (multiplexed illumination), their
    /// frequencies likewise; empty for a frame lit by one LED.
    pub also: &'a [(f64, f64)],
}

/// `passes` passes over `frames`, in the order
/// given, with the adaptive step size; the pupil (if the settings learn it) is learned
/// from bright-field frames from pass `learn_from` on, and the frequencies refined if
/// the settings ask for it ([`super::refine`]). `progress(done, total)` after every
/// update.
pub(crate) fn passes_over(
    epry: &mut Epry,
    system: &System,
    frames: &[PassFrame<'_>],
    passes: usize,
    learn_from: usize,
    mut progress: impl FnMut(usize, usize),
) -> Passes {
    let mut errors = Vec::with_capacity(passes);
    let mut schedule = StepSchedule::default();
    let mut lit = Vec::new();
    let mut search = epry.settings().refine_leds.map(|r| {
        Search::new(
            r,
            epry.bin_step(),
            frames.iter().map(|f| f.frequency).collect(),
            system.wavelength_um,
        )
    });
    for pass in 0..passes {
        let (mut e, mut counted) = (0.0, 0usize);
        for (j, frame) in frames.iter().enumerate() {
            let (img, given) = (frame.amplitude, frame.frequency);
            if !frame.also.is_empty() {
                // Several LEDs: their frequencies as the geometry gives them (a
                // multiplexed frame cannot tell which of its LEDs is off).
                lit.clear();
                lit.push(given);
                lit.extend_from_slice(frame.also);
                let learn = epry.settings().update_pupil && pass >= learn_from;
                let error = epry.update_multiplexed(img, frame.band, &lit, learn);
                if error.is_finite() {
                    e += error;
                    counted += 1;
                }
                progress(pass * frames.len() + j + 1, passes * frames.len());
                continue;
            }
            // Bright-field by the geometry's frequency: refinement moves a frame by a
            // fraction of a bin, and which frames teach the pupil should not flicker.
            let learn = epry.settings().update_pupil
                && pass >= learn_from
                && given.0.hypot(given.1) < system.cutoff();
            let f = match search.as_mut() {
                Some(s) if s.active(pass) => s.step(epry, j, img),
                Some(s) => s.frequency(j),
                None => given,
            };
            let error = epry.update_within(img, frame.band, f, learn);
            // Frames with no light in this field have no relative error.
            if error.is_finite() {
                e += error;
                counted += 1;
            }
            progress(pass * frames.len() + j + 1, passes * frames.len());
        }
        if let Some(s) = search.as_mut().filter(|s| s.active(pass)) {
            s.project();
        }
        let e = e / counted.max(1) as f64;
        errors.push(e);
        epry.set_step_scale(schedule.after_pass(e));
    }
    let (frequencies, led_scatter) = match search {
        Some(s) => (s.frequencies(), Some(s.scatter())),
        None => (frames.iter().map(|f| f.frequency).collect(), None),
    };
    Passes {
        errors,
        frequencies,
        led_scatter,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Error per pass of runs of the repo's simulator (128², 441 LEDs).
    const STAINED_TRUE_GEOMETRY: [f64; 10] = [
        0.2739, 0.2247, 0.2221, 0.2189, 0.2172, 0.2327, 0.2615, 0.2813, 0.2896, 0.2932,
    ];
    const WEAK_PHASE_NOMINAL_GEOMETRY: [f64; 10] = [
        1.1549, 1.3396, 2.7872, 2.7684, 2.7804, 2.7878, 2.7915, 2.7933, 2.7941, 2.7945,
    ];

    #[test]
    fn a_rise_after_the_steps_are_halved_is_not_a_divergence() {
        // The stained set's image was good (complex NRMSE 0.094); its error rose 7 %
        // over the first pass's once the schedule halved the steps.
        assert_eq!(divergence(&STAINED_TRUE_GEOMETRY), None);
    }

    #[test]
    fn a_rise_at_full_steps_or_far_above_the_least_is() {
        // The weak-phase set with the array 5° off (complex NRMSE 0.98).
        assert_eq!(
            divergence(&WEAK_PHASE_NOMINAL_GEOMETRY),
            Some((2, 1.3396, 1.1549))
        );
        // A slow climb, each pass within 1 %: the steps halve, the error doubles.
        let climb: Vec<f64> = (0..80).map(|k| 0.2 * 1.009f64.powi(k)).collect();
        let (pass, last, least) = divergence(&climb).unwrap();
        assert_eq!((pass, least), (80, 0.2));
        assert!(last > 1.5 * least);
        assert_eq!(divergence(&[0.3]), None);
        assert_eq!(divergence(&[]), None);
    }
}
