//! The focus stage, as the acquisition needs it: put a slide under the objective at a
//! given defocus. Implementations: [`ManualStage`] (the user turns the knob),
//! [`MotorisedFocus`] (the Z axis of a motorised stage, `fpm_stage`), the virtual rig's
//! stage (`fpm-rig`).

use std::str::FromStr;

use anyhow::{Context, Result};
use fpm_stage::{Connection, Stage, Target};

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

/// A stage that moves over the slide and focuses: what a scan drives.
pub trait ScanStage: Stage + FocusStage {}
impl<T: Stage + FocusStage> ScanStage for T {}

/// A focus stage.
pub trait FocusStage {
    /// Move to `to` and return once it is there (settled).
    fn move_to(&mut self, to: StagePosition) -> Result<()>;

    /// The sample, at the focus this stage holds, was measured `defocus_um` toward the
    /// LEDs: take that out of its focus, for the moves after (the next move to the
    /// sample in focus goes there). A scan refocuses each field so.
    fn refocus_sample(&mut self, defocus_um: f64) -> Result<()> {
        let _ = defocus_um;
        anyhow::bail!("this stage cannot refocus by itself: a scan needs a motorised stage")
    }

    /// This stage as one that also moves over the slide, for a scan (None: it only
    /// focuses, as a person turning the knob does).
    fn as_scan_stage(&mut self) -> Option<&mut dyn ScanStage> {
        None
    }
}

/// Which focus stage to use: `manual`, `virtual` (the virtual rig's), or a motorised
/// stage's connection (`gcode:/dev/ttyUSB0`, `sangaboard:/dev/ttyACM1`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum StageChoice {
    Manual,
    Virtual,
    Motorised(Connection),
}

impl FromStr for StageChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "manual" => Ok(Self::Manual),
            "virtual" => Ok(Self::Virtual),
            other => other.parse().map(Self::Motorised).map_err(|e| {
                format!("{e}; or `manual` (asked on the terminal) or `virtual` (the virtual rig's)")
            }),
        }
    }
}

impl std::fmt::Display for StageChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Manual => f.write_str("manual"),
            Self::Virtual => f.write_str("virtual"),
            Self::Motorised(c) => c.fmt(f),
        }
    }
}

/// The direction of the stage's Z that moves the sample toward the LEDs (relative to
/// the objective): depends on whether Z moves the sample or the objective, and on the
/// microscope being upright or inverted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TowardLeds {
    Plus,
    Minus,
}

impl FromStr for TowardLeds {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "plus" | "+" => Ok(Self::Plus),
            "minus" | "-" => Ok(Self::Minus),
            _ => Err(format!("`{s}`: give plus or minus")),
        }
    }
}

/// The Z axis of a motorised stage as the focus stage: the defocus is a Z move from
/// where the slide was focused. Changing slides still takes a person: each new slide
/// is asked for on the terminal, focused by the user, and that Z is its focus.
pub struct MotorisedFocus {
    stage: Box<dyn Stage>,
    toward_leds: TowardLeds,
    /// The slide on the stage and the Z it is in focus at.
    focused: Option<(Slide, f64)>,
}

impl MotorisedFocus {
    /// Drive `stage`'s Z; `toward_leds` is the Z direction that defocuses toward the LEDs.
    pub fn new(stage: Box<dyn Stage>, toward_leds: TowardLeds) -> Self {
        Self {
            stage,
            toward_leds,
            focused: None,
        }
    }

    /// The Z, µm, that puts the sample `defocus_um` toward the LEDs from `focus_z`.
    pub fn z_for(&self, focus_z: f64, defocus_um: f64) -> f64 {
        match self.toward_leds {
            TowardLeds::Plus => focus_z + defocus_um,
            TowardLeds::Minus => focus_z - defocus_um,
        }
    }
}

impl FocusStage for MotorisedFocus {
    fn move_to(&mut self, to: StagePosition) -> Result<()> {
        let focus_z = match self.focused {
            Some((slide, z)) if slide == to.slide => z,
            _ => {
                let what = match to.slide {
                    Slide::CalibrationTarget => "the calibration slide",
                    Slide::Sample => "the sample",
                };
                eprintln!("Put {what} on the stage and focus it, then press Enter.");
                let mut line = String::new();
                std::io::stdin()
                    .read_line(&mut line)
                    .context("waiting for the user to focus the slide")?;
                let z = Stage::position(&mut *self.stage)?.z_um;
                tracing::info!(z_um = z, "focus");
                self.focused = Some((to.slide, z));
                z
            }
        };
        let z = self.z_for(focus_z, to.defocus_um);
        let at = Stage::move_to(&mut *self.stage, Target::z(z))?;
        tracing::info!(defocus_um = to.defocus_um, z_um = at.z_um, "stage");
        Ok(())
    }

    fn refocus_sample(&mut self, defocus_um: f64) -> Result<()> {
        let Some((Slide::Sample, z)) = self.focused else {
            anyhow::bail!("the sample has not been focused on this stage yet");
        };
        let z = self.z_for(z, -defocus_um);
        tracing::info!(defocus_um, focus_z_um = z, "refocused");
        self.focused = Some((Slide::Sample, z));
        Ok(())
    }

    fn as_scan_stage(&mut self) -> Option<&mut dyn ScanStage> {
        Some(self)
    }
}

/// The stage itself, for moves over the slide (a scan).
impl Stage for MotorisedFocus {
    fn info(&self) -> fpm_stage::StageInfo {
        self.stage.info()
    }
    fn position(&mut self) -> Result<fpm_stage::Position, fpm_stage::StageError> {
        self.stage.position()
    }
    fn move_to(&mut self, target: Target) -> Result<fpm_stage::Position, fpm_stage::StageError> {
        self.stage.move_to(target)
    }
    fn home(&mut self) -> Result<fpm_stage::Position, fpm_stage::StageError> {
        self.stage.home()
    }
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
