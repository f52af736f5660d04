//! One capture sequence: drives the LED controller through a list of LEDs, takes the
//! camera's frames from the iceoryx2 frame service, labels every frame with the LED
//! that lit it ([`crate::label`]), and hands labelled frames on as they arrive.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use fpm_frames::{FrameHeader, FrameSubscriber, ServiceNames};
use fpm_physics::frame::{Counts, LitFrame, Measured, Response};
use fpm_protocol::{
    Illumination, LedIndex, Polarity, Rgb, SequenceEnd, SequenceOutcome, SequenceTiming, Step,
    TriggerOut,
};
use ndarray::{Array2, ArrayView2};
use serde::Serialize;

use crate::controller::{Controller, ControllerError, SequenceEvent, SequenceEvents};
use crate::label::{FrameTime, StepTime};
use crate::labeller::{Label, Labelled, Labeller, SequenceSteps, Waiting};

/// A frame with the LED that lit it.
pub struct Shot {
    /// LED (row, col).
    pub led: LedIndex,
    /// The camera's header.
    pub header: FrameHeader,
    /// Pixels `[row, col]`: the one copy out of shared memory, kept for the dataset.
    pub pixels: Array2<u16>,
}

impl Shot {
    /// Borrowed, as handed out while capturing.
    pub fn view(&self) -> ShotView<'_> {
        ShotView {
            led: self.led,
            header: &self.header,
            pixels: self.pixels.view(),
        }
    }
}

/// A frame handed out while the capture runs, borrowed (no copy on the way to the
/// streaming reconstructor).
#[derive(Clone, Copy)]
pub struct ShotView<'a> {
    /// LED (row, col).
    pub led: LedIndex,
    /// The camera's header.
    pub header: &'a FrameHeader,
    /// Pixels `[row, col]`.
    pub pixels: ArrayView2<'a, u16>,
}

impl<'a> ShotView<'a> {
    /// The frame as the reconstruction takes it: counts, `dark_level`, and the exposure
    /// the camera reported.
    pub fn lit_frame(&self, dark_level: f32) -> LitFrame<'a> {
        LitFrame {
            also: &[],
            led: self.led,
            measured: Measured {
                counts: Counts::U16(self.pixels),
                response: Response::Linear,
                dark_level,
                exposure_ms: self.header.exposure_us.max(1) as f32 / 1e3,
                floor: 0.0,
                soft_floor: false,
                band: 0.0,
            },
        }
    }
}

/// What a capture did.
#[derive(Debug, Clone, Default, Serialize)]
pub struct CaptureReport {
    /// Steps in the sequence.
    pub requested: usize,
    /// Frames labelled with their LED.
    pub labelled: usize,
    /// LEDs whose frame is missing (dropped, ambiguous).
    pub missing: Vec<LedIndex>,
    /// Frames that matched no step.
    pub extra_frames: usize,
    /// Frames refused because more than one step or frame fit.
    pub ambiguous_frames: usize,
    /// Camera clock minus controller clock at the first step, ns, as fitted.
    pub clock_offset_ns: i64,
    /// How much faster the camera's clock runs than the controller's, ppm, as fitted.
    pub clock_drift_ppm: f64,
    /// Spread of the labelled frames' stamps around the fitted clock mapping, ms (the
    /// camera's trigger-to-stamp jitter).
    pub stamp_spread_ms: f64,
    /// Why no frame could be labelled, when the camera's clock could not be reconciled
    /// with the controller's.
    pub clock_problem: Option<String>,
    /// From sequence start to the last frame, s.
    pub seconds: f64,
    /// Frames per second.
    pub frames_per_s: f64,
    /// How the controller's sequence ended.
    pub outcome: String,
    /// The capture broke off (controller lost); what arrived is still labelled.
    pub failed: bool,
    /// Frames handed out while acquiring whose final label differs, or that the final
    /// pairing refused (0 expected; the dataset follows the final labels, and a caller
    /// that streamed them must not trust what it built).
    pub relabelled: usize,
    /// Controller sequences it took: 1, and one more after each pause.
    pub sequences: usize,
    /// Frames labelled while the controller's sequence still ran, as they arrived (the
    /// rest waited for the final pairing).
    pub labelled_live: usize,
    /// Frames that arrived while the controller's sequence still ran: the most that
    /// could be labelled live (a camera that falls behind its triggers delivers the
    /// rest after the end, however quick the labeller).
    pub arrived_live: usize,
    /// A frame's arrival to its label being handed on, ms: the median over the
    /// labelled frames (those the final pairing labelled too).
    pub label_lag_p50_ms: f64,
    /// The same, 99th percentile.
    pub label_lag_p99_ms: f64,
    /// When the controller confirmed the sequence aborted, its LEDs off (it commits
    /// them dark before it answers).
    #[serde(skip)]
    pub leds_off_at: Option<Instant>,
    /// A cancel's request to the controller's LEDs off, ms (the caller's to fill in:
    /// it knows when the cancel was asked for).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cancel_to_leds_off_ms: Option<f64>,
}

impl CaptureReport {
    /// This capture continued by `later`, which lit the LEDs it had not reached (after
    /// a pause): one report over both. The clock fit is the later sequence's (each
    /// sequence restarts the controller's clock).
    pub fn then(&mut self, later: CaptureReport) {
        self.labelled += later.labelled;
        self.missing = later.missing;
        self.extra_frames += later.extra_frames;
        self.ambiguous_frames += later.ambiguous_frames;
        self.clock_offset_ns = later.clock_offset_ns;
        self.clock_drift_ppm = later.clock_drift_ppm;
        self.stamp_spread_ms = self.stamp_spread_ms.max(later.stamp_spread_ms);
        self.clock_problem = later.clock_problem.or(self.clock_problem.take());
        self.seconds += later.seconds;
        self.frames_per_s = self.labelled as f64 / self.seconds.max(1e-9);
        self.outcome = later.outcome;
        self.failed = later.failed;
        self.relabelled += later.relabelled;
        self.sequences += later.sequences;
        self.labelled_live += later.labelled_live;
        self.arrived_live += later.arrived_live;
        // The worse sequence's (the two are not pooled).
        self.label_lag_p50_ms = self.label_lag_p50_ms.max(later.label_lag_p50_ms);
        self.label_lag_p99_ms = self.label_lag_p99_ms.max(later.label_lag_p99_ms);
        self.leds_off_at = later.leds_off_at.or(self.leds_off_at);
        self.cancel_to_leds_off_ms = later.cancel_to_leds_off_ms.or(self.cancel_to_leds_off_ms);
    }
}

/// One capture sequence: which LEDs in which order, lit how.
#[derive(Debug, Clone, Copy)]
pub struct Sequence<'a> {
    /// The id it is uploaded under.
    pub id: u32,
    /// The LEDs, one frame each, in order.
    pub leds: &'a [LedIndex],
    /// Their colour.
    pub color: Rgb,
    /// How long each stays lit, µs.
    pub exposure_us: u32,
}

/// Sequence timing for one frame per step: the camera is triggered once the LEDs have
/// settled; `exposure_us` is how long each step stays lit.
pub fn timing(exposure_us: u32) -> SequenceTiming {
    SequenceTiming {
        settle_us: 500,
        exposure_us,
        trigger_out: Some(TriggerOut {
            delay_us: 50,
            pulse_us: 100,
            polarity: Polarity::ActiveHigh,
        }),
        trigger_in: None,
        clear_at_end: true,
    }
}

/// Frames taken off the frame service by their own thread, so that a busy consumer
/// (EPRY updates, disk) never lets the service's small buffer overflow. iceoryx2 ports
/// stay on the thread that made them, so the thread opens its own subscriber.
struct FrameDrain {
    rx: mpsc::Receiver<(FrameHeader, Array2<u16>)>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<Result<(), String>>>,
}

impl FrameDrain {
    fn start(names: &ServiceNames) -> Result<Self> {
        let (tx, rx) = mpsc::channel();
        let (ready_tx, ready_rx) = mpsc::channel::<Result<(), String>>();
        let stop = Arc::new(AtomicBool::new(false));
        let (names, flag) = (names.clone(), stop.clone());
        let thread = std::thread::spawn(move || -> Result<(), String> {
            let sub = match FrameSubscriber::create(&names) {
                Ok(s) => s,
                Err(e) => {
                    let _ = ready_tx.send(Err(e.to_string()));
                    return Err(e.to_string());
                }
            };
            // Frames from before this capture (a stray trigger, a previous run).
            while let Ok(Some(_)) = sub.next(Duration::ZERO) {}
            let _ = ready_tx.send(Ok(()));
            while !flag.load(Ordering::SeqCst) {
                match sub.next(Duration::from_millis(20)) {
                    Ok(Some(f)) => {
                        // The one copy out of shared memory: the sample goes back to the
                        // camera at once, the pixels are kept for the dataset.
                        let h = *f.header();
                        let shape = (h.height as usize, h.width as usize);
                        match Array2::from_shape_vec(shape, f.pixels().to_vec()) {
                            Ok(pixels) => {
                                if tx.send((h, pixels)).is_err() {
                                    break;
                                }
                            }
                            // The contract checks pixel_count = width·height already.
                            Err(e) => tracing::warn!(
                                "frame {}: {}x{} header does not fit its pixels: {e}",
                                h.frame_number,
                                h.width,
                                h.height
                            ),
                        }
                    }
                    Ok(None) => {}
                    Err(e) => return Err(e.to_string()),
                }
            }
            Ok(())
        });
        ready_rx
            .recv_timeout(Duration::from_secs(10))
            .context("the frame thread did not start")?
            .map_err(anyhow::Error::msg)?;
        Ok(Self {
            rx,
            stop,
            thread: Some(thread),
        })
    }
}

impl Drop for FrameDrain {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Run one capture sequence lighting `leds` in order, one frame per LED, with the
/// frames of camera `camera`. Frames are labelled as soon as their step is closed (the
/// next step's trigger was seen, or the sequence ended) and told to `on_news` at once
/// ([`News::Labelled`]: the step indexes `leds`); the final pairing over everything is
/// authoritative and is what the returned shots follow. Every labelled frame is told
/// exactly once (those that could not be labelled while acquiring, right after the
/// final pairing); a frame handed out early that the final pairing contradicts is
/// counted in `relabelled`. Once `stop` says so (a cancel, a pause) the sequence is
/// aborted; the frames that came are labelled as ever.
pub fn capture(
    dev: &Controller,
    camera: &ServiceNames,
    sequence: &Sequence<'_>,
    stop: impl Fn() -> bool,
    on_news: impl FnMut(News<'_>),
) -> Result<(Vec<Shot>, CaptureReport)> {
    let &Sequence {
        id,
        leds,
        color,
        exposure_us,
    } = sequence;
    let steps: Vec<Step> = leds
        .iter()
        .map(|&led| Step {
            illumination: Illumination::Led(led),
            color,
        })
        .collect();
    let (frames, mut report) = capture_steps(
        dev,
        camera,
        id,
        Lighting::Steps(&steps),
        exposure_us,
        stop,
        on_news,
    )?;
    report.missing = frames
        .iter()
        .enumerate()
        .filter(|(_, f)| f.is_none())
        .map(|(s, _)| leds[s])
        .collect();
    let shots = frames
        .into_iter()
        .zip(leds)
        .filter_map(|(f, &led)| {
            f.map(|(header, pixels)| Shot {
                led,
                header,
                pixels,
            })
        })
        .collect();
    Ok((shots, report))
}

/// What a running capture tells its caller, as it happens. The first three are the
/// raw record (what a journal keeps, so that frames that arrived can be labelled
/// again after a crash, whatever the labeller knew): replayed into a [`Labeller`] in
/// the order told, they give the capture's own pairing.
pub enum News<'a> {
    /// The sequence is started: a [`Labeller`] for it takes this tolerance (see
    /// [`Labeller::new`]).
    Started { tolerance_ns: u64 },
    /// The controller reported a step: its trigger on the controller's clock, and
    /// when that was on the host's (ns since the sequence was started).
    Step {
        /// The step and its trigger.
        step: StepTime,
        /// As [`Labeller::step`] takes it.
        arrived_ns: i64,
    },
    /// A frame arrived, not yet labelled; `index` is how labels name it.
    Arrived {
        /// Frames before it in this sequence.
        index: usize,
        /// As [`Labeller::frame`] takes it.
        arrived_ns: i64,
        /// The camera's header.
        header: &'a FrameHeader,
        /// Pixels `[row, col]`.
        pixels: ArrayView2<'a, u16>,
    },
    /// Frame `index` labelled with its step (every labelled frame exactly once).
    Labelled {
        /// The sequence step that lit it.
        step: usize,
        /// As [`News::Arrived`] named it.
        index: usize,
        /// The camera's header.
        header: &'a FrameHeader,
        /// Pixels `[row, col]`.
        pixels: ArrayView2<'a, u16>,
    },
    /// Why labels wait now (None: they flow again); told when it changes.
    Labelling(Option<Waiting>),
    /// How far the controller is; told when it reports a step.
    Steps(SequenceSteps),
}

impl<'a> News<'a> {
    /// A labelled frame as the shot of its LED, the sequence lighting `leds` (None for
    /// the other news).
    pub fn shot(&self, leds: &[LedIndex]) -> Option<ShotView<'a>> {
        match *self {
            News::Labelled {
                step,
                header,
                pixels,
                ..
            } => Some(ShotView {
                led: leds[step],
                header,
                pixels,
            }),
            _ => None,
        }
    }
}

/// A step's frame: the camera's header and the pixels.
pub type StepFrame = (FrameHeader, Array2<u16>);

/// What a sequence's steps light: 1.0 steps (LEDs, patterns, dark), or sets of the
/// controller's LED set table (protocol ≥ 1.2, [`Controller::define_led_sets`]).
#[derive(Debug, Clone, Copy)]
pub enum Lighting<'a> {
    /// One LED, a pattern or nothing per step.
    Steps(&'a [Step]),
    /// One LED set per step.
    Sets(&'a [fpm_protocol::SetStep]),
}

impl Lighting<'_> {
    /// Steps.
    pub fn len(&self) -> usize {
        match self {
            Lighting::Steps(s) => s.len(),
            Lighting::Sets(s) => s.len(),
        }
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// [`capture`] for any steps (patterns, LED sets, dark frames): one frame per
/// step, each labelled with its step's index, told to `on_news` as there. Returns each
/// step's frame (None: missing) in step order, and the report (its `missing` left
/// empty: what a step lit is the caller's to name).
pub fn capture_steps(
    dev: &Controller,
    camera: &ServiceNames,
    sequence_id: u32,
    steps: Lighting<'_>,
    exposure_us: u32,
    stop: impl Fn() -> bool,
    mut on_news: impl FnMut(News<'_>),
) -> Result<(Vec<Option<StepFrame>>, CaptureReport)> {
    let n = steps.len();
    let timing = timing(exposure_us);
    let period_ns = (timing.settle_us as u64 + exposure_us as u64) * 1000;
    // A frame's window, a tolerance early to two late (label::pair), spans one nominal
    // period: shorter than any step, which adds the trigger delay and the LED update.
    let tolerance = (period_ns / 3).max(1_000_000);
    let drain = FrameDrain::start(camera)?;
    match steps {
        Lighting::Steps(s) => dev.upload_sequence(sequence_id, s, timing)?,
        Lighting::Sets(s) => dev.upload_set_sequence(sequence_id, s, timing)?,
    };
    let mut events = dev.subscribe()?;
    let start = Instant::now();
    dev.start_sequence(sequence_id)?;
    // Arrival times are ns since `start`, taken before the sequence started.
    let since_start = || start.elapsed().as_nanos() as i64;
    let mut labeller = Labeller::new(n, tolerance);
    on_news(News::Started {
        tolerance_ns: tolerance,
    });
    let mut waiting = None;
    let mut steps_told = 0;
    // How many frames were labelled before the sequence ended: a live figure.
    let mut live = 0usize;
    let mut arrived_live = 0usize;
    let mut received = Received::default();
    let mut ended = None;
    let mut last_frame = Instant::now();
    let idle_after_end = Duration::from_millis(1500) + Duration::from_nanos(period_ns * 4);
    let mut failure: Option<String> = None;
    let mut aborted = false;
    let mut leds_off_at = None;
    loop {
        if !aborted && ended.is_none() && stop() {
            aborted = true;
            match dev.abort_sequence() {
                Ok(_) => leds_off_at = Some(Instant::now()),
                Err(e) => {
                    failure = Some(format!(
                        "the LED controller did not abort the sequence: {e}"
                    ))
                }
            }
        }
        while let Ok(f) = drain.rx.recv_timeout(Duration::from_millis(1)) {
            received.arrive(f, since_start(), &mut labeller, &mut on_news);
            arrived_live += usize::from(ended.is_none());
            last_frame = Instant::now();
        }
        match next_event(&mut events, &mut labeller, since_start, &mut on_news) {
            Ok(Some(end)) => ended = Some(end),
            Ok(None) => {}
            // Keep what arrived: the caller writes it and reports the failure.
            Err(e) => failure = Some(format!("the LED controller was lost mid-sequence: {e}")),
        }
        let steps = labeller.steps();
        if steps.done != steps_told {
            steps_told = steps.done;
            on_news(News::Steps(steps));
        }
        // Hand frames on while they arrive; the final pairing below checks every label.
        let labels = labeller.labels();
        if labeller.waiting() != waiting {
            waiting = labeller.waiting();
            if let Some(why) = waiting.filter(|w| *w != Waiting::FirstFrames) {
                tracing::info!("{why}");
            }
            on_news(News::Labelling(waiting));
        }
        for l in &labels {
            received.label(l, since_start(), &mut on_news);
            live += usize::from(ended.is_none());
        }
        if !labels.is_empty() {
            // Time spent streaming is not the camera being idle.
            last_frame = Instant::now();
        }
        let complete = received.frames.len() >= n;
        // Frames still on their way are waited for; after a cancel only briefly (the
        // LEDs it lit last, a few periods), and not at all once a frame has come for
        // every step the controller finished and a period has passed without another:
        // a cancel ends the capture at once.
        let idle = match aborted {
            false => idle_after_end,
            true => Duration::from_millis(300) + Duration::from_nanos(period_ns * 4),
        };
        let all_in = ended.as_ref().is_some_and(|e| {
            aborted
                && received.frames.len() >= usize::from(e.completed)
                && last_frame.elapsed() > Duration::from_nanos(period_ns)
        });
        if ended.is_some() && (complete || all_in || last_frame.elapsed() > idle) {
            break;
        }
        if failure.is_some() {
            // Frames already on their way still count.
            std::thread::sleep(Duration::from_millis(300));
            while let Ok(f) = drain.rx.try_recv() {
                received.arrive(f, since_start(), &mut labeller, &mut on_news);
            }
            break;
        }
        if ended.is_none()
            && start.elapsed()
                > Duration::from_nanos(period_ns * (n as u64 + 50)) + Duration::from_secs(30)
        {
            bail!("the capture sequence did not end in time");
        }
    }
    drop(drain);
    let seconds = start.elapsed().as_secs_f64();
    if waiting.is_some() {
        on_news(News::Labelling(None));
    }
    let Labelled {
        pairing: p,
        matched,
        late,
        relabelled,
    } = labeller.finish();
    match &p.clock_problem {
        // A sequence cut short by a cancel or a pause may hold too few frames to tell
        // its clock offset (a handful of periodic steps): its LEDs are left missing,
        // as a dropped frame's are, and what earlier sequences took is kept.
        Some(problem) if aborted => tracing::warn!(
            "the {} frames of the sequence cut short could not be labelled ({problem}): their LEDs are left missing",
            received.frames.len()
        ),
        Some(problem) => bail!(
            "none of the {} frames could be labelled with its LED: {problem}; is the camera triggered by the controller's trigger-out, and its clock steady?",
            received.frames.len()
        ),
        None => {}
    }
    // Every labelled frame reaches the stream once: those not handed out while
    // acquiring go now, with their final label.
    for l in &late {
        received.label(l, since_start(), &mut on_news);
    }
    let lags = received.lags_ms(&matched);
    let quantile = |q: f64| match lags.len() {
        0 => 0.0,
        n => lags[((n - 1) as f64 * q).round() as usize],
    };
    let mut frames: Vec<Option<StepFrame>> = (0..n).map(|_| None).collect();
    for &(step, fi) in &matched {
        if let Some(slot) = frames.get_mut(step) {
            let (header, pixels) = &mut received.frames[fi];
            *slot = Some((*header, std::mem::take(pixels)));
        }
    }
    let labelled = frames.iter().filter(|f| f.is_some()).count();
    let report = CaptureReport {
        requested: n,
        labelled,
        missing: vec![],
        extra_frames: p.extra_frames.len(),
        ambiguous_frames: p.ambiguous_frames.len(),
        clock_offset_ns: p.clock_offset_ns,
        clock_drift_ppm: p.clock_drift_ppm,
        stamp_spread_ms: p.residual_spread_ns as f64 / 1e6,
        clock_problem: p.clock_problem.clone(),
        seconds,
        frames_per_s: labelled as f64 / seconds.max(1e-9),
        relabelled,
        outcome: match (&failure, ended.map(|e| e.outcome)) {
            (Some(f), _) => f.clone(),
            (None, Some(SequenceOutcome::Done)) => "done".into(),
            (None, Some(other)) => format!("{other:?}"),
            (None, None) => "no end of sequence".into(),
        },
        failed: failure.is_some(),
        sequences: 1,
        labelled_live: live.min(labelled),
        arrived_live,
        label_lag_p50_ms: quantile(0.5),
        label_lag_p99_ms: quantile(0.99),
        leds_off_at,
        cancel_to_leds_off_ms: None,
    };
    Ok((frames, report))
}

/// Give the labeller the controller's step reports waiting now; the end of the sequence
/// when it came.
fn next_event(
    events: &mut SequenceEvents,
    labeller: &mut Labeller,
    since_start: impl Fn() -> i64,
    on_news: &mut impl FnMut(News<'_>),
) -> Result<Option<SequenceEnd>, ControllerError> {
    loop {
        match events.next(Duration::from_millis(1)) {
            // The report is sent when the step ends: its trigger was that much earlier
            // (device time), and that is what a frame's arrival is compared with.
            Ok(SequenceEvent::End(e)) => return Ok(Some(e)),
            Ok(step) => {
                if let Some((_, index, trigger_us, end_us)) = step.step_times() {
                    let step = StepTime {
                        step: index as usize,
                        trigger_ns: trigger_us * 1000,
                    };
                    let arrived_ns =
                        since_start() - (end_us.saturating_sub(trigger_us) * 1000) as i64;
                    labeller.step(step, arrived_ns);
                    on_news(News::Step { step, arrived_ns });
                }
            }
            Err(ControllerError::Timeout { .. }) => return Ok(None),
            Err(e) => return Err(e),
        }
    }
}

/// The frames that arrived, by index (as the labeller names them): each frame, when it
/// arrived and when its label was handed on (ns since the sequence was started: the
/// live figures).
#[derive(Default)]
struct Received {
    frames: Vec<StepFrame>,
    arrived_ns: Vec<i64>,
    labelled_ns: Vec<Option<i64>>,
}

impl Received {
    /// Arrival → label handed on, ms, over the frames the final pairing kept
    /// (`matched`: step, frame), sorted. The first frames' (they wait for the camera's
    /// clock to be fitted, and are the p99) go to the debug log, in arrival order, for
    /// whoever tunes the labeller.
    fn lags_ms(&self, matched: &[(usize, usize)]) -> Vec<f64> {
        let lag = |fi: usize| {
            Some((self.labelled_ns.get(fi).copied()?? - *self.arrived_ns.get(fi)?) as f64 / 1e6)
        };
        let mut lags: Vec<f64> = matched.iter().filter_map(|&(_, fi)| lag(fi)).collect();
        lags.sort_by(f64::total_cmp);
        if tracing::enabled!(tracing::Level::DEBUG) {
            let first: Vec<String> = (0..self.arrived_ns.len().min(12))
                .map(|fi| lag(fi).map_or("-".into(), |ms| format!("{ms:.0}")))
                .collect();
            tracing::debug!("label lag of the first frames, ms: {}", first.join(" "));
        }
        lags
    }

    /// A frame taken off the camera at `at`: given to the labeller, told (before any
    /// label), kept.
    fn arrive(
        &mut self,
        (header, pixels): StepFrame,
        at: i64,
        labeller: &mut Labeller,
        on_news: &mut impl FnMut(News<'_>),
    ) {
        let index = labeller.frame(frame_time(&header), at);
        on_news(News::Arrived {
            index,
            arrived_ns: at,
            header: &header,
            pixels: pixels.view(),
        });
        self.arrived_ns.push(at);
        self.labelled_ns.push(None);
        self.frames.push((header, pixels));
    }

    /// Label `l` handed on at `at`.
    fn label(&mut self, l: &Label, at: i64, on_news: &mut impl FnMut(News<'_>)) {
        let (header, pixels) = &self.frames[l.frame];
        on_news(News::Labelled {
            step: l.step,
            index: l.frame,
            header,
            pixels: pixels.view(),
        });
        self.labelled_ns[l.frame] = Some(at);
    }
}

/// What the pairing needs of a frame's header.
fn frame_time(h: &FrameHeader) -> FrameTime {
    FrameTime {
        frame_number: h.frame_number,
        timestamp_ns: h.timestamp_ns,
    }
}
