//! LED sets (protocol 1.2): a table of LED lists uploaded once, each lit whole by a
//! sequence step that names it, for multiplexed illumination (several LEDs per frame,
//! Tian et al. 2014) and any pattern the device cannot compute itself.
//!
//! The table is filled in order: set 0 clears it and starts again, each later set
//! appends (`index` = the number defined). Steps naming sets are uploaded with
//! [`crate::SequenceSetStepsEndpoint`], into the same sequence as
//! [`crate::SequenceStepsEndpoint`]'s steps (a sequence may mix both), and reported on
//! [`crate::SetStepTopic`]. The 1.0 endpoints and topics are untouched: a host that
//! never defines a set sees nothing new.
//!
//! Errors reuse the 1.0 types (a new variant would change every 1.0 key): an index out
//! of order is [`DeviceError::ChunkOutOfRange`] (offset = the index, loaded = the sets
//! defined), a full table [`DeviceError::TooMany`], an empty set
//! [`DeviceError::BadParam`]`(`[`Param::StepCount`]`)`, and a step naming a set not
//! defined [`DeviceError::TooMany`] (requested = its index + 1, max = the sets defined).

use heapless::Vec;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

use crate::limits::{MAX_LEDS_PER_LIST, MAX_STEPS_PER_CHUNK};
#[allow(unused_imports)] // named in the docs above
use crate::{DeviceError, Param};
use crate::{LedIndex, ProtocolVersion, Rgb};

/// The protocol version that introduced LED sets.
pub const PROTOCOL_1_2: ProtocolVersion = ProtocolVersion { major: 1, minor: 2 };

/// Request of [`crate::LedSetDefineEndpoint`]: set `index` of the table.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LedSetDefine {
    /// 0 (clears the table first) or the number of sets defined (appends).
    pub index: u16,
    /// Its LEDs (at least one; duplicates lit once).
    pub leds: Vec<LedIndex, MAX_LEDS_PER_LIST>,
}

/// Reply of [`crate::LedSetDefineEndpoint`]: the table after the request.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LedSetsDefined {
    /// Sets defined.
    pub sets: u16,
    /// LEDs they hold together.
    pub leds: u16,
}

/// One step lighting a whole LED set.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SetStep {
    /// The set's index in the table.
    pub set: u16,
    /// The colour of every LED in it (global brightness applies).
    pub color: Rgb,
}

/// Request of [`crate::SequenceSetStepsEndpoint`]: a slice of the defined sequence,
/// each step lighting a set (as [`crate::StepChunk`] for single LEDs and patterns).
#[derive(Serialize, Deserialize, Schema, Debug, Clone, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SetStepChunk {
    /// Id given to [`crate::SequenceDefine`].
    pub id: u32,
    /// Index of the first step in this chunk; at most the number already loaded.
    pub offset: u16,
    /// The steps.
    pub steps: Vec<SetStep, MAX_STEPS_PER_CHUNK>,
}

/// Message of [`crate::SetStepTopic`]: a step lighting a set has finished (the fields
/// of [`crate::StepEvent`], the set in place of the illumination).
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SetStepEvent {
    /// Sequence id.
    pub sequence_id: u32,
    /// Step index, from 0.
    pub step: u16,
    /// The set lit.
    pub set: u16,
    /// In which colour.
    pub color: Rgb,
    /// LEDs lit during the step.
    pub leds_on: u16,
    /// Device time the LEDs were lit, µs.
    pub light_on_us: u64,
    /// Device time the trigger-out went active, µs.
    pub trigger_us: u64,
    /// Device time of the camera's trigger-in edge, if one was awaited, µs.
    pub trigger_in_us: Option<u64>,
    /// Device time the step ended, µs.
    pub end_us: u64,
}
