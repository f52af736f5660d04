//! Capture sequences: storage of the uploaded steps, and the run engine that turns them
//! into timed actions. The engine is a pure state machine: [`Engine::next`] says what to
//! do at a given time; the device carries it out and reports back.

use fpm_protocol::{
    limits::MAX_SEQUENCE_STEPS, DeviceError, Edge, Param, SequenceDefine, SequenceEnd,
    SequenceOutcome, SequenceState, SequenceStatus, SequenceTiming, SetStep, SetStepEvent, Step,
    StepEvent, StepsLoaded,
};
use heapless::Vec;

/// One loaded step: a 1.0 step (an LED, a pattern, dark) or one lighting a set of the
/// LED set table (1.2). A sequence may hold both.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Stored {
    /// Uploaded with `fpm/seq/steps`.
    Step(Step),
    /// Uploaded with `fpm/seq/set-steps`.
    Set(SetStep),
}

/// A finished step's report, on the topic its kind is reported on.
#[derive(Debug, Clone, PartialEq)]
pub enum Done {
    /// `fpm/seq/step`.
    Step(StepEvent),
    /// `fpm/seq/set-step`.
    Set(SetStepEvent),
}

/// What the device must do next for a running sequence.
#[derive(Debug, Clone, PartialEq)]
pub enum Action {
    /// Light step `step`'s LEDs now, then report with [`Engine::lit`].
    Light {
        /// Step index.
        step: u16,
    },
    /// Drive the trigger output active (`true`) or idle (`false`).
    Trigger(bool),
    /// A step finished: publish it.
    StepDone(Done),
    /// The run ended: publish it (and clear the LEDs if the timing says so).
    End(SequenceEnd),
    /// Nothing to do before this time (`None`: only an event can change anything).
    WaitUntil(Option<u64>),
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Phase {
    /// Waiting to light the step at the given time.
    Light(u64),
    /// Light is being shifted out; the device reports back with `lit`.
    Lighting,
    /// Lit; the trigger is due at the given time.
    Trigger(u64),
    /// Triggered; waiting for the pulse to end and the exposure (or camera edge).
    Expose,
}

#[derive(Debug, Clone, Copy)]
struct Run {
    step: u16,
    phase: Phase,
    light_on: u64,
    leds_on: u16,
    trigger_at: u64,
    pulse_end: Option<u64>,
    pulse_end_at: u64,
    edge_at: Option<u64>,
}

/// Each step after the first settles up to this much longer, µs ([`trigger_dither_us`]).
pub const TRIGGER_DITHER_MAX_US: u64 = 1023;

/// The extra settle of step `step`, 0 to [`TRIGGER_DITHER_MAX_US`] µs, pseudo-random by
/// the step's index (0 for the first step).
///
/// Why: a periodic sequence's triggers look alike a whole step apart, so a camera's
/// stamps cannot tell which trigger took which frame once frames arrive later than a
/// step or the first ones are lost; the host then waits for the sequence's end to label
/// them. With each interval lengthened by its own amount, the intervals are a
/// fingerprint only the true pairing reproduces in the stamps (the host's labeller
/// checks it), from a handful of frames on. Reported in each step's `trigger_us`, so the
/// host needs no copy of this function. The LEDs only stay lit a little longer: the
/// exposure follows the trigger as before.
pub fn trigger_dither_us(step: u16) -> u64 {
    if step == 0 {
        return 0;
    }
    // murmur3's 32-bit finaliser: neighbouring steps get unrelated values.
    let mut h = u32::from(step);
    h ^= h >> 16;
    h = h.wrapping_mul(0x85eb_ca6b);
    h ^= h >> 13;
    h = h.wrapping_mul(0xc2b2_ae35);
    h ^= h >> 16;
    u64::from(h) % (TRIGGER_DITHER_MAX_US + 1)
}

/// The one sequence slot and its run state.
pub struct Engine {
    id: u32,
    total: u16,
    timing: Option<SequenceTiming>,
    steps: Vec<Stored, MAX_SEQUENCE_STEPS>,
    run: Option<Run>,
    completed: u16,
    last_outcome: Option<SequenceOutcome>,
}

impl Default for Engine {
    fn default() -> Self {
        Self::new()
    }
}

impl Engine {
    /// No sequence defined.
    pub const fn new() -> Self {
        Self {
            id: 0,
            total: 0,
            timing: None,
            steps: Vec::new(),
            run: None,
            completed: 0,
            last_outcome: None,
        }
    }

    /// Whether a run is in progress.
    pub fn is_running(&self) -> bool {
        self.run.is_some()
    }

    /// The defined timing, if any.
    pub fn timing(&self) -> Option<&SequenceTiming> {
        self.timing.as_ref()
    }

    /// The uploaded steps.
    pub fn steps(&self) -> &[Stored] {
        &self.steps
    }

    /// State report.
    pub fn status(&self) -> SequenceStatus {
        let state = if self.run.is_some() {
            SequenceState::Running
        } else if self.timing.is_none() {
            SequenceState::Empty
        } else if (self.steps.len() as u16) < self.total {
            SequenceState::Loading
        } else {
            SequenceState::Ready
        };
        SequenceStatus {
            state,
            id: self.id,
            total: self.total,
            loaded: self.steps.len() as u16,
            completed: self.completed,
            last_outcome: self.last_outcome,
        }
    }

    /// Define a new sequence, replacing the old one.
    pub fn define(&mut self, def: &SequenceDefine) -> Result<SequenceStatus, DeviceError> {
        if self.run.is_some() {
            return Err(DeviceError::Busy);
        }
        if def.steps == 0 {
            return Err(DeviceError::BadParam(Param::StepCount));
        }
        if def.steps as usize > MAX_SEQUENCE_STEPS {
            return Err(DeviceError::TooMany {
                requested: def.steps as u32,
                max: MAX_SEQUENCE_STEPS as u32,
            });
        }
        if let Some(t) = def.timing.trigger_out {
            if t.pulse_us == 0 {
                return Err(DeviceError::BadParam(Param::PulseWidth));
            }
        }
        if let Some(t) = def.timing.trigger_in {
            if t.timeout_us == 0 {
                return Err(DeviceError::BadParam(Param::TriggerTimeout));
            }
        }
        *self = Self {
            id: def.id,
            total: def.steps,
            timing: Some(def.timing),
            ..Self::new()
        };
        Ok(self.status())
    }

    /// Load a chunk of steps of sequence `id` from `offset`, each checked by
    /// `check(index, step)` first. A failing chunk loads nothing.
    pub fn load(
        &mut self,
        id: u32,
        offset: u16,
        steps: &[Stored],
        mut check: impl FnMut(u16, &Stored) -> Result<(), DeviceError>,
    ) -> Result<StepsLoaded, DeviceError> {
        if self.run.is_some() {
            return Err(DeviceError::Busy);
        }
        if self.timing.is_none() || id != self.id {
            return Err(DeviceError::WrongSequence {
                requested: id,
                defined: if self.timing.is_some() { self.id } else { 0 },
            });
        }
        let loaded = self.steps.len() as u16;
        let len = steps.len() as u16;
        let end = offset as u32 + len as u32;
        if offset > loaded || end > self.total as u32 {
            return Err(DeviceError::ChunkOutOfRange {
                offset,
                len,
                loaded,
                total: self.total,
            });
        }
        for (i, step) in steps.iter().enumerate() {
            check(offset + i as u16, step)?;
        }
        for (i, step) in steps.iter().enumerate() {
            let idx = offset as usize + i;
            if let Some(slot) = self.steps.get_mut(idx) {
                *slot = *step;
            } else if self.steps.push(*step).is_err() {
                // Unreachable: `end <= total <= MAX_SEQUENCE_STEPS` was checked above.
                return Err(DeviceError::TooMany {
                    requested: end,
                    max: MAX_SEQUENCE_STEPS as u32,
                });
            }
        }
        self.completed = 0;
        Ok(StepsLoaded {
            loaded: self.steps.len() as u16,
            total: self.total,
        })
    }

    /// Start the loaded sequence at `now`.
    pub fn start(&mut self, id: u32, now: u64) -> Result<(), DeviceError> {
        if self.run.is_some() {
            return Err(DeviceError::Busy);
        }
        if self.timing.is_none() || id != self.id {
            return Err(DeviceError::WrongSequence {
                requested: id,
                defined: if self.timing.is_some() { self.id } else { 0 },
            });
        }
        let loaded = self.steps.len() as u16;
        if loaded < self.total {
            return Err(DeviceError::Incomplete {
                loaded,
                total: self.total,
            });
        }
        self.completed = 0;
        self.run = Some(Run {
            step: 0,
            phase: Phase::Light(now),
            light_on: now,
            leds_on: 0,
            trigger_at: now,
            pulse_end: None,
            pulse_end_at: now,
            edge_at: None,
        });
        Ok(())
    }

    /// Shortest run time: settle (with its dither), trigger delay and exposure (or
    /// pulse) of every step, without LED shift times or trigger-in waits, µs.
    pub fn min_duration_us(&self) -> u64 {
        let Some(t) = self.timing else { return 0 };
        let (delay, pulse) = t
            .trigger_out
            .map(|o| (o.delay_us as u64, o.pulse_us as u64))
            .unwrap_or((0, 0));
        let expose = if t.trigger_in.is_some() {
            0
        } else {
            t.exposure_us as u64
        };
        let dither: u64 = (0..self.total).map(trigger_dither_us).sum();
        (t.settle_us as u64 + delay + expose.max(pulse)) * self.total as u64 + dither
    }

    /// The device has shifted out the current step's LEDs: they are lit from `light_on`.
    pub fn lit(&mut self, light_on: u64, leds_on: u16) {
        let Some(t) = self.timing else { return };
        if let Some(run) = self.run.as_mut() {
            if run.phase == Phase::Lighting {
                run.light_on = light_on;
                run.leds_on = leds_on;
                let delay = t.trigger_out.map(|o| o.delay_us as u64).unwrap_or(0);
                let dither = trigger_dither_us(run.step);
                run.phase = Phase::Trigger(light_on + t.settle_us as u64 + dither + delay);
            }
        }
    }

    /// A trigger-in edge arrived at `at`. Only edges of the configured kind, after the
    /// current step's trigger, count.
    pub fn edge(&mut self, edge: Edge, at: u64) {
        let Some(want) = self.timing.and_then(|t| t.trigger_in).map(|t| t.edge) else {
            return;
        };
        if let Some(run) = self.run.as_mut() {
            if run.phase == Phase::Expose
                && edge == want
                && at >= run.trigger_at
                && run.edge_at.is_none()
            {
                run.edge_at = Some(at);
            }
        }
    }

    /// End the run now (host abort, or a failure found by the device).
    pub fn stop(&mut self, outcome: SequenceOutcome, now: u64) -> Option<SequenceEnd> {
        self.run.take()?;
        self.last_outcome = Some(outcome);
        Some(SequenceEnd {
            sequence_id: self.id,
            completed: self.completed,
            outcome,
            end_us: now,
        })
    }

    /// What to do at `now`. Call repeatedly until it answers [`Action::WaitUntil`].
    pub fn next(&mut self, now: u64) -> Action {
        let (Some(t), Some(run)) = (self.timing, self.run.as_mut()) else {
            return Action::WaitUntil(None);
        };
        match run.phase {
            Phase::Light(at) => {
                if run.step >= self.total {
                    self.run = None;
                    self.last_outcome = Some(SequenceOutcome::Done);
                    return Action::End(SequenceEnd {
                        sequence_id: self.id,
                        completed: self.completed,
                        outcome: SequenceOutcome::Done,
                        end_us: at,
                    });
                }
                if now < at {
                    return Action::WaitUntil(Some(at));
                }
                run.phase = Phase::Lighting;
                Action::Light { step: run.step }
            }
            // The device reports `lit` right after `Light`; until then nothing is due.
            Phase::Lighting => Action::WaitUntil(None),
            Phase::Trigger(at) => {
                if now < at {
                    return Action::WaitUntil(Some(at));
                }
                // Time-stamp what really happens: a late poll triggers late.
                let at = at.max(now);
                run.trigger_at = at;
                run.edge_at = None;
                run.phase = Phase::Expose;
                match t.trigger_out {
                    Some(o) => {
                        run.pulse_end = Some(at + o.pulse_us as u64);
                        run.pulse_end_at = at + o.pulse_us as u64;
                        Action::Trigger(true)
                    }
                    None => {
                        run.pulse_end = None;
                        run.pulse_end_at = at;
                        self.next(now)
                    }
                }
            }
            Phase::Expose => {
                if let Some(end) = run.pulse_end {
                    if now >= end {
                        run.pulse_end = None;
                        return Action::Trigger(false);
                    }
                }
                let exposed_at = match t.trigger_in {
                    Some(_) => run.edge_at,
                    None => Some(run.trigger_at + t.exposure_us as u64),
                };
                let timeout_at = match (t.trigger_in, run.edge_at) {
                    (Some(ti), None) => Some(run.trigger_at + ti.timeout_us as u64),
                    _ => None,
                };
                if let Some(done) = exposed_at {
                    if now >= done && run.pulse_end.is_none() {
                        let step = run.step;
                        let end_us = done.max(run.pulse_end_at);
                        let s = self
                            .steps
                            .get(step as usize)
                            .copied()
                            .unwrap_or(Stored::Step(Step {
                                illumination: fpm_protocol::Illumination::Dark,
                                color: fpm_protocol::Rgb::OFF,
                            }));
                        let event = match s {
                            Stored::Step(s) => Done::Step(StepEvent {
                                sequence_id: self.id,
                                step,
                                illumination: s.illumination,
                                color: s.color,
                                leds_on: run.leds_on,
                                light_on_us: run.light_on,
                                trigger_us: run.trigger_at,
                                trigger_in_us: run.edge_at,
                                end_us,
                            }),
                            Stored::Set(s) => Done::Set(SetStepEvent {
                                sequence_id: self.id,
                                step,
                                set: s.set,
                                color: s.color,
                                leds_on: run.leds_on,
                                light_on_us: run.light_on,
                                trigger_us: run.trigger_at,
                                trigger_in_us: run.edge_at,
                                end_us,
                            }),
                        };
                        run.step = step + 1;
                        run.phase = Phase::Light(end_us);
                        self.completed = step + 1;
                        return Action::StepDone(event);
                    }
                } else if let Some(deadline) = timeout_at {
                    if now >= deadline {
                        if run.pulse_end.take().is_some() {
                            // Leave the trigger line idle before failing.
                            return Action::Trigger(false);
                        }
                        let step = run.step;
                        let failed = SequenceOutcome::Failed(DeviceError::TriggerTimeout { step });
                        return match self.stop(failed, now) {
                            Some(end) => Action::End(end),
                            None => Action::WaitUntil(None),
                        };
                    }
                }
                let wake = [run.pulse_end, exposed_at, timeout_at]
                    .into_iter()
                    .flatten()
                    .min();
                Action::WaitUntil(wake)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The dither is bounded, absent on the first step, and varies enough from step to
    /// step to be a fingerprint: its spread over a 21×21 board's sequence is near a
    /// uniform draw's (1024/√12 ≈ 296 µs), and no two neighbouring steps share it more
    /// often than chance would have them.
    #[test]
    fn the_trigger_dither_is_bounded_and_irregular() {
        assert_eq!(trigger_dither_us(0), 0);
        let d: std::vec::Vec<f64> = (1..441).map(|s| trigger_dither_us(s) as f64).collect();
        assert!(d.iter().all(|&v| v <= TRIGGER_DITHER_MAX_US as f64));
        let mean = d.iter().sum::<f64>() / d.len() as f64;
        let sd = (d.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / d.len() as f64).sqrt();
        assert!((250.0..340.0).contains(&sd), "{sd}");
        let same = d.windows(2).filter(|w| w[0] == w[1]).count();
        assert!(same <= 3, "{same} neighbours alike");
    }
}
