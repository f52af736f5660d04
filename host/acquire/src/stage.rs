//! The focus stage, as the acquisition needs it: put a slide under the objective at a
//! given defocus. Implementations: [`ManualStage`] (the user turns the knob), the
//! virtual rig's stage (`fpm-rig`), later motorised stages.

use anyhow::{Context, Result};

/// Which slide is on the stage.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Slide {
    /// The specimen.
    Sample,
    /// A slide with one small isolated feature (pinhole, bead), for pdcFPM.
    CalibrationTarget,
}

/// Where the stage should be.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StagePosition {
    /// The slide under the objective.
    pub slide: Slide,
    /// Sample moved toward the LEDs by this much, µm (0 = in focus).
    pub defocus_um: f64,
}

impl StagePosition {
    /// `slide` in focus.
    pub fn in_focus(slide: Slide) -> Self {
        Self {
            slide,
            defocus_um: 0.0,
        }
    }
}

/// A focus stage.
pub trait FocusStage {
    /// Move to `to` and return once it is there (settled).
    fn move_to(&mut self, to: StagePosition) -> Result<()>;
}

/// A stage moved by hand: the user is asked on the terminal and confirms with Enter.
#[derive(Debug, Default, Clone, Copy)]
pub struct ManualStage;

impl FocusStage for ManualStage {
    fn move_to(&mut self, to: StagePosition) -> Result<()> {
        let what = match to.slide {
            Slide::CalibrationTarget => "the calibration slide",
            Slide::Sample => "the sample",
        };
        eprintln!(
            "Put {what} on the stage, move it {:.0} µm {} the focus, then press Enter.",
            to.defocus_um.abs(),
            if to.defocus_um > 0.0 {
                "toward the LEDs from"
            } else {
                "back to"
            }
        );
        let mut line = String::new();
        std::io::stdin()
            .read_line(&mut line)
            .context("waiting for the user to move the stage")?;
        Ok(())
    }
}
