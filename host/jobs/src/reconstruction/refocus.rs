//! How far the frames are refocused, and why: a distance given, or the defocus the
//! bright-field frames' shifts show ([`fpm_physics::reconstruct::refocus`]).

use anyhow::Result;
use fpm_physics::reconstruct::refocus::{DefocusEstimate, ShiftReader};
use fpm_physics::{LedGeometry, LedIndex, System};
use serde::Serialize;

use super::lit;
use crate::dataset::DatasetOnDisk;

/// How the distance was chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum RefocusChoice {
    /// Given (`--refocus-um D`).
    Given,
    /// As the frames' shifts say (`--refocus-um auto`).
    Auto,
    /// As the frames' shifts say where they clearly show a defocus, else none (the
    /// default).
    WhereClear,
}

/// `refocus` in `report.json`.
#[derive(Debug, Clone, Serialize)]
pub struct RefocusReport {
    /// The distance the frames were refocused by, µm (toward the LEDs positive).
    pub refocus_um: f64,
    /// How it was chosen.
    pub choice: RefocusChoice,
    /// What the bright-field frames' shifts show, with every frame's shift (None: a
    /// distance was given, or too few bright-field frames with texture to read).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub estimate: Option<DefocusEstimate>,
}

impl RefocusReport {
    /// Refocused by a distance given.
    pub fn given(refocus_um: f64) -> Self {
        Self {
            refocus_um,
            choice: RefocusChoice::Given,
            estimate: None,
        }
    }

    /// Refocused as `choice` says of `estimate`.
    pub fn found(choice: RefocusChoice, estimate: Option<DefocusEstimate>) -> Self {
        let refocus_um = match (choice, &estimate) {
            (RefocusChoice::Auto, Some(e)) => e.z_um,
            (RefocusChoice::WhereClear, Some(e)) if e.is_clear() => e.z_um,
            _ => 0.0,
        };
        Self {
            refocus_um,
            choice,
            estimate,
        }
    }

    /// What a user should know about the focus, with what to do (None: nothing).
    pub fn warning(&self) -> Option<String> {
        self.warning_with("focus the microscope before the next acquisition")
    }

    /// [`warning`](Self::warning) for one colour of a colour run: the colours focus
    /// apart by the objective's chromatic focal shift, so focusing the microscope for
    /// this one defocuses the others.
    pub fn warning_for_colour(&self) -> Option<String> {
        self.warning_with(
            "the colours of a run focus apart (the objective's chromatic focal shift; a colour calibration measures it), so focus the microscope in the colour that matters most",
        )
    }

    /// The warning, with `focus_advice` for a sample clearly out of focus.
    fn warning_with(&self, focus_advice: &str) -> Option<String> {
        let e = self.estimate.as_ref()?;
        let shown = format!(
            "the bright-field frames' shifts put the sample {:.1} ± {:.1} µm out of focus ({} of {} frames fit, rms {:.2} µm)",
            e.z_um,
            e.sigma_um,
            e.kept(),
            e.shifts.len(),
            e.residual_um
        );
        match self.choice {
            RefocusChoice::Given => None,
            RefocusChoice::WhereClear if e.is_clear() => Some(format!(
                "{shown}: the image is refocused by it; {focus_advice}, or give --refocus-um 0 to reconstruct as in focus"
            )),
            RefocusChoice::WhereClear => None,
            RefocusChoice::Auto if !e.is_clear() => Some(format!(
                "{shown}, not clearly out of focus: refocused by it as --refocus-um auto asks; leave the flag out to reconstruct as in focus"
            )),
            RefocusChoice::Auto => None,
        }
    }
}

/// The defocus the in-focus frames of a dataset on disk show, read one frame at a
/// time (only the bright-field ones past the reference).
pub fn defocus_on_disk(
    ds: &DatasetOnDisk,
    system: &System,
    geometry: &LedGeometry,
) -> Result<Option<DefocusEstimate>> {
    // A shift is one LED's: frames lit by several take no part.
    let indices: Vec<usize> = ds
        .in_focus()
        .into_iter()
        .filter(|&k| !ds.manifest.frames[k].is_multiplexed())
        .collect();
    let leds: Vec<LedIndex> = indices.iter().map(|&k| ds.manifest.frames[k].led).collect();
    let Some(&first) = geometry.nearest_first(&leds, (0.0, 0.0), system).first() else {
        return Ok(None);
    };
    let reference = indices[first];
    let pixels = ds.frame(reference)?;
    let Some(mut reader) = ShiftReader::new(system, geometry, &lit(ds, reference, &pixels)) else {
        return Ok(None);
    };
    for (&k, &led) in indices.iter().zip(&leds) {
        if k != reference && geometry.is_bright_field(led, 0.0, 0.0, system) {
            let pixels = ds.frame(k)?;
            reader.read(&lit(ds, k, &pixels));
        }
    }
    Ok(reader.estimate())
}
