//! The labelling of one capture as a sans-IO state machine (as `firmware/core` is for
//! the controller, quinn-proto for QUIC): step reports and frames go in with the host
//! time they arrived, labels come out as soon as they are certain, and
//! [`Labeller::finish`] gives the authoritative pairing ([`crate::label`]) over
//! everything. No clock, no thread, no I/O: the capture loop feeds it, and tests drive
//! it synchronously through any interleaving they can think of.

use crate::label::{pair_with_arrivals, step_for, Arrivals, FrameTime, Pairing, StepTime};

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
    anchored_at: usize,
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
            anchored_at: 0,
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
        self.steps.push(step);
        self.step_arrival_ns.push(arrived_ns);
        self.changed = true;
    }

    /// A frame arrived (at `arrived_ns`, on the clock of [`Labeller::step`]); returns its
    /// index, by which labels name it.
    pub fn frame(&mut self, frame: FrameTime, arrived_ns: i64) -> usize {
        let k = self.frames.len();
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
        if received >= 8.max(self.anchored_at * 2) && self.steps.len() >= 8 {
            self.anchored_at = received;
            // As many steps as frames: steps run ahead of frames still in flight, and
            // with extra steps an offset a step later would fit as well.
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
            let trusted =
                p.clock_problem.is_none() && p.arrivals_agree && p.matched.len() * 4 >= n * 3;
            if !trusted {
                tracing::debug!(
                    "labelling waits after {received} frames: clock problem {:?}, arrivals agree {}, {} of {n} matched",
                    p.clock_problem,
                    p.arrivals_agree,
                    p.matched.len()
                );
            }
            self.anchor = trusted.then(|| Anchor {
                t0_ns: self.steps[..n]
                    .iter()
                    .map(|s| s.trigger_ns)
                    .min()
                    .unwrap_or(0),
                offset_ns: p.clock_offset_ns,
                drift: p.clock_drift_ppm * 1e-6,
            });
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
                (t - s.trigger_ns as i128) as f64 / 1e6,
                s.step
            );
        }
    }
}
