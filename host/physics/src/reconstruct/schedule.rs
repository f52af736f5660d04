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

/// What [`passes_over`] leaves besides the solver's state.
pub(crate) struct Passes {
    /// Mean error per pass.
    pub errors: Vec<f64>,
    /// Each frame's illumination frequency at the end, in the order given: refined
    /// when the settings ask for it, else as given.
    pub frequencies: Vec<(f64, f64)>,
}

/// `passes` passes over `frames` (amplitude, illumination frequency), in the order
/// given, with the adaptive step size; the pupil (if the settings learn it) is learned
/// from bright-field frames from pass `learn_from` on, and the frequencies refined if
/// the settings ask for it ([`super::refine`]). `progress(done, total)` after every
/// update.
pub(crate) fn passes_over(
    epry: &mut Epry,
    system: &System,
    frames: &[(&Image, (f64, f64))],
    passes: usize,
    learn_from: usize,
    mut progress: impl FnMut(usize, usize),
) -> Passes {
    let mut errors = Vec::with_capacity(passes);
    let mut schedule = StepSchedule::default();
    let mut search = epry
        .settings()
        .refine_leds
        .map(|r| Search::new(r, epry.bin_step(), frames.iter().map(|f| f.1).collect()));
    for pass in 0..passes {
        let (mut e, mut counted) = (0.0, 0usize);
        for (j, &(img, given)) in frames.iter().enumerate() {
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
            let error = epry.update_amplitude(img, f, learn);
            // Frames with no light in this field have no relative error.
            if error.is_finite() {
                e += error;
                counted += 1;
            }
            progress(pass * frames.len() + j + 1, passes * frames.len());
        }
        if let Some(s) = search.as_mut().filter(|s| s.active(pass)) {
            s.remove_common();
        }
        let e = e / counted.max(1) as f64;
        errors.push(e);
        epry.set_step_scale(schedule.after_pass(e));
    }
    let frequencies = match search {
        Some(s) => s.frequencies(),
        None => frames.iter().map(|f| f.1).collect(),
    };
    Passes {
        errors,
        frequencies,
    }
}
