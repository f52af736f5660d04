//! Pairing frames with the LED that lit them. The controller reports, per step, when it
//! fired the camera trigger (its clock); the camera stamps each frame with the start of
//! its exposure (the camera's clock). A frame is given a step only when the match is
//! unambiguous; anything else is reported, never guessed: a frame is never paired with
//! the wrong LED.

/// A step as the controller reported it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepTime {
    /// Step index in the sequence.
    pub step: usize,
    /// Trigger time, controller clock, ns.
    pub trigger_ns: u64,
}

/// A frame as the camera stamped it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameTime {
    /// The camera's frame number.
    pub frame_number: u64,
    /// Exposure start, camera clock, ns.
    pub timestamp_ns: u64,
}

/// The outcome of [`pair`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Pairing {
    /// (step index, frame index into the frames given), one per labelled frame.
    pub matched: Vec<(usize, usize)>,
    /// Steps no frame could be given to (dropped or unusable frames).
    pub missing_steps: Vec<usize>,
    /// Frames matching no step (extra or stray frames).
    pub extra_frames: Vec<usize>,
    /// Frames that fit more than one step, or a step that more than one frame fits.
    pub ambiguous_frames: Vec<usize>,
    /// Camera clock minus controller clock, ns, as estimated.
    pub clock_offset_ns: i64,
}

/// Pair `frames` with `steps`. The two clocks may differ by a constant offset, which is
/// estimated as the median difference over the candidate pairs (each frame against
/// every step within `max_offset_ns`), the most common difference winning; then a frame
/// belongs to a step when their offset-corrected times differ by at most `tolerance_ns`
/// and no other step or frame is that close. Keep `tolerance_ns` below half the step
/// period.
pub fn pair(
    steps: &[StepTime],
    frames: &[FrameTime],
    tolerance_ns: u64,
    max_offset_ns: u64,
) -> Pairing {
    let offset = estimate_offset(steps, frames, tolerance_ns, max_offset_ns);
    let corrected = |f: &FrameTime| f.timestamp_ns as i128 - offset as i128;
    let near = |s: &StepTime, f: &FrameTime| {
        (corrected(f) - s.trigger_ns as i128).unsigned_abs() <= tolerance_ns as u128
    };
    let mut out = Pairing {
        clock_offset_ns: offset,
        ..Pairing::default()
    };
    let mut step_taken = vec![false; steps.len()];
    for (fi, f) in frames.iter().enumerate() {
        let candidates: Vec<usize> = (0..steps.len()).filter(|&si| near(&steps[si], f)).collect();
        match candidates.as_slice() {
            [] => out.extra_frames.push(fi),
            [si] => {
                let rivals = frames.iter().filter(|g| near(&steps[*si], g)).count();
                if rivals == 1 {
                    out.matched.push((*si, fi));
                    step_taken[*si] = true;
                } else {
                    out.ambiguous_frames.push(fi);
                }
            }
            _ => out.ambiguous_frames.push(fi),
        }
    }
    out.missing_steps = (0..steps.len()).filter(|&si| !step_taken[si]).collect();
    out
}

/// The step `frame` belongs to when the clock offset (camera minus controller) is known:
/// the index into `steps` (sorted by trigger time) of the one step whose trigger is
/// within `tolerance_ns` of the frame's corrected time; None when none or several are.
pub fn step_for(
    steps: &[StepTime],
    frame: &FrameTime,
    offset_ns: i64,
    tolerance_ns: u64,
) -> Option<usize> {
    let t = frame.timestamp_ns as i128 - offset_ns as i128;
    let lo = t - tolerance_ns as i128;
    let first = steps.partition_point(|s| (s.trigger_ns as i128) < lo);
    let near: Vec<usize> = (first..steps.len())
        .take_while(|&i| (steps[i].trigger_ns as i128) <= t + tolerance_ns as i128)
        .collect();
    match near.as_slice() {
        [i] => Some(*i),
        _ => None,
    }
}

/// The clock offset most frame/step pairs agree on (0 when there is nothing to go by).
fn estimate_offset(
    steps: &[StepTime],
    frames: &[FrameTime],
    tolerance_ns: u64,
    max_offset_ns: u64,
) -> i64 {
    let mut diffs: Vec<i64> = vec![];
    for f in frames {
        for s in steps {
            let d = f.timestamp_ns as i128 - s.trigger_ns as i128;
            if d.unsigned_abs() <= max_offset_ns as u128 {
                diffs.push(d as i64);
            }
        }
    }
    if diffs.is_empty() {
        return 0;
    }
    diffs.sort_unstable();
    // The densest window of width `tolerance_ns`: true pairs cluster there, wrong pairs
    // spread out by multiples of the step period.
    let (mut best, mut best_count, mut j) = (0usize, 0usize, 0usize);
    for i in 0..diffs.len() {
        while diffs[i] - diffs[j] > tolerance_ns as i64 {
            j += 1;
        }
        if i - j + 1 > best_count {
            best_count = i - j + 1;
            best = j;
        }
    }
    let window = &diffs[best..best + best_count];
    window[window.len() / 2]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_known_offset_gives_each_frame_its_one_step() {
        let s = steps(10);
        let f = frames_for(&s, 7_000_000, &[0, 1_000_000, -2_000_000]);
        for (k, frame) in f.iter().enumerate() {
            assert_eq!(step_for(&s, frame, 7_000_000, TOL), Some(k));
        }
        // A wrong offset by a step period would label every frame with its neighbour:
        // only the right offset gives frame 0 a step before it is too late.
        assert_eq!(step_for(&s, &f[0], 7_000_000 + PERIOD as i64, TOL), None);
        // Between two steps, nothing.
        let between = FrameTime {
            frame_number: 0,
            timestamp_ns: s[3].trigger_ns + PERIOD / 2,
        };
        assert_eq!(step_for(&s, &between, 0, TOL), None);
    }

    const PERIOD: u64 = 40_000_000; // 40 ms steps
    const TOL: u64 = 5_000_000;

    fn steps(n: usize) -> Vec<StepTime> {
        (0..n)
            .map(|i| StepTime {
                step: i,
                trigger_ns: 1_000_000_000 + i as u64 * PERIOD,
            })
            .collect()
    }

    fn frames_for(steps: &[StepTime], offset: i64, jitter: &[i64]) -> Vec<FrameTime> {
        steps
            .iter()
            .enumerate()
            .map(|(k, s)| FrameTime {
                frame_number: k as u64,
                timestamp_ns: (s.trigger_ns as i64 + offset + jitter[k % jitter.len()]) as u64,
            })
            .collect()
    }

    #[test]
    fn every_frame_finds_its_step_despite_a_clock_offset_and_jitter() {
        let s = steps(50);
        let f = frames_for(&s, 123_456_789, &[0, 300_000, -200_000, 1_000_000]);
        let p = pair(&s, &f, TOL, 10_000_000_000);
        assert_eq!(p.matched.len(), 50);
        assert!(p.matched.iter().all(|&(si, fi)| si == fi));
        assert!(p.missing_steps.is_empty() && p.extra_frames.is_empty());
        assert!((p.clock_offset_ns - 123_456_789).abs() < 1_000_000);
    }

    #[test]
    fn a_dropped_frame_leaves_its_step_missing_and_shifts_nothing() {
        let s = steps(20);
        let mut f = frames_for(&s, 5_000, &[0]);
        f.remove(7);
        let p = pair(&s, &f, TOL, 1_000_000_000);
        assert_eq!(p.missing_steps, vec![7]);
        // Frame k (after the gap) still belongs to step k + 1, not k.
        for &(si, fi) in &p.matched {
            assert_eq!(si, if fi < 7 { fi } else { fi + 1 });
        }
    }

    #[test]
    fn an_extra_frame_between_steps_is_reported_not_labelled() {
        let s = steps(10);
        let mut f = frames_for(&s, 0, &[0]);
        f.insert(
            4,
            FrameTime {
                frame_number: 99,
                timestamp_ns: s[3].trigger_ns + PERIOD / 2,
            },
        );
        let p = pair(&s, &f, TOL, 1_000_000_000);
        assert_eq!(p.extra_frames, vec![4]);
        assert_eq!(p.matched.len(), 10);
    }

    #[test]
    fn two_frames_for_one_step_are_both_refused() {
        let s = steps(10);
        let mut f = frames_for(&s, 0, &[0]);
        f.insert(
            3,
            FrameTime {
                frame_number: 98,
                timestamp_ns: s[3].trigger_ns + 1_000,
            },
        );
        let p = pair(&s, &f, TOL, 1_000_000_000);
        assert_eq!(p.ambiguous_frames.len(), 2);
        assert!(p.missing_steps.contains(&3));
        assert!(p.matched.iter().all(|&(si, _)| si != 3));
    }

    #[test]
    fn late_frames_still_pair_by_their_stamp_not_their_arrival() {
        // Arrival order is irrelevant: frames delivered shuffled pair the same.
        let s = steps(12);
        let mut f = frames_for(&s, 0, &[0]);
        f.reverse();
        let p = pair(&s, &f, TOL, 1_000_000_000);
        assert_eq!(p.matched.len(), 12);
        for &(si, fi) in &p.matched {
            assert_eq!(f[fi].frame_number as usize, si);
        }
    }
}
