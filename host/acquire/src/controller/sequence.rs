//! A raw capture sequence run to its end: upload, start, every step event checked in
//! order, the end reported — the loop `fpm device run-sequence` and any client that
//! drives the controller without a camera share. (With a camera, [`crate::capture`]
//! interleaves the same events with frames.)

use std::time::Duration;

use anyhow::{bail, Context, Result};
use fpm_protocol::{SequenceEnd, SequenceOutcome, SequenceTiming, Step};

use super::{Controller, SequenceEvent};

/// How a sequence ran.
#[derive(Debug, Clone, serde::Serialize)]
pub struct SequenceRun {
    /// The sequence id.
    pub id: u32,
    /// Steps uploaded.
    pub steps: usize,
    /// When it started, device clock, µs.
    pub started_us: u64,
    /// How it ended.
    pub end: SequenceEnd,
}

impl SequenceRun {
    /// Device time from start to end, s.
    pub fn seconds(&self) -> f64 {
        self.end.end_us.saturating_sub(self.started_us) as f64 * 1e-6
    }
}

/// The longest a step of `timing` can take before the controller counts as silent.
pub fn step_timeout(timing: &SequenceTiming) -> Duration {
    Duration::from_micros(
        (timing.settle_us as u64 + timing.exposure_us as u64)
            + timing
                .trigger_out
                .map_or(0, |t| (t.delay_us + t.pulse_us) as u64)
            + timing.trigger_in.map_or(0, |t| t.timeout_us as u64)
            + 100_000,
    ) + Duration::from_millis(500)
}

impl Controller {
    /// Upload `steps` as sequence `id`, run it and wait for its end, giving each event
    /// to `on_event` as it comes. A step out of order (events lost), a failure or an
    /// early end is an error saying which.
    pub fn run_sequence(
        &self,
        id: u32,
        steps: &[Step],
        timing: SequenceTiming,
        mut on_event: impl FnMut(&SequenceEvent),
    ) -> Result<SequenceRun> {
        self.upload_sequence(id, steps, timing)
            .context("uploading the sequence")?;
        let mut events = self.subscribe()?;
        let started = self.start_sequence(id)?;
        let per_step = step_timeout(&timing);
        let mut expected = 0u16;
        loop {
            let event = events.next(per_step)?;
            on_event(&event);
            match event {
                SequenceEvent::Step(_) | SequenceEvent::SetStep(_) => {
                    let Some((sequence, step, _, _)) = event.step_times() else {
                        continue;
                    };
                    if sequence != id || step != expected {
                        bail!(
                            "expected step {expected} of sequence {id}, got step {step} of sequence {sequence}: events were lost"
                        );
                    }
                    expected += 1;
                }
                SequenceEvent::End(end) => {
                    if let SequenceOutcome::Failed(e) = end.outcome {
                        bail!("the sequence failed at step {}: {e}", end.completed);
                    }
                    if end.completed as usize != steps.len() {
                        bail!(
                            "the sequence ended after {} of {} steps",
                            end.completed,
                            steps.len()
                        );
                    }
                    return Ok(SequenceRun {
                        id,
                        steps: steps.len(),
                        started_us: started.started_us,
                        end,
                    });
                }
            }
        }
    }
}
