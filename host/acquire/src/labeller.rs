//! The labelling of one capture as a sans-IO state machine (as `firmware/core` is for
//! the controller, quinn-proto for QUIC): step reports and frames go in with the host
//! time they arrived, labels come out as soon as they are certain, and
//! [`Labeller::finish`] gives the authoritative pairing ([`crate::label`]) over
//! everything. No clock, no thread, no I/O: the capture loop feeds it, and tests drive
//! it synchronously through any interleaving they can think of.

use crate::label::{pair_with_arrivals, step_for, Arrivals, FrameTime, Pairing, StepTime};

/// How far a running sequence is, as its controller reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct SequenceSteps {
    /// Steps reported.
    pub done: usize,
    /// Steps in the sequence.
    pub of: usize,
    /// The step period on the controller's clock, µs (None until two steps are in).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub period_us: Option<u64>,
}

/// Frames (and step reports) before the clock mapping is first fitted.
const MIN_FRAMES_TO_ANCHOR: usize = 8;

/// Frames lost before the first that arrived, at most, for labels given while the
/// capture runs (more wait for the final pairing, which has every step).
const LOST_AT_START_MAX: usize = 8;

/// Why frames wait for their labels while the capture runs ([`Labeller::waiting`]);
/// shown with the acquisition's progress, as its text.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Waiting {
    /// Fewer than 8 frames or step reports so far: the camera's clock is fitted from 8.
    FirstFrames,
    /// The frames so far fit clock offsets a whole step apart alike: neither the
    /// stamps (a periodic sequence, or stamps with more jitter than the steps'
    /// timing varies) nor the arrivals (a camera slower than a step) tell which.
    Fingerprint,
    /// The camera's clock and the controller's could not be reconciled so far (the
    /// debug log says how).
    Clocks,
}

impl std::fmt::Display for Waiting {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Waiting::FirstFrames => "labelling: waiting for the first 8 frames to fit the camera's clock",
            Waiting::Fingerprint => "labelling: waiting for the camera's clock (the frames so far fit it a whole step apart alike); the frames are labelled when the sequence ends",
            Waiting::Clocks => "labelling: waiting for the camera's clock (the frames so far follow no one clock: is the camera triggered by the controller?)",
        })
    }
}

impl serde::Serialize for Waiting {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(self)
    }
}

/// A frame given its step while the capture runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Label {
    /// Index of the frame, in the order frames were given to [`Labeller::frame`].
    pub frame: usize,
    /// The sequence step (the controller's step index) that lit it.
    pub step: usize,
}

/// What a finished labelling found.
#[derive(Debug, Clone)]
pub struct Labelled {
    /// The final pairing (indices into the steps and frames as they were given).
    pub pairing: Pairing,
    /// (sequence step, frame index) for every labelled frame, by step; steps outside
    /// the sequence (the controller's error) are left out.
    pub matched: Vec<(usize, usize)>,
    /// Labelled frames that were not handed out while the capture ran: the caller
    /// hands these on now, so that every labelled frame is handed out once.
    pub late: Vec<Label>,
    /// Frames handed out while capturing whose final label differs, or that the final
    /// pairing refused (0 expected; a caller that streamed them must not trust what it
    /// built from them).
    pub relabelled: usize,
}

/// The camera's clock against the controller's, as fitted on the frames so far.
#[derive(Debug, Clone, Copy)]
struct Anchor {
    /// Controller time of the first step, ns.
    t0_ns: u64,
    offset_ns: i64,
    drift: f64,
}

impl Anchor {
    /// A frame stamp mapped back to the controller's clock, ns.
    fn controller_ns(&self, stamp_ns: u64) -> i128 {
        // camera = t + offset + drift·(t − t0)  ⇒  t = (camera − offset + drift·t0)/(1 + drift)
        let shifted = stamp_ns as f64 - self.offset_ns as f64 + self.drift * self.t0_ns as f64;
        (shifted / (1.0 + self.drift)).round() as i128
    }
}

/// Labels one capture's frames with their steps; see the module's doc.
#[derive(Debug, Clone)]
pub struct Labeller {
    sequence_len: usize,
    tolerance_ns: u64,
    steps: Vec<StepTime>,
    step_arrival_ns: Vec<i64>,
    frames: Vec<FrameTime>,
    frame_arrival_ns: Vec<i64>,
    /// The label each frame was handed out with while capturing.
    online: Vec<Option<usize>>,
    /// Per sequence step: a frame was handed out for it.
    given: Vec<bool>,
    /// Frames not yet handed out.
    pending: Vec<usize>,
    anchor: Option<Anchor>,
    /// Fit the clock mapping again once this many frames have arrived.
    next_fit_at: usize,
    waiting: Option<Waiting>,
    /// The latest camera stamp so far, ns.
    newest_stamp_ns: u64,
    changed: bool,
}

impl Labeller {
    /// A labeller for a sequence of `sequence_len` steps. A frame belongs to a step when
    /// its stamp is within `tolerance_ns` before to twice that after the mapped
    /// trigger ([`crate::label::pair`]): keep it at most a third of the shortest step.
    pub fn new(sequence_len: usize, tolerance_ns: u64) -> Self {
        Self {
            sequence_len,
            tolerance_ns,
            steps: vec![],
            step_arrival_ns: vec![],
            frames: vec![],
            frame_arrival_ns: vec![],
            online: vec![],
            given: vec![false; sequence_len],
            pending: vec![],
            anchor: None,
            next_fit_at: MIN_FRAMES_TO_ANCHOR,
            waiting: Some(Waiting::FirstFrames),
            newest_stamp_ns: 0,
            changed: false,
        }
    }

    /// The controller reported a step; `arrived_ns` is when its trigger happened on
    /// this host's clock (ns from an instant taken before the sequence was started):
    /// the report's arrival less the device time from the trigger to the report (a
    /// report sent when the step ends would otherwise arrive after the step's frame,
    /// and the true labels would look acausal).
    pub fn step(&mut self, step: StepTime, arrived_ns: i64) {
        tracing::trace!(
            "step {} triggered at {} ns (controller), arrived {arrived_ns} ns",
            step.step,
            step.trigger_ns
        );
        self.steps.push(step);
        self.step_arrival_ns.push(arrived_ns);
        self.changed = true;
    }

    /// A frame arrived (at `arrived_ns`, on the clock of [`Labeller::step`]); returns its
    /// index, by which labels name it.
    pub fn frame(&mut self, frame: FrameTime, arrived_ns: i64) -> usize {
        let k = self.frames.len();
        tracing::trace!(
            "frame {} stamped {} ns (camera), arrived {arrived_ns} ns",
            frame.frame_number,
            frame.timestamp_ns
        );
        self.frames.push(frame);
        self.newest_stamp_ns = self.newest_stamp_ns.max(frame.timestamp_ns);
        self.frame_arrival_ns.push(arrived_ns);
        self.online.push(None);
        self.pending.push(k);
        self.changed = true;
        k
    }

    /// Frames that can be labelled now, each once. The clock mapping is fitted on what
    /// has arrived (the same pairing as the final one, on fewer frames), from 8 frames on
    /// and again as the count doubles; until it is known, or while it is ambiguous,
    /// frames wait. A frame waits until a later frame closes its step's window (a rival
    /// frame may still come until then), and two frames in one window both wait.
    pub fn labels(&mut self) -> Vec<Label> {
        if !std::mem::take(&mut self.changed) {
            return vec![];
        }
        let received = self.frames.len();
        if received >= self.next_fit_at && self.steps.len() >= MIN_FRAMES_TO_ANCHOR {
            let (anchor, waiting) = self.fit_anchor();
            // While the clocks are not known, try again after a quarter more frames (a
            // fingerprint needs only a few more; a fit is over everything so far, so
            // trying at every frame would cost the square of the count); once known,
            // refit as the count doubles.
            self.next_fit_at = match anchor {
                Some(_) => received * 2,
                None => received + (received / 4).max(1),
            };
            match (anchor, waiting) {
                // A refit the frames so far leave ambiguous (offsets a step apart fit
                // alike, which more frames resolve) contradicts nothing: labelling goes
                // on by the mapping fitted before, and tries again after a quarter more
                // frames. Dropping it stalled every frame until then (found by the live
                // property test at 10⁵ cases: 16 frames ambiguous, 8 and 20 not).
                (None, Some(Waiting::Fingerprint)) if self.anchor.is_some() => {}
                _ => {
                    self.anchor = anchor;
                    self.waiting = waiting;
                }
            }
        }
        let Some(anchor) = self.anchor else {
            return vec![];
        };
        // A camera delivers its frames in the order it took them: once a frame stamped
        // after a step's window has arrived, no other frame of that step will (frames
        // delivered out of order are caught by the final pairing: `relabelled`).
        // (The mapping is increasing, so the newest stamp maps to the latest time.)
        let tol = self.tolerance_ns as i128;
        let newest_stamp = anchor.controller_ns(self.newest_stamp_ns);
        let closed = |s: &StepTime| newest_stamp > s.trigger_ns as i128 + 2 * tol;
        let candidates: Vec<(usize, usize)> = self
            .pending
            .iter()
            .filter_map(|&k| Some((k, self.step_of(&anchor, &self.frames[k])?)))
            .collect();
        let mut waiting = vec![0u32; self.steps.len()];
        for &(_, si) in &candidates {
            waiting[si] += 1;
        }
        let mut out = vec![];
        for &(k, si) in &candidates {
            let step = self.steps[si].step;
            // Two frames waiting for one step: neither is handed out (the final pairing
            // refuses both); a step index outside the sequence is the controller's
            // error, left to the final pairing too.
            if waiting[si] > 1
                || !closed(&self.steps[si])
                || self.given.get(step).is_none_or(|&g| g)
            {
                continue;
            }
            self.given[step] = true;
            self.online[k] = Some(step);
            out.push(Label { frame: k, step });
        }
        self.pending.retain(|&k| self.online[k].is_none());
        out
    }

    /// The clock mapping to label by, when the frames so far single it out; else why
    /// labelling waits.
    ///
    /// Two kinds of evidence, either enough:
    /// - the stamps: the pairing over everything so far, whose clock offset alone
    ///   reproduces the controller's irregular step timing in the stamps
    ///   ([`Pairing::fingerprint`]). It holds however late frames reach the host
    ///   and whatever was lost at the start: the usual case on every rig we ship;
    /// - the arrivals, for a strictly periodic sequence: as many steps as frames (steps
    ///   run ahead of frames still in flight, and with extra steps an offset a step
    ///   later would fit as well), and the frames reaching the host soonest after their
    ///   steps under the offset chosen ([`Pairing::arrivals_agree`]), which guards
    ///   against frames lost at the start but holds only for a camera faster than a
    ///   step.
    fn fit_anchor(&self) -> (Option<Anchor>, Option<Waiting>) {
        let received = self.frames.len();
        // The mapping a pairing over `steps` fitted (its offset is at their first trigger).
        let anchor = |steps: &[StepTime], offset_ns: i64, drift_ppm: f64| Anchor {
            t0_ns: steps.iter().map(|s| s.trigger_ns).min().unwrap_or(0),
            offset_ns,
            drift: drift_ppm * 1e-6,
        };
        let enough =
            |p: &Pairing, n: usize| p.clock_problem.is_none() && p.matched.len() * 4 >= n * 3;
        // The steps a frame so far can belong to: frames come in order, so no further
        // than the frames' count plus those lost at the start. A camera slower than the
        // steps falls many steps behind; the steps beyond would only add offsets that
        // fit as well, until there are too many to fit.
        let reach = self.steps.len().min(received + LOST_AT_START_MAX);
        let all = pair_with_arrivals(
            &self.steps[..reach],
            &self.frames,
            self.tolerance_ns,
            u64::MAX,
            Some(Arrivals {
                steps_ns: &self.step_arrival_ns[..reach],
                frames_ns: &self.frame_arrival_ns,
            }),
        );
        if let Some(fit) = all.fingerprint {
            if fit.matched * 4 >= received.min(reach) * 3 {
                let steps = &self.steps[..reach];
                return (Some(anchor(steps, fit.offset_ns, fit.drift_ppm)), None);
            }
        }
        if !self.reports_prompt() {
            tracing::debug!(
                "labelling waits after {received} frames: clock problem {:?}; stamps single out their steps {}; step reports arrive in batches",
                all.clock_problem,
                all.fingerprint.is_some(),
            );
            return (None, Some(Waiting::Fingerprint));
        }
        let n = received.min(self.steps.len());
        let arrivals = Arrivals {
            steps_ns: &self.step_arrival_ns[..n],
            frames_ns: &self.frame_arrival_ns[..n],
        };
        let p = pair_with_arrivals(
            &self.steps[..n],
            &self.frames[..n],
            self.tolerance_ns,
            u64::MAX,
            Some(arrivals),
        );
        if p.arrivals_agree && enough(&p, n) {
            let steps = &self.steps[..n];
            return (
                Some(anchor(steps, p.clock_offset_ns, p.clock_drift_ppm)),
                None,
            );
        }
        tracing::debug!(
            "labelling waits after {received} frames: clock problem {:?}; stamps single out their steps {}, arrivals agree {}, {} of {n} matched",
            all.clock_problem.as_ref().or(p.clock_problem.as_ref()),
            all.fingerprint.is_some(),
            p.arrivals_agree,
            p.matched.len()
        );
        let why = match all.clock_problem.or(p.clock_problem) {
            Some(_) => Waiting::Clocks,
            None => Waiting::Fingerprint,
        };
        (None, Some(why))
    }

    /// Whether the step reports reached the host one by one, each about as long after
    /// the one before as their triggers were apart: the arrivals' check needs that. A
    /// link that hands several over at once (USB CDC) makes the first of each batch look
    /// late, its frame early, and the check would favour an offset a step off.
    fn reports_prompt(&self) -> bool {
        let (t, a) = (&self.steps, &self.step_arrival_ns);
        let (Some(first), Some(last)) = (t.first().zip(a.first()), t.last().zip(a.last())) else {
            return false;
        };
        let span = last.0.trigger_ns as f64 - first.0.trigger_ns as f64;
        if t.len() < 3 || span <= 0.0 {
            return false;
        }
        // Host ns per controller ns over the whole run (an emulator's may be far from 1).
        let rate = (*last.1 - *first.1) as f64 / span;
        if rate <= 0.0 {
            return false;
        }
        let bunched = t
            .windows(2)
            .zip(a.windows(2))
            .filter(|(s, h)| {
                let apart = (s[1].trigger_ns as f64 - s[0].trigger_ns as f64) * rate;
                ((h[1] - h[0]) as f64) < 0.5 * apart
            })
            .count();
        bunched * 10 < t.len()
    }

    /// Why frames wait for their labels now (None: they do not).
    pub fn waiting(&self) -> Option<Waiting> {
        self.waiting
    }

    /// How far the controller is: the steps it has reported, and its step period on
    /// its own clock, µs (None until two steps are in).
    pub fn steps(&self) -> SequenceSteps {
        let period_us = match (self.steps.first(), self.steps.last()) {
            (Some(a), Some(b)) if b.step > a.step => {
                Some(b.trigger_ns.saturating_sub(a.trigger_ns) / (b.step - a.step) as u64 / 1000)
            }
            _ => None,
        };
        SequenceSteps {
            done: self.steps.len(),
            of: self.sequence_len,
            period_us,
        }
    }

    /// The index into the steps of the one step in whose window the frame's mapped
    /// time falls (None when none or several are).
    fn step_of(&self, anchor: &Anchor, frame: &FrameTime) -> Option<usize> {
        step_for(
            &self.steps,
            anchor.controller_ns(frame.timestamp_ns),
            self.tolerance_ns,
        )
    }

    /// The final pairing over everything that arrived: authoritative; what the capture
    /// keeps follows it.
    pub fn finish(self) -> Labelled {
        let arrivals = Arrivals {
            steps_ns: &self.step_arrival_ns,
            frames_ns: &self.frame_arrival_ns,
        };
        // A real camera's clock may be anything (seconds since it powered up, the Unix
        // epoch): no bound on the offset.
        let pairing = pair_with_arrivals(
            &self.steps,
            &self.frames,
            self.tolerance_ns,
            u64::MAX,
            Some(arrivals),
        );
        log_residuals(&pairing, &self.steps, &self.frames);
        let mut matched: Vec<(usize, usize)> = pairing
            .matched
            .iter()
            .map(|&(si, fi)| (self.steps[si].step, fi))
            .filter(|&(step, _)| step < self.sequence_len)
            .collect();
        matched.sort_by_key(|&(step, _)| step);
        let mut final_label: Vec<Option<usize>> = vec![None; self.frames.len()];
        for &(step, fi) in &matched {
            final_label[fi] = Some(step);
        }
        let relabelled = self
            .online
            .iter()
            .zip(&final_label)
            .filter(|(streamed, label)| streamed.is_some() && streamed != label)
            .count();
        let late = matched
            .iter()
            .filter(|&&(_, fi)| self.online[fi].is_none())
            .map(|&(step, frame)| Label { frame, step })
            .collect();
        Labelled {
            pairing,
            matched,
            late,
            relabelled,
        }
    }
}

/// The fitted clock mapping and how tightly the labelled frames follow it (the
/// camera's trigger-to-stamp jitter), and every frame that found no step, for whoever
/// tunes a camera.
fn log_residuals(p: &Pairing, steps: &[StepTime], frames: &[FrameTime]) {
    if !p.matched.is_empty() {
        tracing::info!(
            "camera clock: offset {:.6} s, drift {:+.1} ppm; labelled frames within {:.1} ms of the fitted mapping",
            p.clock_offset_ns as f64 / 1e9,
            p.clock_drift_ppm,
            p.residual_spread_ns as f64 / 1e6
        );
    }
    for &fi in p.extra_frames.iter().chain(&p.ambiguous_frames) {
        let t = frames[fi].timestamp_ns as i128 - p.clock_offset_ns as i128;
        let nearest = steps
            .iter()
            .min_by_key(|s| (s.trigger_ns as i128 - t).unsigned_abs());
        if let Some(s) = nearest {
            tracing::debug!(
                "frame {} unlabelled: about {:+.1} ms from step {}'s trigger",
                frames[fi].frame_number,
                crate::label::ns_f64(t - s.trigger_ns as i128) / 1e6,
                s.step
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_step_period_is_read_on_the_controller_clock_whatever_the_reports_arrival() {
        let mut labeller = Labeller::new(10, 1_000_000);
        assert_eq!(
            labeller.steps(),
            SequenceSteps {
                done: 0,
                of: 10,
                period_us: None
            }
        );
        // Steps 49.5 ms apart on the controller; their reports arrive in a batch (USB
        // CDC hands several over at once), all at the same host time.
        for step in 0..4 {
            let trigger_ns = 1_000_000 + step as u64 * 49_500_000;
            labeller.step(StepTime { step, trigger_ns }, 300_000_000);
        }
        assert_eq!(
            labeller.steps(),
            SequenceSteps {
                done: 4,
                of: 10,
                period_us: Some(49_500)
            }
        );
    }
}
