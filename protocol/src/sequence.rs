//! Capture sequences: a list of illumination steps run by the device with its own clock,
//! each step lighting LEDs, pulsing the camera trigger and (optionally) waiting for the
//! camera to report the exposure.
//!
//! Timing of one step (device clock, µs):
//! ```text
//! t0            LEDs shifted out (takes ⌈changed/lanes⌉·led_shift + latch)
//! light_on      = t0 + shift time: the new LEDs are lit
//! trigger       = light_on + settle_us + trigger.delay_us: trigger-out goes active
//!                 for pulse_us (no trigger-out: trigger = light_on + settle_us)
//! end           = trigger-in edge (if configured; none within timeout_us → error)
//!                 or trigger + exposure_us, and never before the pulse has ended
//! ```
//! A [`StepEvent`] is published at each step's end, a [`SequenceEnd`] after the last.

use heapless::Vec;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

use crate::limits::MAX_STEPS_PER_CHUNK;
use crate::{DeviceError, LedIndex, Pattern, Rgb};

/// What one step lights.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Illumination {
    /// Nothing: a dark frame.
    Dark,
    /// One LED.
    Led(LedIndex),
    /// An on-device pattern.
    Pattern(Pattern),
}

/// One step of a capture sequence.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Step {
    /// What to light.
    pub illumination: Illumination,
    /// In which colour (global brightness applies).
    pub color: Rgb,
}

/// Level of a line while it is active.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Polarity {
    /// Idle low, pulse high.
    ActiveHigh,
    /// Idle high, pulse low.
    ActiveLow,
}

/// Which edge of the camera's output ends a step.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Edge {
    /// Low to high.
    Rising,
    /// High to low.
    Falling,
}

/// Trigger-out pulse sent to the camera at each step.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TriggerOut {
    /// Delay after the settle time, µs.
    pub delay_us: u32,
    /// Pulse width, µs (≥ 1).
    pub pulse_us: u32,
    /// Line polarity.
    pub polarity: Polarity,
}

/// Wait for the camera to signal the end of its exposure before the next step.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TriggerIn {
    /// The edge to wait for (only edges after the step's trigger count).
    pub edge: Edge,
    /// Longest wait after the trigger, µs (≥ 1); then the sequence ends with
    /// [`DeviceError::TriggerTimeout`].
    pub timeout_us: u32,
}

/// Timing and triggering of every step in a sequence.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SequenceTiming {
    /// Time from light-on to the trigger (LED and driver settling), µs.
    pub settle_us: u32,
    /// Time the light stays on after the trigger when no trigger-in is awaited, µs.
    pub exposure_us: u32,
    /// Trigger pulse to the camera, if any.
    pub trigger_out: Option<TriggerOut>,
    /// Camera exposure signal to wait for, if any.
    pub trigger_in: Option<TriggerIn>,
    /// Turn every LED off when the sequence ends (done, aborted or failed).
    pub clear_at_end: bool,
}

/// Request of [`crate::SequenceDefineEndpoint`]: announce a sequence and its timing.
/// Replaces any sequence that is not running.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SequenceDefine {
    /// Host-chosen id, echoed in every event.
    pub id: u32,
    /// Number of steps that will be uploaded.
    pub steps: u16,
    /// Timing of every step.
    pub timing: SequenceTiming,
}

/// Request of [`crate::SequenceStepsEndpoint`]: a slice of the defined sequence.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StepChunk {
    /// Id given to [`SequenceDefine`].
    pub id: u32,
    /// Index of the first step in this chunk; at most the number already loaded.
    pub offset: u16,
    /// The steps.
    pub steps: Vec<Step, MAX_STEPS_PER_CHUNK>,
}

/// Reply of [`crate::SequenceStepsEndpoint`].
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StepsLoaded {
    /// Steps loaded so far (contiguous from 0).
    pub loaded: u16,
    /// Steps defined.
    pub total: u16,
}

/// Reply of [`crate::SequenceStartEndpoint`].
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SequenceStarted {
    /// Sequence id.
    pub id: u32,
    /// Steps that will run.
    pub steps: u16,
    /// Device time of the start, µs.
    pub started_us: u64,
    /// Shortest possible run time (without trigger-in waits), µs.
    pub min_duration_us: u64,
}

/// Where the sequence engine is.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SequenceState {
    /// No sequence defined.
    Empty,
    /// Defined, steps still missing.
    Loading,
    /// Fully loaded, not running.
    Ready,
    /// Running.
    Running,
}

/// Reply of [`crate::SequenceStatusEndpoint`] and [`crate::SequenceAbortEndpoint`].
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SequenceStatus {
    /// Engine state.
    pub state: SequenceState,
    /// Id of the defined sequence (0 when empty).
    pub id: u32,
    /// Steps defined.
    pub total: u16,
    /// Steps uploaded.
    pub loaded: u16,
    /// Steps finished in the current or last run.
    pub completed: u16,
    /// How the last run ended, if one has ended since the sequence was defined.
    pub last_outcome: Option<SequenceOutcome>,
}

/// Message of [`crate::StepTopic`]: one step has finished.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StepEvent {
    /// Sequence id.
    pub sequence_id: u32,
    /// Step index, from 0.
    pub step: u16,
    /// What was lit.
    pub illumination: Illumination,
    /// In which colour.
    pub color: Rgb,
    /// LEDs lit during the step.
    pub leds_on: u16,
    /// Device time the LEDs were lit, µs.
    pub light_on_us: u64,
    /// Device time the trigger-out went active (light-on + settle without a
    /// trigger-out), µs.
    pub trigger_us: u64,
    /// Device time of the camera's trigger-in edge, if one was awaited, µs.
    pub trigger_in_us: Option<u64>,
    /// Device time the step ended, µs.
    pub end_us: u64,
}

/// How a run ended.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SequenceOutcome {
    /// Every step ran.
    Done,
    /// Stopped by [`crate::SequenceAbortEndpoint`].
    Aborted,
    /// Stopped by an error (e.g. [`DeviceError::TriggerTimeout`]).
    Failed(DeviceError),
}

/// Message of [`crate::SequenceEndTopic`]: the run has ended.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SequenceEnd {
    /// Sequence id.
    pub sequence_id: u32,
    /// Steps that finished.
    pub completed: u16,
    /// Why it ended.
    pub outcome: SequenceOutcome,
    /// Device time of the end, µs.
    pub end_us: u64,
}
