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
    /// Camera clock minus controller clock at the first step, ns, as fitted.
    pub clock_offset_ns: i64,
    /// How much faster the camera's clock runs than the controller's, ppm, as fitted.
    pub clock_drift_ppm: f64,
    /// Spread of the labelled frames' stamps around the fitted clock mapping
    /// (largest minus smallest residual), ns: the camera's latency jitter.
    pub residual_spread_ns: u64,
    /// Why the two clocks could not be reconciled, if they could not (then nothing is
    /// labelled: every frame is reported unlabelled rather than guessed).
    pub clock_problem: Option<String>,
    /// With arrival times: whether, among the offsets labelling nearly as many frames,
    /// the one taken is also the one whose frames arrive soonest after their steps
    /// without arriving before them (always true without arrival times). Labels given
    /// while frames still arrive should wait until it is.
    pub arrivals_agree: bool,
    /// The clock offset singled out by the stamps, if one is: the stamps follow the
    /// controller's step-to-step timing (its LED update times and its trigger dither)
    /// under it, and decisively not under any other offset that labels at least half
    /// as many frames. The steps' timing is a fingerprint only the true offset
    /// reproduces. Evidence that does not depend on when frames reach the host (unlike
    /// [`Pairing::arrivals_agree`]) nor on how many frames an offset labels so far, so
    /// it holds for a camera slower than a step, for frames lost at the start, and
    /// while step reports lag behind frames. None for a strictly periodic sequence,
    /// stamps with more jitter than the steps' irregularity, or under
    /// [`MIN_PAIRS_TO_COMPARE`] pairs.
    pub fingerprint: Option<ClockFit>,
}

/// A clock mapping fitted to the frames: see [`Pairing::fingerprint`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClockFit {
    /// Camera clock minus controller clock at the first step, ns.
    pub offset_ns: i64,
    /// How much faster the camera's clock runs than the controller's, ppm.
    pub drift_ppm: f64,
    /// Frames it labels.
    pub matched: usize,
}

/// The camera's clock as a function of the controller's: `camera = t + offset +
/// drift · (t − t0)`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct ClockMap {
    t0_ns: i128,
    offset_ns: f64,
    drift: f64,
}

impl ClockMap {
    /// A frame stamp's residual against a step: its stamp minus the stamp predicted.
    fn residual_ns(&self, step: &StepTime, frame: &FrameTime) -> f64 {
        ns_f64(frame.timestamp_ns as i128) - self.predicted_ns(step)
    }

    /// The camera stamp a frame of `step` would carry, with no latency.
    fn predicted_ns(&self, step: &StepTime) -> f64 {
        let t = step.trigger_ns as i128;
        ns_f64(t) + self.offset_ns + self.drift * ns_f64(t - self.t0_ns)
    }
}

/// `ns as f64` through i64, saturating beyond ±292 years (no clock or difference here
/// comes near): within that the same value, rounded the same way, in one instruction
/// instead of the software conversion of a 128-bit integer, which was a quarter of
/// the labeller's time.
pub(crate) fn ns_f64(ns: i128) -> f64 {
    ns.clamp(i64::MIN.into(), i64::MAX.into()) as i64 as f64
}

/// Offsets that label as many frames are told apart by their stamp residuals only
/// when the next best's rms is this many times the best's, plus
/// [`MIN_RMS_DIFFERENCE_NS`].
const DECISIVE_RMS_RATIO: f64 = 4.0;
/// See [`DECISIVE_RMS_RATIO`]: below this, both are within any camera's stamp jitter.
const MIN_RMS_DIFFERENCE_NS: f64 = 100_000.0;
/// Stamp residuals decide between offsets only over at least this many pairs: with
/// offset and drift fitted to a handful, any candidate can look tight. Measured with
/// the labeller's property test (host/acquire/tests/labeller.rs, 4·10⁵ generated
/// captures): at 4 it labels frames wrongly within 10⁴, at 6 a clean 7-step capture
/// had 5 frames labelled online and relabelled; at 8, none.
const MIN_PAIRS_TO_COMPARE: usize = 8;

/// A frame may come this many tolerances late after its trigger but only one early:
/// a camera's latency is one-sided (it waits for its next tick or line, or its first
/// frame after arming is slow), never ahead of the trigger. The window, `tolerance_ns`
/// early to twice it late, must stay shorter than any step interval.
const LATE_TOLERANCES: f64 = 2.0;

/// Whether a stamp `residual_ns` from a mapped trigger is within the window.
fn within(residual_ns: f64, tolerance_ns: u64) -> bool {
    let tol = tolerance_ns as f64;
    (-tol..=LATE_TOLERANCES * tol).contains(&residual_ns)
}

/// Drift beyond this is no clock of a working camera: fits are held within it.
const MAX_DRIFT_PPM: f64 = 1000.0;

/// Pair `frames` with `steps`. The camera's clock may differ from the controller's by
/// any offset and a small drift (tens of ppm), with jitter: the offset is first
/// estimated as the densest cluster of frame-minus-step differences (true pairs
/// cluster there, wrong pairs spread out by multiples of the step period), then offset
/// and drift are fitted by least squares over the pairs that agree, outliers
/// rejected, and the pairing redone with the fitted mapping. A frame belongs to a step
/// when its stamp is at most `tolerance_ns` before the mapped trigger time or twice
/// that after it ([`LATE_TOLERANCES`]), and no other step or frame is that close. Keep
/// `tolerance_ns` at most a third of the shortest step interval.
/// `max_offset_ns` bounds the offset searched (`u64::MAX`: any).
///
/// When the clocks cannot be reconciled (fewer than half the frames fit one mapping,
/// or the fitted drift is beyond any real clock's), nothing is labelled and
/// [`Pairing::clock_problem`] says why.
pub fn pair(
    steps: &[StepTime],
    frames: &[FrameTime],
    tolerance_ns: u64,
    max_offset_ns: u64,
) -> Pairing {
    pair_with_arrivals(steps, frames, tolerance_ns, max_offset_ns, None)
}

/// When each step's report and each frame reached the host, for
/// [`pair_with_arrivals`]: ns on one host clock, counted from an instant taken before
/// the sequence was started (so before the first trigger).
#[derive(Debug, Clone, Copy)]
pub struct Arrivals<'a> {
    /// Per step, in the order of `steps`.
    pub steps_ns: &'a [i64],
    /// Per frame, in the order of `frames`.
    pub frames_ns: &'a [i64],
}

/// [`pair`], and with the host's arrival times two more things: clock offsets under
/// which most frames would have reached the host before their LED was lit are ruled
/// out (causality, whatever the camera's latency), and a check for labels given while
/// frames still arrive ([`Pairing::arrivals_agree`]).
///
/// Arrival times never decide between clock offsets a whole step apart otherwise (a
/// frame lost at the start of a periodic run, when only an *earlier* pairing is
/// possible as well): that would take a bound on how late a frame may reach the host,
/// and a camera slower than a step (a large frame over GigE, a loaded host) breaks it
/// silently, shifting every label by a step. Such a tie is reported as a
/// [`Pairing::clock_problem`] and nothing is labelled.
pub fn pair_with_arrivals(
    steps: &[StepTime],
    frames: &[FrameTime],
    tolerance_ns: u64,
    max_offset_ns: u64,
    arrivals: Option<Arrivals<'_>>,
) -> Pairing {
    let Some(first) = steps.iter().map(|s| s.trigger_ns).min() else {
        return Pairing {
            extra_frames: (0..frames.len()).collect(),
            ..Pairing::default()
        };
    };
    // Steps are nearly periodic, so offsets a whole step apart explain the data almost
    // as well: every alignment of a frame with a step is a candidate, the most
    // promising are fitted, and the one that labels the most frames is kept. A tie
    // (e.g. the first frame lost) that the stamps' residuals do not decide either is
    // not guessed: nothing is labelled then.
    let causality = arrivals.and_then(|a| Causality::new(steps, first, a));
    let Some(starts) =
        candidate_offsets(steps, frames, tolerance_ns, max_offset_ns, first, causality)
    else {
        return refused(
            steps.len(),
            frames.len(),
            format!(
                "{} frames fit more than {MAX_FITTED} clock offsets a whole step apart equally well (far fewer frames than steps): which LED each frame belongs to cannot be told from the stamps, and is not guessed",
                frames.len()
            ),
        );
    };
    let mut fits: Vec<(ClockMap, Pairing)> = starts
        .into_iter()
        .map(|offset_ns| {
            let start = ClockMap {
                t0_ns: first as i128,
                offset_ns,
                drift: 0.0,
            };
            refine(steps, frames, start, tolerance_ns)
        })
        .collect();
    // A frame cannot reach the host before its LED was lit: an offset that says most
    // frames did is impossible, however well it fits the stamps (frames one step
    // later than true, when they arrive within a step).
    if arrivals.is_some() {
        let candidates = fits.len();
        fits.retain(|(_, p)| !causality.is_some_and(|c| c.rules_out(steps, &p.matched)));
        tracing::debug!(
            "{} of {candidates} clock offsets ruled out: most of their frames would have arrived before their LED was lit",
            candidates - fits.len()
        );
        if fits.is_empty() {
            return refused(
                steps.len(),
                frames.len(),
                "under every clock offset most frames would have reached this host before their LED was lit: the controller's step reports or this host's clock are wrong".to_owned(),
            );
        }
    }
    fits.sort_by_key(|(_, p)| std::cmp::Reverse(p.matched.len()));
    fits.dedup_by(|a, b| (a.0.offset_ns - b.0.offset_ns).abs() < tolerance_ns as f64);
    let best = fits.first().map_or(0, |f| f.1.matched.len());
    let tied: Vec<usize> = (0..fits.len())
        .filter(|&k| best > 0 && fits[k].1.matched.len() == best)
        .collect();
    // Offsets a step apart that label as many frames can still differ in how closely
    // the stamps follow the triggers: the controller's steps are not exactly periodic
    // (a step's LED update takes longer the further down the chain its LEDs are), and
    // only the true offset reproduces those irregularities in the stamps. That decides
    // from the stamps alone, when the difference is decisive.
    let mut tie = tied.len() > 1;
    if tie {
        let mut by_rms: Vec<(f64, usize)> = tied
            .iter()
            .map(|&k| (residual_rms_ns(steps, frames, &fits[k]), k))
            .collect();
        by_rms.sort_by(|a, b| a.0.total_cmp(&b.0));
        let ((first, closest), (second, _)) = (by_rms[0], by_rms[1]);
        tracing::debug!(
            "{} offsets a step apart label {best} frames; stamp residuals {:.1} µs rms for the closest, {:.1} µs for the next",
            tied.len(),
            first / 1e3,
            second / 1e3
        );
        if first.is_finite() && second >= DECISIVE_RMS_RATIO * first + MIN_RMS_DIFFERENCE_NS {
            fits.swap(0, closest);
            tie = false;
        }
    }
    // The median arrival lag of a candidate's frames after their steps.
    let lag = |k: usize| -> Option<i64> {
        let a = arrivals?;
        let mut l: Vec<i64> = fits[k]
            .1
            .matched
            .iter()
            .filter_map(|&(si, fi)| Some(a.frames_ns.get(fi)? - a.steps_ns.get(si)?))
            .collect();
        fpm_physics::stats::median(&mut l)
    };
    // Of the candidates labelling at least `at_least` frames, the one whose frames
    // arrive soonest after their steps without arriving before them.
    let soonest = |at_least: usize| -> Option<(usize, i64)> {
        (0..fits.len())
            .filter(|&k| at_least > 0 && fits[k].1.matched.len() >= at_least)
            .filter_map(|k| lag(k).map(|l| (k, l)))
            .filter(|&(_, l)| l >= -(tolerance_ns as i64))
            .min_by_key(|&(_, l)| l)
    };
    let nearly = soonest(best.saturating_sub(1));
    // Whether the arrivals agree with the choice even among offsets one frame short of
    // it (a shifted offset always is: it loses one frame at an end).
    let arrivals_agree = match (arrivals, nearly) {
        (None, _) => true,
        (Some(_), Some((k, _))) => k == 0,
        (Some(_), None) => false,
    };
    let fingerprint = singled_out_by_stamps(steps, frames, &fits).map(|k| ClockFit {
        offset_ns: fits[k].0.offset_ns.round() as i64,
        drift_ppm: fits[k].0.drift * 1e6,
        matched: fits[k].1.matched.len(),
    });
    let (map, mut out) = fits.swap_remove(0);
    out.arrivals_agree = arrivals_agree;
    out.fingerprint = fingerprint;
    let drift_ppm = map.drift * 1e6;
    let residuals: Vec<f64> = out
        .matched
        .iter()
        .map(|&(si, fi)| map.residual_ns(&steps[si], &frames[fi]))
        .collect();
    let spread = residuals.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
        - residuals.iter().cloned().fold(f64::INFINITY, f64::min);
    let usable = frames.len().min(steps.len());
    let problem = if usable >= 4 && out.matched.len() * 2 < usable {
        Some(format!(
            "only {} of {usable} frames fit one clock mapping (offset {:.3} s, drift {drift_ppm:+.1} ppm) within ±{:.1} ms",
            out.matched.len(),
            map.offset_ns / 1e9,
            tolerance_ns as f64 / 1e6
        ))
    } else if tie {
        Some(format!(
            "{} frames fit clock offsets a whole step apart equally well (frames lost at the start or end of a periodic sequence, e.g. a camera that stopped): which LED each frame belongs to cannot be told from the stamps, and is not guessed",
            out.matched.len()
        ))
    } else {
        None
    };
    out.clock_offset_ns = map.offset_ns.round() as i64;
    out.clock_drift_ppm = drift_ppm;
    out.residual_spread_ns = if spread.is_finite() { spread as u64 } else { 0 };
    if let Some(p) = problem {
        return Pairing {
            clock_offset_ns: out.clock_offset_ns,
            clock_drift_ppm: out.clock_drift_ppm,
            residual_spread_ns: out.residual_spread_ns,
            arrivals_agree: out.arrivals_agree,
            fingerprint: out.fingerprint,
            ..refused(steps.len(), frames.len(), p)
        };
    }
    out
}

/// Nothing labelled, for `why`.
fn refused(steps: usize, frames: usize, why: String) -> Pairing {
    Pairing {
        missing_steps: (0..steps).collect(),
        extra_frames: (0..frames).collect(),
        clock_problem: Some(why),
        ..Pairing::default()
    }
}

/// The sums of a least-squares line through points: means and centred moments.
struct Line {
    mx: f64,
    my: f64,
    sxx: f64,
    sxy: f64,
}

impl Line {
    /// None under 3 points (no line worth a slope).
    fn fit(points: &[(f64, f64)]) -> Option<Self> {
        if points.len() < 3 {
            return None;
        }
        let n = points.len() as f64;
        let (mx, my) = points
            .iter()
            .fold((0.0, 0.0), |(a, b), (x, y)| (a + x / n, b + y / n));
        let sxx = points.iter().map(|(x, _)| (x - mx) * (x - mx)).sum();
        let sxy = points.iter().map(|(x, y)| (x - mx) * (y - my)).sum();
        Some(Self { mx, my, sxx, sxy })
    }
}

/// When a frame can have reached this host at the earliest: after its step's LED was
/// lit, which is no earlier than the first trigger (after the arrivals' zero) plus the
/// step's controller time since then at the controller's slowest credible rate.
#[derive(Clone, Copy)]
struct Causality<'a> {
    /// The first trigger, controller ns.
    first: u64,
    /// Host ns per controller ns, at least ([`controller_rate_lower_bound`]).
    rate: f64,
    /// When each frame reached the host, ns from the arrivals' zero.
    frames_ns: &'a [i64],
}

impl Causality<'_> {
    /// The rule for `steps` with `arrivals`; None when the step reports cannot bound the
    /// controller's rate (then nothing is ruled out).
    fn new<'a>(steps: &[StepTime], first: u64, arrivals: Arrivals<'a>) -> Option<Causality<'a>> {
        Some(Causality {
            first,
            rate: controller_rate_lower_bound(steps, arrivals.steps_ns)?,
            frames_ns: arrivals.frames_ns,
        })
    }

    /// Whether most of `matched`'s (step, frame) pairs would have the frame reach the
    /// host before the earliest instant its LED can have been lit. Most, not any: a
    /// stray frame does not rule out the rest.
    fn rules_out(&self, steps: &[StepTime], matched: &[(usize, usize)]) -> bool {
        let early = matched
            .iter()
            .filter(|&&(si, fi)| {
                let earliest = (steps[si].trigger_ns - self.first) as f64 * self.rate;
                self.frames_ns
                    .get(fi)
                    .is_some_and(|&t| (t as f64) < earliest)
            })
            .count();
        early * 2 > matched.len()
    }
}

/// How many host ns at least pass per controller ns, as the step reports show it.
///
/// A step's LED is lit no earlier than the first trigger (which came after the
/// arrivals' zero) plus its controller time since then, converted at the controller's
/// rate against this host's clock. That rate is not assumed (an emulated RP2040 runs at
/// a fraction of real time, a real one within ppm): it is fitted, by least squares, to
/// when the step reports arrived against their trigger times, and lowered by what the
/// reports' latency spread leaves uncertain (twice the fit's residual range over the
/// span of the steps) and by [`MAX_DRIFT_PPM`]. Any steady controller clock passes.
/// None with fewer than 3 reports or no span: then nothing is ruled out.
fn controller_rate_lower_bound(steps: &[StepTime], arrived_ns: &[i64]) -> Option<f64> {
    let points: Vec<(f64, f64)> = steps
        .iter()
        .zip(arrived_ns)
        .map(|(s, &t)| (s.trigger_ns as f64, t as f64))
        .collect();
    let Line { mx, my, sxx, sxy } = Line::fit(&points)?;
    let (lo, hi) = points
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(p.0), hi.max(p.0))
        });
    let span = hi - lo;
    if sxx <= 0.0 || span <= 0.0 {
        return None;
    }
    let rate = sxy / sxx;
    let residuals = points.iter().map(|(x, y)| y - (my + rate * (x - mx)));
    let (rlo, rhi) = residuals.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), r| {
        (lo.min(r), hi.max(r))
    });
    let bound = rate * (1.0 - MAX_DRIFT_PPM * 1e-6) - 2.0 * (rhi - rlo) / span;
    (bound > 0.0).then_some(bound)
}

/// From a first guess of the mapping, alternately pair and fit offset and drift until
/// no more frames pair.
fn refine(
    steps: &[StepTime],
    frames: &[FrameTime],
    mut map: ClockMap,
    tolerance_ns: u64,
) -> (ClockMap, Pairing) {
    let mut out = match_with(steps, frames, &map, tolerance_ns);
    // Each fit over the pairs found can reach pairs further along the drift.
    for _ in 0..20 {
        let Some(better) = fit(steps, frames, &out.matched, map) else {
            break;
        };
        let next = match_with(steps, frames, &better, tolerance_ns);
        if next.matched.len() < out.matched.len() {
            break;
        }
        let grew = next.matched.len() > out.matched.len();
        (map, out) = (better, next);
        if !grew {
            break;
        }
    }
    (map, out)
}

/// How far a candidate's stamps scatter about its mapped triggers (rms about their
/// mean: the offset is free, so a candidate that was not refitted is not favoured by
/// where its fit started), ns. Infinite under [`MIN_PAIRS_TO_COMPARE`] pairs.
fn residual_rms_ns(steps: &[StepTime], frames: &[FrameTime], fit: &(ClockMap, Pairing)) -> f64 {
    if fit.1.matched.len() < MIN_PAIRS_TO_COMPARE {
        return f64::INFINITY;
    }
    scatter_ns(steps, frames, fit)
}

/// The index of the one of `fits` singled out by its stamps' residuals
/// ([`Pairing::fingerprint`]): at least [`MIN_PAIRS_TO_COMPARE`] pairs and half as many
/// as the most any labels, and every other candidate labelling at least half as many
/// frames as it scatters decisively more ([`DECISIVE_RMS_RATIO`],
/// [`MIN_RMS_DIFFERENCE_NS`]). A rival is measured over as few as 3 pairs; one that
/// cannot be measured is not counted as beaten.
fn singled_out_by_stamps(
    steps: &[StepTime],
    frames: &[FrameTime],
    fits: &[(ClockMap, Pairing)],
) -> Option<usize> {
    let most = fits.iter().map(|f| f.1.matched.len()).max()?;
    let rms: Vec<f64> = fits.iter().map(|f| scatter_ns(steps, frames, f)).collect();
    let (k, own) = rms
        .iter()
        .copied()
        .enumerate()
        .filter(|&(k, _)| {
            let n = fits[k].1.matched.len();
            n >= MIN_PAIRS_TO_COMPARE && n * 2 >= most
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))?;
    let n = fits[k].1.matched.len();
    let beaten = (0..fits.len())
        .filter(|&r| r != k && fits[r].1.matched.len() * 2 >= n)
        .all(|r| rms[r].is_finite() && rms[r] >= DECISIVE_RMS_RATIO * own + MIN_RMS_DIFFERENCE_NS);
    (own.is_finite() && beaten).then_some(k)
}

/// [`residual_rms_ns`] over any 3 pairs or more (infinite under 3).
fn scatter_ns(steps: &[StepTime], frames: &[FrameTime], fit: &(ClockMap, Pairing)) -> f64 {
    let (map, p) = fit;
    if p.matched.len() < 3 {
        return f64::INFINITY;
    }
    let r: Vec<f64> = p
        .matched
        .iter()
        .map(|&(si, fi)| map.residual_ns(&steps[si], &frames[fi]))
        .collect();
    let n = r.len() as f64;
    let mean = r.iter().sum::<f64>() / n;
    (r.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n).sqrt()
}

/// Pair with a known clock mapping: a frame gets the one step near its stamp, if that
/// step has no rival frame.
///
/// Steps and frames are put in time order once, so that a frame's candidate steps and a
/// step's rival frames are found by binary search in a window a little wider than
/// [`within`]'s, then checked exactly: the same pairing as comparing every frame with
/// every step, in O((F + S) log S) instead of O(F·S + F²) (it is run for every
/// candidate offset and every refinement, and was most of the labeller's time).
fn match_with(
    steps: &[StepTime],
    frames: &[FrameTime],
    map: &ClockMap,
    tolerance_ns: u64,
) -> Pairing {
    let near = |s: &StepTime, f: &FrameTime| within(map.residual_ns(s, f), tolerance_ns);
    // The window on the controller's mapped time, widened by far more than the
    // rounding of the mapping (its exact check follows).
    let tol = tolerance_ns as f64;
    let slack = 10_000.0;
    let (early, late) = (tol + slack, LATE_TOLERANCES * tol + slack);
    let mut by_time: Vec<(f64, usize)> = steps
        .iter()
        .enumerate()
        .map(|(si, s)| (map.predicted_ns(s), si))
        .collect();
    by_time.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut frames_by_time: Vec<(f64, usize)> = frames
        .iter()
        .enumerate()
        .map(|(fi, f)| (ns_f64(f.timestamp_ns as i128), fi))
        .collect();
    frames_by_time.sort_by(|a, b| a.0.total_cmp(&b.0));
    // Items of `sorted` whose time is within [from, to].
    fn between(sorted: &[(f64, usize)], from: f64, to: f64) -> impl Iterator<Item = usize> + '_ {
        let first = sorted.partition_point(|x| x.0 < from);
        sorted[first..]
            .iter()
            .take_while(move |x| x.0 <= to)
            .map(|x| x.1)
    }
    let mut out = Pairing::default();
    let mut step_taken = vec![false; steps.len()];
    for (fi, f) in frames.iter().enumerate() {
        // residual = stamp − predicted ∈ [−tol, late]: predicted ∈ [stamp − late, stamp + tol].
        let stamp = ns_f64(f.timestamp_ns as i128);
        let mut candidates =
            between(&by_time, stamp - late, stamp + early).filter(|&si| near(&steps[si], f));
        match (candidates.next(), candidates.next()) {
            (None, _) => out.extra_frames.push(fi),
            (Some(si), None) => {
                let predicted = map.predicted_ns(&steps[si]);
                let rivals = between(&frames_by_time, predicted - early, predicted + late)
                    .filter(|&gi| near(&steps[si], &frames[gi]))
                    .count();
                if rivals == 1 {
                    out.matched.push((si, fi));
                    step_taken[si] = true;
                } else {
                    out.ambiguous_frames.push(fi);
                }
            }
            (Some(_), Some(_)) => out.ambiguous_frames.push(fi),
        }
    }
    out.missing_steps = (0..steps.len()).filter(|&si| !step_taken[si]).collect();
    out
}

/// Least-squares offset and drift over `matched`, with pairs further than 4 robust
/// standard deviations (or 1 µs, whichever is more) from the median residual left
/// out. None with fewer than 3 pairs (drift is then taken as 0).
fn fit(
    steps: &[StepTime],
    frames: &[FrameTime],
    matched: &[(usize, usize)],
    map: ClockMap,
) -> Option<ClockMap> {
    if matched.len() < 3 {
        return None;
    }
    let mut residuals: Vec<f64> = matched
        .iter()
        .map(|&(si, fi)| map.residual_ns(&steps[si], &frames[fi]))
        .collect();
    let (m, mad) = fpm_physics::stats::median_and_sigma(&residuals)?;
    let keep = (4.0 * mad).max(1_000.0);
    // x: controller time since t0 (s); y: camera minus controller (ns).
    let points: Vec<(f64, f64)> = matched
        .iter()
        .zip(&mut residuals)
        .filter(|(_, r)| (**r - m).abs() <= keep)
        .map(|(&(si, fi), _)| {
            let t = steps[si].trigger_ns as i128;
            (
                ns_f64(t - map.t0_ns) / 1e9,
                ns_f64(frames[fi].timestamp_ns as i128 - t),
            )
        })
        .collect();
    let Line { mx, my, sxx, sxy } = Line::fit(&points)?;
    // Over less than a millisecond of controller time drift is not observable; and no
    // working camera's clock drifts beyond MAX_DRIFT_PPM, however a short run's jitter
    // would have it (a fitted drift extrapolated beyond the frames fitted would move
    // later windows onto the neighbouring step).
    let max_slope = MAX_DRIFT_PPM * 1e-6 * 1e9;
    let slope = if sxx > 1e-6 {
        (sxy / sxx).clamp(-max_slope, max_slope)
    } else {
        0.0
    };
    Some(ClockMap {
        t0_ns: map.t0_ns,
        offset_ns: my - slope * mx,
        drift: slope / 1e9,
    })
}

/// The step a frame belongs to once its stamp is mapped back to the controller's clock
/// (`controller_ns`): the index into `steps` (in trigger order, as the controller
/// reports them) of the one step in whose window (see [`pair`]) it falls; None when
/// none or several are.
pub fn step_for(steps: &[StepTime], controller_ns: i128, tolerance_ns: u64) -> Option<usize> {
    one_in_window(steps, |s| s.trigger_ns, ns_f64(controller_ns), tolerance_ns)
}

/// The index of the one item of `sorted` (ascending `trigger_ns`) whose window holds
/// the mapped time `t`: the trigger at most twice the tolerance before `t` and one
/// after it ([`LATE_TOLERANCES`]); None when none or several do. A binary search.
fn one_in_window<T>(
    sorted: &[T],
    trigger_ns: impl Fn(&T) -> u64,
    t: f64,
    tolerance_ns: u64,
) -> Option<usize> {
    let tol = tolerance_ns as f64;
    let from = sorted.partition_point(|x| (trigger_ns(x) as f64) < t - LATE_TOLERANCES * tol);
    let mut near = sorted[from..]
        .iter()
        .take_while(|x| trigger_ns(x) as f64 <= t + tol);
    match (near.next(), near.next()) {
        (Some(_), None) => Some(from),
        _ => None,
    }
}

/// How many candidate clock offsets are fitted at most.
const MAX_FITTED: usize = 21;

/// The clock offsets worth fitting, best first: each alignment of a reference frame
/// (the frames a quarter, half and three quarters through by stamp, in case one is a
/// stray) with each step, and the densest cluster of frame-minus-step differences,
/// scored by how many frames the offset alone gives exactly one step. Offsets under
/// which most frames would have reached the host before their LED was lit are left
/// out. The [`MAX_FITTED`] best are returned; None when more than that many tie for the
/// best score, so that the true offset might not be among them (far more steps than
/// frames): that is refused, not guessed.
fn candidate_offsets(
    steps: &[StepTime],
    frames: &[FrameTime],
    tolerance_ns: u64,
    max_offset_ns: u64,
    first: u64,
    causality: Option<Causality<'_>>,
) -> Option<Vec<f64>> {
    let densest = estimate_offset(steps, frames, tolerance_ns, max_offset_ns) as f64;
    let mut by_stamp: Vec<u64> = frames.iter().map(|f| f.timestamp_ns).collect();
    by_stamp.sort_unstable();
    let mut refs: Vec<u64> = [1, 2, 3]
        .iter()
        .filter_map(|q| by_stamp.get(by_stamp.len() * q / 4).copied())
        .collect();
    refs.dedup();
    // The window's centre: a tolerance early to two late.
    let centre = (LATE_TOLERANCES - 1.0) / 2.0 * tolerance_ns as f64;
    let mut offsets: Vec<f64> = refs
        .iter()
        .flat_map(|&r| {
            steps
                .iter()
                .map(move |s| r as f64 - s.trigger_ns as f64 - centre)
        })
        .filter(|o| o.abs() <= max_offset_ns as f64)
        .chain(std::iter::once(densest))
        .collect();
    offsets.sort_by(f64::total_cmp);
    offsets.dedup_by(|a, b| (*a - *b).abs() < tolerance_ns as f64 / 2.0);
    let mut triggers: Vec<(u64, usize)> = steps
        .iter()
        .enumerate()
        .map(|(i, s)| (s.trigger_ns, i))
        .collect();
    triggers.sort_unstable();
    let mut scored: Vec<(usize, f64)> = offsets
        .into_iter()
        .filter_map(|offset_ns| {
            let map = ClockMap {
                t0_ns: first as i128,
                offset_ns,
                drift: 0.0,
            };
            let pairs = quick_pairs(&triggers, frames, &map, tolerance_ns);
            let ruled_out = causality.is_some_and(|c| c.rules_out(steps, &pairs));
            (!ruled_out).then_some((pairs.len(), offset_ns))
        })
        .collect();
    // Best first; among equals, nearest the densest cluster.
    scored.sort_by(|a, b| {
        b.0.cmp(&a.0)
            .then((a.1 - densest).abs().total_cmp(&(b.1 - densest).abs()))
    });
    let best = scored.first().map_or(0, |s| s.0);
    let tied = scored.iter().filter(|s| s.0 == best).count();
    if best > 0 && tied > MAX_FITTED {
        return None;
    }
    if scored.is_empty() {
        // Everything ruled out: fit the densest, for the refusal that follows.
        return Some(vec![densest]);
    }
    Some(scored.into_iter().take(MAX_FITTED).map(|s| s.1).collect())
}

/// (step, frame) for each frame with exactly one step in its window under `map`;
/// `triggers` (trigger, step index) sorted by trigger.
fn quick_pairs(
    triggers: &[(u64, usize)],
    frames: &[FrameTime],
    map: &ClockMap,
    tolerance_ns: u64,
) -> Vec<(usize, usize)> {
    frames
        .iter()
        .enumerate()
        .filter_map(|(fi, f)| {
            let t = f.timestamp_ns as f64 - map.offset_ns;
            let k = one_in_window(triggers, |&(x, _)| x, t, tolerance_ns)?;
            Some((triggers[k].1, fi))
        })
        .collect()
}

/// The clock offset most frame/step pairs agree on: the centre of the densest window
/// of frame-minus-step differences (0 when there is nothing to go by).
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
    // Its centre, not its median: a camera's latency is often skewed (a trigger waits
    // for the sensor's next line or tick), and the centre keeps both ends inside.
    window[0] + (window[window.len() - 1] - window[0]) / 2
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_known_offset_gives_each_frame_its_one_step() {
        let s = steps(10);
        let f = frames_for(&s, 7_000_000, &[0, 1_000_000, -2_000_000]);
        let mapped = |f: &FrameTime, offset: i64| f.timestamp_ns as i128 - offset as i128;
        for (k, frame) in f.iter().enumerate() {
            assert_eq!(step_for(&s, mapped(frame, 7_000_000), TOL), Some(k));
        }
        // A wrong offset by a step period would label every frame with its neighbour:
        // only the right offset gives frame 0 a step before it is too late.
        assert_eq!(
            step_for(&s, mapped(&f[0], 7_000_000 + PERIOD as i64), TOL),
            None
        );
        // Between two steps, nothing.
        let between = s[3].trigger_ns as i128 + PERIOD as i128 / 2;
        assert_eq!(step_for(&s, between, TOL), None);
    }

    /// Matching by binary search over time-ordered steps and frames pairs exactly as
    /// comparing every frame with every step does, on crowded, shuffled, drifting
    /// captures where windows overlap, frames go missing and come twice.
    #[test]
    fn matching_by_search_is_matching_every_pair() {
        let every_pair = |steps: &[StepTime], frames: &[FrameTime], map: &ClockMap, tol: u64| {
            let near = |s: &StepTime, f: &FrameTime| within(map.residual_ns(s, f), tol);
            let mut out = Pairing::default();
            let mut taken = vec![false; steps.len()];
            for (fi, f) in frames.iter().enumerate() {
                let c: Vec<usize> = (0..steps.len()).filter(|&si| near(&steps[si], f)).collect();
                match c.as_slice() {
                    [] => out.extra_frames.push(fi),
                    [si] if frames.iter().filter(|g| near(&steps[*si], g)).count() == 1 => {
                        out.matched.push((*si, fi));
                        taken[*si] = true;
                    }
                    _ => out.ambiguous_frames.push(fi),
                }
            }
            out.missing_steps = (0..steps.len()).filter(|&si| !taken[si]).collect();
            out
        };
        let mut rng = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = |m: u64| {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            rng % m
        };
        let mut disagreements = 0;
        let mut matched = 0;
        for case in 0..400 {
            let n = 1 + next(120) as usize;
            let mut t = 1_000_000_000 + next(1 << 40);
            let mut steps = Vec::new();
            for i in 0..n {
                steps.push(StepTime {
                    step: i,
                    trigger_ns: t,
                });
                t += 2_000_000 + next(30_000_000);
            }
            if case % 5 == 0 {
                steps.reverse(); // out of order: the search must not assume it
            }
            let offset = next(1 << 36) as f64 - (1u64 << 35) as f64;
            let drift = (next(2001) as f64 - 1000.0) * 1e-6;
            let map = ClockMap {
                t0_ns: steps[0].trigger_ns as i128,
                offset_ns: offset,
                drift,
            };
            let mut frames = Vec::new();
            for s in &steps {
                if next(10) == 0 {
                    continue; // lost
                }
                let copies = if next(15) == 0 { 2 } else { 1 };
                let at = map.predicted_ns(s) + next(12_000_000) as f64 - 4_000_000.0;
                for k in 0..copies {
                    frames.push(FrameTime {
                        frame_number: 0,
                        timestamp_ns: (at + k as f64 * 1_000_000.0).max(0.0) as u64,
                    });
                }
            }
            frames.sort_by_key(|f| f.timestamp_ns ^ (case & 1)); // arrival order, roughly
            let tol = 1_000_000 + next(5_000_000);
            let fast = match_with(&steps, &frames, &map, tol);
            matched += fast.matched.len();
            if fast != every_pair(&steps, &frames, &map, tol) {
                disagreements += 1;
            }
        }
        assert_eq!(disagreements, 0);
        assert!(matched > 10_000, "the cases must pair frames: {matched}");
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

    /// A camera clock seconds away from the controller's, running 100 ppm fast, with
    /// 0.5 ms of jitter, over a 441-step run: every frame gets its own step, and the
    /// fitted drift is the one put in.
    #[test]
    fn offset_drift_and_jitter_are_fitted_and_every_frame_labelled() {
        let s = steps(441);
        let mut rng = 0x1234_5678_u64;
        let mut uniform = || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng % 1_000_000) as f64 / 1e6
        };
        let t0 = s[0].trigger_ns as f64;
        let f: Vec<FrameTime> = s
            .iter()
            .enumerate()
            .map(|(k, st)| {
                let t = st.trigger_ns as f64;
                let camera = 3_700_000_000_000.0 + t + 100e-6 * (t - t0) + (uniform() - 0.5) * 1e6;
                FrameTime {
                    frame_number: k as u64,
                    timestamp_ns: camera as u64,
                }
            })
            .collect();
        let p = pair(&s, &f, TOL, u64::MAX);
        assert_eq!(p.clock_problem, None);
        assert_eq!(p.matched.len(), 441, "{:?}", p.missing_steps);
        assert!(p.matched.iter().all(|&(si, fi)| si == fi));
        assert!(
            (p.clock_drift_ppm - 100.0).abs() < 2.0,
            "{}",
            p.clock_drift_ppm
        );
        assert!(
            p.residual_spread_ns <= 1_100_000,
            "{}",
            p.residual_spread_ns
        );
        // Without the drift fit the last frames would be 1.76 ms off: with a tolerance
        // tighter than that, only the fit labels them all.
        let tight = pair(&s, &f, 1_500_000, u64::MAX);
        assert_eq!(
            tight.matched.len(),
            441,
            "{:?} {} {} {:?}",
            tight.missing_steps,
            tight.clock_drift_ppm,
            tight.residual_spread_ns,
            tight.extra_frames
        );
    }

    /// Frames whose stamps follow no common clock with the steps are refused as a
    /// whole, with the reason, rather than some of them guessed.
    #[test]
    fn clocks_that_cannot_be_reconciled_label_nothing() {
        let s = steps(60);
        let mut x = 7u64;
        let f: Vec<FrameTime> = (0..60)
            .map(|k| {
                x = x
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                FrameTime {
                    frame_number: k,
                    timestamp_ns: 5_000_000_000 + (x >> 33) % 2_400_000_000,
                }
            })
            .collect();
        let p = pair(&s, &f, TOL, u64::MAX);
        assert!(p.matched.is_empty());
        assert_eq!(p.missing_steps.len(), 60);
        let why = p.clock_problem.expect("a reason");
        assert!(why.contains("fit one clock mapping"), "{why}");
    }

    /// With the first frame lost, a periodic sequence's frames fit their own steps and
    /// the steps one earlier equally well: refused, and arrival times do not overrule
    /// that, even when they look decisive (they would need a bound on how late a frame
    /// may arrive, which a slow camera breaks without a sign).
    #[test]
    fn a_lost_first_frame_of_a_periodic_run_is_not_guessed_around() {
        let s = steps(30);
        let mut f = frames_for(&s, 2_000_000_000, &[0, 200_000]);
        f.remove(0);
        let p = pair(&s, &f, TOL, u64::MAX);
        assert!(p.matched.is_empty(), "{:?}", p.matched);
        let why = p.clock_problem.expect("a reason");
        assert!(why.contains("a whole step apart"), "{why}");
        // Frame k is step k + 1's. Prompt frames (25 ms after their trigger) would
        // point at the right offset, late ones (1.5 periods) at the wrong one: the
        // host cannot tell the two apart, so neither is followed (pairing each frame
        // with the step before its own is never ruled out by when it arrived).
        let since_start = |t: u64| (t - s[0].trigger_ns) as i64 + 5_000_000;
        let steps_ns: Vec<i64> = s
            .iter()
            .map(|st| since_start(st.trigger_ns) + 1_000_000)
            .collect();
        for late_ns in [25_000_000, 3 * PERIOD as i64 / 2] {
            let frames_ns: Vec<i64> = (0..f.len())
                .map(|k| since_start(s[k + 1].trigger_ns) + late_ns)
                .collect();
            let arrivals = Arrivals {
                steps_ns: &steps_ns,
                frames_ns: &frames_ns,
            };
            let p = pair_with_arrivals(&s, &f, TOL, u64::MAX, Some(arrivals));
            assert!(p.matched.is_empty(), "{late_ns}: {:?}", p.matched);
            assert!(p.clock_problem.unwrap().contains("not guessed"));
        }
    }

    /// Steps as the controller runs them: each takes its period plus the time to
    /// shift its LED update down the chain (`per_led_ns` per LED up to the furthest
    /// one changed: 30 µs for WS2812), so triggers are not exactly periodic.
    fn chain_steps(n: usize, per_led_ns: u64) -> Vec<StepTime> {
        let mut t = 1_000_000_000u64;
        (0..n)
            .map(|i| {
                // A nearest-first order jumps around the chain.
                let chain_index = (i as u64 * 137 + 60) % 441;
                t += PERIOD + chain_index * per_led_ns;
                StepTime {
                    step: i,
                    trigger_ns: t,
                }
            })
            .collect()
    }

    /// A camera that stops mid-run, or loses the first frame: offsets a step apart
    /// label as many frames, but only the true one follows the steps' irregular
    /// timing, and with stamps tighter than that irregularity the stamps decide.
    /// With stamp jitter larger than the irregularity they cannot, and nothing is
    /// labelled.
    #[test]
    fn irregular_steps_decide_between_offsets_a_step_apart_only_when_decisive() {
        let s = chain_steps(60, 30_000);
        // The camera stopped after frame 39.
        let f: Vec<FrameTime> = frames_for(&s, 3_000_000_000, &[0, 40_000, -30_000])
            .into_iter()
            .take(40)
            .collect();
        let p = pair(&s, &f, TOL, u64::MAX);
        assert_eq!(p.clock_problem, None);
        assert_eq!(p.matched.len(), 40);
        assert!(
            p.matched.iter().all(|&(si, fi)| si == fi),
            "{:?}",
            p.matched
        );
        // The first frame lost: frame k is step k + 1's.
        let mut f = frames_for(&s, 3_000_000_000, &[0, 40_000, -30_000]);
        f.remove(0);
        let p = pair(&s, &f, TOL, u64::MAX);
        assert_eq!(p.clock_problem, None);
        assert!(
            p.matched.iter().all(|&(si, fi)| si == fi + 1),
            "{:?}",
            p.matched
        );
        assert_eq!(p.missing_steps, vec![0]);
        // A faster chain (1 µs per LED) under ±0.4 ms of stamp jitter: refused.
        let s = chain_steps(60, 1_000);
        let jitter: Vec<i64> = (0..60).map(|k| ((k * 7919) % 9 - 4) * 100_000).collect();
        let mut f = frames_for(&s, 3_000_000_000, &jitter);
        f.remove(0);
        let p = pair(&s, &f, TOL, u64::MAX);
        assert!(p.matched.is_empty(), "{:?}", p.matched);
        assert!(p.clock_problem.unwrap().contains("a whole step apart"));
    }

    /// A camera that starts an exposure only on its own 12 ms tick (a software
    /// trigger), so its stamps are too coarse for the steps' irregular timing, and
    /// that stopped before the last step: offsets a step apart label 59 frames each. Frames reaching the host within a step rule out the later one (its frames
    /// would have arrived before their LEDs were lit); frames slower than a step do
    /// not, and nothing is guessed. A first frame answered late, but less than two
    /// thirds of a step, is still its step's: then the count decides.
    #[test]
    fn frames_cannot_arrive_before_their_led_was_lit() {
        let s = chain_steps(60, 10_000);
        let tolerance = PERIOD / 3;
        let tick = 12_000_000;
        let mut f: Vec<FrameTime> = s
            .iter()
            .enumerate()
            .map(|(k, st)| FrameTime {
                frame_number: k as u64,
                timestamp_ns: (st.trigger_ns + 7_000_000_000).div_ceil(tick) * tick,
            })
            .collect();
        let on_time = f.clone();
        f.pop();
        let p = pair(&s, &f, tolerance, u64::MAX);
        assert!(
            p.matched.is_empty(),
            "the stamps alone decide: {:?}",
            p.matched
        );
        // Arrivals from an instant 5 ms before the first trigger.
        let since_start = |t: u64| (t - s[0].trigger_ns) as i64 + 5_000_000;
        let steps_ns: Vec<i64> = s
            .iter()
            .map(|st| since_start(st.trigger_ns) + 1_000_000)
            .collect();
        for (late_ns, decided) in [(15_000_000, true), (3 * PERIOD as i64 / 2, false)] {
            let frames_ns: Vec<i64> = s
                .iter()
                .enumerate()
                .map(|(k, st)| since_start(st.trigger_ns) + late_ns + (k as i64 % 7) * 1_000_000)
                .collect();
            let arrivals = Arrivals {
                steps_ns: &steps_ns,
                frames_ns: &frames_ns,
            };
            let p = pair_with_arrivals(&s, &f, tolerance, u64::MAX, Some(arrivals));
            if decided {
                assert_eq!(p.clock_problem, None);
                assert_eq!(p.matched.len(), 59);
                assert!(
                    p.matched.iter().all(|&(si, fi)| si == fi),
                    "{:?}",
                    p.matched
                );
                assert_eq!(p.missing_steps, vec![59]);
            } else {
                assert!(p.matched.is_empty(), "{late_ns}: {:?}", p.matched);
                assert!(p.clock_problem.unwrap().contains("a whole step apart"));
            }
        }
        // Arrivals before any trigger could have fired: nothing fits.
        let frames_ns = vec![0i64; f.len()];
        let arrivals = Arrivals {
            steps_ns: &steps_ns,
            frames_ns: &frames_ns,
        };
        let p = pair_with_arrivals(&s, &f, tolerance, u64::MAX, Some(arrivals));
        assert!(p.matched.is_empty());
        assert!(p
            .clock_problem
            .unwrap()
            .contains("before their LED was lit"));
        // The first frame a tick late (more than the tolerance): labelled, and so all.
        let mut f = on_time;
        f[0].timestamp_ns += tick;
        let p = pair(&s, &f, tolerance, u64::MAX);
        assert_eq!(p.clock_problem, None);
        assert_eq!(p.matched.len(), 60);
        assert!(
            p.matched.iter().all(|&(si, fi)| si == fi),
            "{:?}",
            p.matched
        );
    }

    /// A camera slower than a step period: the stamps decide (no frame lost), and the
    /// arrivals, which would point at the neighbouring offset, are reported as
    /// disagreeing, so labels given while frames arrive wait.
    #[test]
    fn arrivals_that_point_elsewhere_are_flagged_not_followed() {
        let s = steps(30);
        let f = frames_for(&s, 900_000_000, &[0, 150_000]);
        let steps_ns: Vec<i64> = s.iter().map(|st| st.trigger_ns as i64).collect();
        // Each frame reaches the host 1.5 periods after its own trigger.
        let frames_ns: Vec<i64> = s
            .iter()
            .map(|st| st.trigger_ns as i64 + 3 * PERIOD as i64 / 2)
            .collect();
        let arrivals = Arrivals {
            steps_ns: &steps_ns,
            frames_ns: &frames_ns,
        };
        let p = pair_with_arrivals(&s, &f, TOL, u64::MAX, Some(arrivals));
        assert_eq!(p.matched.len(), 30);
        assert!(p.matched.iter().all(|&(si, fi)| si == fi));
        assert!(!p.arrivals_agree);
        // Frames arriving soon after their trigger agree.
        let prompt: Vec<i64> = steps_ns.iter().map(|t| t + 3_000_000).collect();
        let arrivals = Arrivals {
            steps_ns: &steps_ns,
            frames_ns: &prompt,
        };
        assert!(pair_with_arrivals(&s, &f, TOL, u64::MAX, Some(arrivals)).arrivals_agree);
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
