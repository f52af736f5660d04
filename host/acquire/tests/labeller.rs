//! The labeller, driven synchronously through generated captures: arbitrary
//! interleavings of step reports and frames (frames late, dropped, doubled, reordered;
//! the camera's clock offset and drifting; the controller's clock running at any
//! steady rate against the host's, as an emulated RP2040's does) never pair a frame
//! with the wrong LED, neither while the capture runs nor in the final pairing; and a
//! clean capture is labelled whole.
//!
//! 10⁵ generated captures per run (`FPM_LABELLER_CASES` sets another count).

use fpm_acquire::label::{FrameTime, StepTime};
use fpm_acquire::labeller::Labeller;
use proptest::prelude::*;
use proptest::test_runner::{Config, RngAlgorithm, TestRng, TestRunner};
use rand::{Rng, SeedableRng};

/// One generated capture: how the rig behaves.
#[derive(Debug, Clone)]
struct Rig {
    steps: usize,
    /// Nominal step period (settle + exposure), controller µs; the labeller's tolerance
    /// is a third of it, as the capture sets it.
    period_us: u64,
    /// Each step is longer by up to this fraction of the period (the LED update down
    /// the chain, the trigger delay).
    irregular: f64,
    /// Host ns per controller ns: below 1 the controller's clock runs fast (an
    /// emulator's idle jumps), above 1 slow (an emulator at a fraction of real time).
    host_per_controller: f64,
    /// Camera clock minus controller clock, ns.
    camera_offset_ns: u64,
    camera_drift_ppm: f64,
    /// Exposure start after the trigger, in tolerances: drawn per frame from this range
    /// (the labeller's window is −1 … +2 tolerances; a camera is never early, but its
    /// stamp may be ahead by its own jitter). The range is at most 0.8 tolerances wide:
    /// the stamps' jitter well under the step (the capture's tolerance is a third of
    /// the exposure); wider, a periodic run with dropped frames has offsets that split
    /// the jitter between two steps and label as many frames.
    stamp_delay: (f64, f64),
    /// Frame reaches the host this many periods (host time) after its trigger, plus up
    /// to `arrival_spread` more: frames arrive late and out of order.
    arrival_delay: f64,
    arrival_spread: f64,
    /// Step report latency to the host, ns, up to this.
    report_latency_ns: u64,
    drop: f64,
    double: f64,
    /// The camera stops after this many frames (None: it doesn't).
    camera_stops: Option<usize>,
    /// Labels are asked for after an event with this probability.
    poll: f64,
    seed: u64,
}

impl Rig {
    fn clean(&self) -> bool {
        self.drop == 0.0
            && self.double == 0.0
            && self.camera_stops.is_none()
            && self.stamp_delay.0 >= 0.0
            && self.stamp_delay.1 <= 1.0
    }
}

fn rig() -> impl Strategy<Value = Rig> {
    let timing = (
        6usize..40,
        2_000u64..60_000,
        0.0..0.3f64,
        -1.3..1.3f64, // log10 of host ns per controller ns: 0.05 … 20
        0u64..10_000_000_000_000,
        -300.0..300.0f64,
    );
    let camera = (
        (-0.5..1.0f64, 0.0..0.8f64),
        0.0..3.0f64,
        prop_oneof![Just(0.0), 0.0..3.0f64],
        1_000u64..5_000_000,
    );
    let faults = (
        prop_oneof![3 => Just(0.0), 1 => 0.0..0.3f64],
        prop_oneof![3 => Just(0.0), 1 => 0.0..0.2f64],
        prop_oneof![4 => Just(None), 1 => (1usize..40).prop_map(Some)],
        0.05..1.0f64,
        any::<u64>(),
    );
    (timing, camera, faults).prop_map(
        |(
            (steps, period_us, irregular, log_rate, camera_offset_ns, camera_drift_ppm),
            ((from, width), arrival_delay, arrival_spread, report_latency_ns),
            (drop, double, camera_stops, poll, seed),
        )| Rig {
            steps,
            period_us,
            irregular,
            host_per_controller: 10f64.powf(log_rate),
            camera_offset_ns,
            camera_drift_ppm,
            stamp_delay: (from, from + width),
            arrival_delay,
            arrival_spread,
            report_latency_ns,
            drop,
            double,
            camera_stops,
            poll,
            seed,
        },
    )
}

/// What reaches the host, in the order it arrives.
#[derive(Debug, Clone, Copy)]
enum Event {
    Step(StepTime),
    /// A frame and the step that really lit it.
    Frame(FrameTime, Option<usize>),
}

/// The capture as the host sees it: events with their host arrival times, sorted.
fn events(r: &Rig) -> (Vec<(i64, Event)>, u64) {
    let mut rng = rand::rngs::StdRng::seed_from_u64(r.seed);
    let period_ns = r.period_us * 1000;
    let tolerance = (period_ns / 3).max(1);
    let first_trigger = 1_000_000_000_000u64 + rng.gen_range(0..1_000_000_000);
    let host_start = rng.gen_range(100_000..50_000_000) as f64;
    let host = |controller_ns: u64| {
        host_start + (controller_ns - first_trigger) as f64 * r.host_per_controller
    };
    let camera = |controller_ns: u64| {
        let t = controller_ns as f64;
        r.camera_offset_ns as f64 + t + r.camera_drift_ppm * 1e-6 * (t - first_trigger as f64)
    };
    let mut out = vec![];
    let mut trigger = first_trigger;
    let mut frame_number = 0u64;
    let mut last_step_arrival = 0i64;
    for step in 0..r.steps {
        if step > 0 {
            trigger += period_ns + (rng.gen::<f64>() * r.irregular * period_ns as f64) as u64;
        }
        let report = host(trigger) + rng.gen_range(0..=r.report_latency_ns) as f64;
        last_step_arrival = last_step_arrival.max(report as i64);
        out.push((
            last_step_arrival,
            Event::Step(StepTime {
                step,
                trigger_ns: trigger,
            }),
        ));
        let stopped = r.camera_stops.is_some_and(|n| frame_number as usize >= n);
        if stopped || rng.gen::<f64>() < r.drop {
            continue;
        }
        let delay = rng.gen_range(r.stamp_delay.0..=r.stamp_delay.1) * tolerance as f64;
        let stamp = camera(trigger) + delay;
        let frame = FrameTime {
            frame_number,
            timestamp_ns: stamp as u64,
        };
        frame_number += 1;
        let copies = if rng.gen::<f64>() < r.double { 2 } else { 1 };
        for _ in 0..copies {
            let late = r.arrival_delay + rng.gen::<f64>() * r.arrival_spread;
            let arrival =
                host(trigger) + (late * period_ns as f64 + delay.max(0.0)) * r.host_per_controller;
            out.push((arrival as i64 + 1, Event::Frame(frame, Some(step))));
        }
    }
    out.sort_by_key(|e| e.0);
    (out, tolerance)
}

/// Run the labeller over one capture; Err names the first wrong label.
fn check(r: &Rig) -> Result<(), TestCaseError> {
    let (events, tolerance) = events(r);
    let mut labeller = Labeller::new(r.steps, tolerance);
    let mut truth: Vec<Option<usize>> = vec![];
    let mut rng = rand::rngs::StdRng::seed_from_u64(r.seed ^ 0x9E37_79B9);
    let mut online = vec![];
    for (arrived, e) in &events {
        match *e {
            Event::Step(s) => labeller.step(s, *arrived),
            Event::Frame(f, step) => {
                labeller.frame(f, *arrived);
                truth.push(step);
            }
        }
        if rng.gen::<f64>() < r.poll {
            online.extend(labeller.labels());
        }
    }
    online.extend(labeller.labels());
    let done = labeller.finish();
    // A label handed out while capturing is provisional (it is given on the frames so
    // far): it is right, or the final pairing counts it as relabelled, and the capture
    // then reconstructs from the dataset instead of the stream.
    for l in &online {
        if truth[l.frame] != Some(l.step) {
            prop_assert!(
                done.relabelled > 0,
                "frame {} handed out as step {} while capturing (truth {:?}), relabelled {}",
                l.frame,
                l.step,
                truth[l.frame],
                done.relabelled
            );
        }
    }
    for &(step, frame) in &done.matched {
        prop_assert_eq!(
            truth[frame],
            Some(step),
            "frame {} finally paired with step {}",
            frame,
            step
        );
    }
    if r.clean() {
        prop_assert_eq!(done.relabelled, 0);
        prop_assert_eq!(
            done.matched.len(),
            r.steps,
            "a clean capture not labelled whole: {:?}",
            done.pairing.clock_problem
        );
    }
    Ok(())
}

#[test]
fn no_interleaving_pairs_a_frame_with_the_wrong_led() {
    let cases = std::env::var("FPM_LABELLER_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(100_000);
    let config = Config {
        cases,
        failure_persistence: None,
        ..Config::default()
    };
    // Seeded: a failure is reproduced by the same run (and shrunk to its smallest rig).
    let mut runner =
        TestRunner::new_with_rng(config, TestRng::deterministic_rng(RngAlgorithm::ChaCha));
    let result = runner.run(&rig(), |r| check(&r));
    if let Err(e) = result {
        panic!("{e}");
    }
}

/// A capture as the rigs we ship make them, for [`labels_come_out_while_frames_arrive`]:
/// the controller's steps lengthened by its trigger dither (up to 1 ms, as
/// `fpm_firmware::sequence::trigger_dither_us`) and by its LED update down the chain,
/// a triggered camera stamping the exposure's start (exactly, as the virtual camera
/// does, or with a hardware stamp's few µs of jitter), and the ways frames and reports
/// reach the host.
#[derive(Debug, Clone)]
struct LiveRig {
    steps: usize,
    /// Nominal step, controller µs (15 to 100 ms).
    period_us: u64,
    /// The LED update down the chain: each step up to this much longer, µs.
    chain_us: u64,
    /// Stamp jitter, ns (uniform, this wide).
    jitter_ns: u64,
    camera_offset_ns: u64,
    /// Up to ±1000 ppm.
    camera_drift_ppm: f64,
    /// Frames reach the host this many steps after their trigger (0: within the step,
    /// up to 3: a camera three steps behind), plus up to half a step at random.
    late_steps: f64,
    /// A camera slower than the steps (a virtual camera rendering on a busy machine):
    /// frame k is delivered no sooner than k · (1 + this) steps after the first
    /// trigger, so it falls further behind (0: it keeps up).
    falls_behind: f64,
    /// Step reports reach the host in batches of this many (USB CDC hands several
    /// over at once; 1: one by one).
    report_batch: usize,
    /// Frames lost at the start.
    lost_at_start: usize,
    /// Frames lost in the middle (by step index).
    lost_in_middle: Vec<usize>,
    seed: u64,
}

fn live_rig() -> impl Strategy<Value = LiveRig> {
    (
        (
            24usize..160,
            15_000u64..100_000,
            0u64..13_000,
            prop_oneof![Just(0u64), 0u64..20_000],
        ),
        (0u64..10_000_000_000_000, -1000.0..1000.0f64),
        (
            0.0..3.0f64,
            prop_oneof![3 => Just(0.0), 1 => 0.0..0.8f64],
            prop_oneof![2 => Just(1usize), 1 => 2usize..9],
        ),
        (
            prop_oneof![3 => Just(0usize), 1 => 1usize..4],
            prop::collection::vec(8usize..160, 0..3),
            any::<u64>(),
        ),
    )
        .prop_map(
            |(
                (steps, period_us, chain_us, jitter_ns),
                (camera_offset_ns, camera_drift_ppm),
                (late_steps, falls_behind, report_batch),
                (lost_at_start, lost_in_middle, seed),
            )| LiveRig {
                steps,
                period_us,
                chain_us,
                jitter_ns,
                camera_offset_ns,
                camera_drift_ppm,
                late_steps,
                falls_behind,
                report_batch,
                lost_at_start,
                lost_in_middle,
                seed,
            },
        )
}

/// The same dither as the firmware's (kept apart: the host must not need it).
fn dither_us(step: usize) -> u64 {
    if step == 0 {
        return 0;
    }
    let mut h = step as u32;
    h ^= h >> 16;
    h = h.wrapping_mul(0x85eb_ca6b);
    h ^= h >> 13;
    h = h.wrapping_mul(0xc2b2_ae35);
    h ^= h >> 16;
    u64::from(h) % 1024
}

/// The capture as the host sees it, in arrival order, and the labeller's tolerance (a
/// third of the step, as the capture sets it).
fn live_events(r: &LiveRig) -> (Vec<(i64, Event)>, u64) {
    let mut rng = rand::rngs::StdRng::seed_from_u64(r.seed);
    let period_ns = r.period_us * 1000;
    let first_trigger = 5_000_000_000u64 + rng.gen_range(0..1_000_000_000);
    // The host's clock: ns since the capture started, a little before the first trigger.
    let host = |controller_ns: u64| (controller_ns - first_trigger) as i64 + 2_000_000;
    let camera = |t: u64| {
        r.camera_offset_ns as f64
            + t as f64
            + r.camera_drift_ppm * 1e-6 * (t as f64 - first_trigger as f64)
    };
    let mut out = vec![];
    let mut trigger = first_trigger;
    let mut batch: Vec<StepTime> = vec![];
    for step in 0..r.steps {
        if step > 0 {
            trigger += period_ns + dither_us(step) * 1000 + rng.gen_range(0..=r.chain_us) * 1000;
        }
        batch.push(StepTime {
            step,
            trigger_ns: trigger,
        });
        // A step is reported when it ends; a batch when its last step has.
        if batch.len() == r.report_batch || step + 1 == r.steps {
            let at = host(trigger + period_ns);
            out.extend(batch.drain(..).map(|s| (at, Event::Step(s))));
        }
        // The camera counts every trigger, the frames it loses too.
        let number = step as u64;
        if step < r.lost_at_start || r.lost_in_middle.contains(&step) {
            continue;
        }
        let jitter = rng.gen_range(0..=r.jitter_ns) as f64;
        let frame = FrameTime {
            frame_number: number,
            timestamp_ns: (camera(trigger) + jitter) as u64,
        };
        let late = r.late_steps + rng.gen::<f64>() * 0.5;
        let behind =
            host(first_trigger) + (step as f64 * (1.0 + r.falls_behind) * period_ns as f64) as i64;
        let arrival = (host(trigger) + ((0.7 + late) * period_ns as f64) as i64).max(behind);
        out.push((arrival, Event::Frame(frame, Some(step))));
    }
    // Frames come in the order the camera took them (one stream); reports likewise.
    out.sort_by_key(|e| e.0);
    (out, period_ns / 3)
}

/// On every configuration we ship, labels come out while the capture runs: after the
/// first frames that fit the camera's clock, each frame is labelled within a few steps
/// of its arrival, not when the sequence ends: with frames arriving up to 3 steps late,
/// step reports in batches, camera clocks drifting up to 1000 ppm, and frames lost at
/// the start and in the middle. And no frame is labelled wrongly, online or finally,
/// nor relabelled (issue 61).
#[test]
fn labels_come_out_while_frames_arrive() {
    let cases = std::env::var("FPM_LABELLER_LIVE_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1_500);
    let config = Config {
        cases,
        failure_persistence: None,
        ..Config::default()
    };
    let mut runner =
        TestRunner::new_with_rng(config, TestRng::deterministic_rng(RngAlgorithm::ChaCha));
    let result = runner.run(&live_rig(), |r| {
        let (events, tolerance) = live_events(&r);
        let mut labeller = Labeller::new(r.steps, tolerance);
        let mut truth: Vec<Option<usize>> = vec![];
        // When each frame arrived, and when it was labelled (host ns).
        let mut arrived_at: Vec<i64> = vec![];
        let mut labelled_at: Vec<Option<i64>> = vec![];
        let last_frame = events
            .iter()
            .filter(|e| matches!(e.1, Event::Frame(..)))
            .map(|e| e.0)
            .max()
            .unwrap_or(0);
        for (arrived, e) in &events {
            match *e {
                // As the capture does: a report's arrival less the device time from the
                // trigger to the report (a step: the report is sent when it ends).
                Event::Step(s) => labeller.step(s, *arrived - (r.period_us * 1000) as i64),
                Event::Frame(f, step) => {
                    labeller.frame(f, *arrived);
                    truth.push(step);
                    arrived_at.push(*arrived);
                    labelled_at.push(None);
                }
            }
            for l in labeller.labels() {
                prop_assert_eq!(
                    truth[l.frame],
                    Some(l.step),
                    "frame {} labelled step {} while the capture ran",
                    l.frame,
                    l.step
                );
                labelled_at[l.frame] = Some(*arrived);
            }
        }
        let received = truth.len();
        let done = labeller.finish();
        prop_assert_eq!(done.relabelled, 0);
        for &(step, frame) in &done.matched {
            prop_assert_eq!(truth[frame], Some(step));
        }
        prop_assert_eq!(
            done.matched.len(),
            received,
            "{:?}",
            done.pairing.clock_problem
        );
        // Live: all but the first frames (the clock is fitted from 8, more when frames
        // were lost at the start) and the last few are labelled before the last frame
        // arrives, each within a few steps of the moment it could be: a frame waits for
        // a later one to close its step's window (frames come in order: until the next
        // arrives, a second frame of its step may still come), so its wait is counted
        // from its own arrival or the next frame's, whichever is later, and for its
        // step's report (batched reports: a few steps more). Counted from its own
        // arrival, a frame whose next frames were lost, from a camera falling behind,
        // looked slow at 5·10⁴ cases while the labeller could not have known sooner.
        let period = (r.period_us * 1000) as i64;
        let allowed = (r.report_batch as i64 + 3) * period;
        let live = (0..received)
            .filter(|&k| labelled_at[k].is_some_and(|t| t < last_frame))
            .count();
        let could_label_at = |k: usize| {
            let next = arrived_at.get(k + 1).copied().unwrap_or(i64::MAX);
            arrived_at[k].max(next)
        };
        let slow: Vec<usize> = (12..received)
            .filter(|&k| labelled_at[k].is_none_or(|t| t - could_label_at(k) > allowed))
            .filter(|&k| could_label_at(k) < last_frame - allowed)
            .collect();
        prop_assert!(
            slow.is_empty(),
            "{} of {received} frames labelled live; frames {slow:?} waited more than {} steps",
            live,
            r.report_batch + 3
        );
        Ok(())
    });
    if let Err(e) = result {
        panic!("{e}");
    }
}
