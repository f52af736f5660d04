//! The controller logic driven through its real wire format, on the host.

mod common;

use common::*;
use fpm_firmware::chain::chain_index;
use fpm_firmware::patterns;
use fpm_firmware::sequence::trigger_dither_us;
use fpm_protocol::*;
use postcard_rpc::header::{VarHeader, VarKey, VarSeq};
use postcard_rpc::standard_icd::{PingEndpoint, WireError};

const T0: u64 = 1_000_000;

fn board() -> BoardGeometry {
    fpm_firmware::BoardConfig::PICO_21X21.geometry
}

#[test]
fn identity_and_ping() {
    let mut dev = device();
    assert_eq!(ok::<VersionEndpoint>(&mut dev, &(), T0), PROTOCOL_VERSION);
    assert_eq!(ok::<PingEndpoint>(&mut dev, &0xDEAD_BEEF, T0), 0xDEAD_BEEF);
    let info = ok::<InfoEndpoint>(&mut dev, &(), T0);
    assert_eq!(info.geometry, board());
    assert_eq!(info.geometry.led_count(), 441);
    assert_eq!(info.serial, 42);
    assert_eq!(info.limits.max_current_ma, 4000);
    assert_eq!(info.firmware.to_string(), env!("CARGO_PKG_VERSION"));
}

#[test]
fn one_led_lights_exactly_that_led_and_shifts_only_that_far() {
    let mut dev = device();
    let led = LedIndex::new(3, 5);
    let color = Rgb::new(0, 0, 200);
    let lit = ok::<SetLedEndpoint>(&mut dev, &SetLed { led, color }, T0).unwrap();
    let index = chain_index(&board(), led).unwrap() as usize;
    assert_eq!(lit.leds_on, 1);
    assert_eq!(
        lit.current_ma,
        (200u32 * 20_000).div_ceil(255).div_ceil(1000)
    );
    assert_eq!(lit.latched_us, T0 + (index as u64 + 1) * 30 + 280);
    let strip = dev.strip();
    assert_eq!(strip.writes.last().unwrap(), &vec![index as u16 + 1]);
    for (i, px) in strip.pixels.iter().enumerate() {
        assert_eq!(
            *px,
            if i == index { color } else { Rgb::OFF },
            "chain position {i}"
        );
    }
    // The next LED replaces it: both positions must be shifted.
    let led2 = LedIndex::new(0, 0);
    ok::<SetLedEndpoint>(&mut dev, &SetLed { led: led2, color }, T0).unwrap();
    assert_eq!(dev.strip().writes.last().unwrap(), &vec![index as u16 + 1]);
    assert_eq!(dev.strip().pixels.iter().filter(|p| !p.is_off()).count(), 1);
    assert_eq!(dev.strip().pixels[0], color);
}

#[test]
fn leds_off_the_board_are_refused_and_nothing_changes() {
    let mut dev = device();
    ok::<SetLedEndpoint>(
        &mut dev,
        &SetLed {
            led: LedIndex::new(1, 1),
            color: Rgb::WHITE,
        },
        T0,
    )
    .unwrap();
    let writes = dev.strip().writes.len();
    let err = ok::<SetLedEndpoint>(
        &mut dev,
        &SetLed {
            led: LedIndex::new(21, 0),
            color: Rgb::WHITE,
        },
        T0,
    );
    assert_eq!(err, Err(DeviceError::BadLed { row: 21, col: 0 }));
    let mut leds = heapless::Vec::new();
    leds.push(LedIndex::new(0, 0)).unwrap();
    leds.push(LedIndex::new(0, 200)).unwrap();
    let err = ok::<SetLedsEndpoint>(
        &mut dev,
        &SetLeds {
            leds,
            color: Rgb::WHITE,
            keep_others: false,
        },
        T0,
    );
    assert_eq!(err, Err(DeviceError::BadLed { row: 0, col: 200 }));
    assert_eq!(dev.strip().writes.len(), writes);
    assert_eq!(ok::<StatusEndpoint>(&mut dev, &(), T0).leds_on, 1);
}

#[test]
fn a_list_adds_or_replaces() {
    let mut dev = device();
    ok::<SetLedEndpoint>(
        &mut dev,
        &SetLed {
            led: LedIndex::new(10, 10),
            color: Rgb::WHITE,
        },
        T0,
    )
    .unwrap();
    let mut leds = heapless::Vec::new();
    for c in 0..5 {
        leds.push(LedIndex::new(2, c)).unwrap();
    }
    leds.push(LedIndex::new(2, 0)).unwrap(); // duplicate
    let lit = ok::<SetLedsEndpoint>(
        &mut dev,
        &SetLeds {
            leds: leds.clone(),
            color: Rgb::new(255, 0, 0),
            keep_others: true,
        },
        T0,
    )
    .unwrap();
    assert_eq!(lit.leds_on, 6);
    let lit = ok::<SetLedsEndpoint>(
        &mut dev,
        &SetLeds {
            leds,
            color: Rgb::new(255, 0, 0),
            keep_others: false,
        },
        T0,
    )
    .unwrap();
    assert_eq!(lit.leds_on, 5);
    let lit = ok::<ClearEndpoint>(&mut dev, &(), T0).unwrap();
    assert_eq!(lit.leds_on, 0);
    assert!(dev.strip().pixels.iter().all(|p| p.is_off()));
}

#[test]
fn patterns_light_what_the_geometry_says() {
    let mut dev = device();
    let g = board();
    for pattern in [
        Pattern::BrightField { na: 0.1 },
        Pattern::DarkField { na: 0.2 },
        Pattern::Annulus {
            inner: 0.1,
            outer: 0.2,
        },
        Pattern::HalfCircle {
            na: 0.15,
            half: Half::Left,
        },
    ] {
        let color = Rgb::new(0, 40, 0);
        let lit = ok::<PatternEndpoint>(&mut dev, &PatternRequest { pattern, color }, T0).unwrap();
        let mut expected = 0;
        for r in 0..21 {
            for c in 0..21 {
                let led = LedIndex::new(r, c);
                let on = patterns::contains(&g, &pattern, led);
                expected += on as u16;
                let px = dev.strip().pixels[chain_index(&g, led).unwrap() as usize];
                assert_eq!(
                    px,
                    if on { color } else { Rgb::OFF },
                    "{pattern:?} at {led:?}"
                );
            }
        }
        assert_eq!(lit.leds_on, expected, "{pattern:?}");
        assert!(expected > 0);
    }
    let bad = ok::<PatternEndpoint>(
        &mut dev,
        &PatternRequest {
            pattern: Pattern::BrightField { na: 2.0 },
            color: Rgb::WHITE,
        },
        T0,
    );
    assert_eq!(bad, Err(DeviceError::BadParam(Param::Na)));
}

#[test]
fn the_budget_refuses_or_scales_and_is_never_exceeded() {
    let mut dev = device();
    let all_white = PatternRequest {
        pattern: Pattern::All,
        color: Rgb::WHITE,
    };
    let refused = ok::<PatternEndpoint>(&mut dev, &all_white, T0);
    assert_eq!(
        refused,
        Err(DeviceError::OverBudget {
            required_ma: 441 * 60,
            limit_ma: 4000,
            step: None
        })
    );
    assert!(
        dev.strip().writes.is_empty(),
        "nothing may be shifted out when refused"
    );

    let scale = BudgetConfig {
        limit_ma: 2000,
        policy: BudgetPolicy::Scale,
    };
    assert_eq!(ok::<BudgetEndpoint>(&mut dev, &scale, T0), Ok(scale));
    let lit = ok::<PatternEndpoint>(&mut dev, &all_white, T0).unwrap();
    assert!(lit.scaled);
    assert!(lit.current_ma <= 2000, "{lit:?}");
    assert!(
        lit.current_ma > 1900,
        "scaled no further than needed: {lit:?}"
    );
    assert_eq!(lit.leds_on, 441);

    // Raising the budget above the supply's rating is refused.
    let too_much = BudgetConfig {
        limit_ma: 5000,
        policy: BudgetPolicy::Refuse,
    };
    assert_eq!(
        ok::<BudgetEndpoint>(&mut dev, &too_much, T0),
        Err(DeviceError::TooMany {
            requested: 5000,
            max: 4000
        })
    );
    // Lowering it dims what is lit at once.
    let low = BudgetConfig {
        limit_ma: 500,
        policy: BudgetPolicy::Refuse,
    };
    ok::<BudgetEndpoint>(&mut dev, &low, T0).unwrap();
    let status = ok::<StatusEndpoint>(&mut dev, &(), T0);
    assert!(status.current_ma <= 500, "{status:?}");
    // And brightness cannot push it back over.
    let r = ok::<BrightnessEndpoint>(&mut dev, &255, T0);
    assert!(
        matches!(r, Err(DeviceError::OverBudget { limit_ma: 500, .. })),
        "{r:?}"
    );
}

#[test]
fn brightness_dims_every_channel() {
    let mut dev = device();
    ok::<SetLedEndpoint>(
        &mut dev,
        &SetLed {
            led: LedIndex::new(0, 0),
            color: Rgb::new(200, 100, 50),
        },
        T0,
    )
    .unwrap();
    let lit = ok::<BrightnessEndpoint>(&mut dev, &128, T0).unwrap();
    assert_eq!(lit.brightness, 128);
    assert_eq!(dev.strip().pixels[0], Rgb::new(100, 50, 25));
}

fn timing(trigger_in: Option<TriggerIn>) -> SequenceTiming {
    SequenceTiming {
        settle_us: 1000,
        exposure_us: 5000,
        trigger_out: Some(TriggerOut {
            delay_us: 100,
            pulse_us: 200,
            polarity: Polarity::ActiveLow,
        }),
        trigger_in,
        clear_at_end: true,
    }
}

fn upload(dev: &mut Dev, id: u32, steps: &[Step], timing: SequenceTiming) {
    ok::<SequenceDefineEndpoint>(
        dev,
        &SequenceDefine {
            id,
            steps: steps.len() as u16,
            timing,
        },
        T0,
    )
    .unwrap();
    for (k, chunk) in steps.chunks(limits::MAX_STEPS_PER_CHUNK).enumerate() {
        let c = StepChunk {
            id,
            offset: (k * limits::MAX_STEPS_PER_CHUNK) as u16,
            steps: heapless::Vec::from_slice(chunk).unwrap(),
        };
        ok::<SequenceStepsEndpoint>(dev, &c, T0).unwrap();
    }
}

fn led_steps(n: usize) -> Vec<Step> {
    (0..n)
        .map(|i| Step {
            illumination: Illumination::Led(LedIndex::new((i / 21) as u8, (i % 21) as u8)),
            color: Rgb::WHITE,
        })
        .collect()
}

#[test]
fn a_sequence_runs_with_exact_timing_and_reports_every_step() {
    let mut dev = device();
    let steps = led_steps(30);
    upload(&mut dev, 9, &steps, timing(None));
    let started = ok::<SequenceStartEndpoint>(&mut dev, &9, T0).unwrap();
    assert_eq!(started.steps, 30);
    // Each step after the first settles its dither longer (the steps' timing is a
    // fingerprint the host's labeller checks the camera's stamps against).
    let dither: u64 = (0..30).map(trigger_dither_us).sum();
    assert_eq!(started.min_duration_us, 30 * (1000 + 100 + 5000) + dither);
    let frames = run_until(&mut dev, T0, T0 + 10_000_000);
    let events = topics::<StepTopic>(&frames);
    let ends = topics::<SequenceEndTopic>(&frames);
    assert_eq!(events.len(), 30);
    let mut prev_end = T0;
    let mut prev_index: Option<usize> = None;
    for (i, ev) in events.iter().enumerate() {
        assert_eq!(ev.step as usize, i);
        assert_eq!(ev.sequence_id, 9);
        assert_eq!(ev.illumination, steps[i].illumination);
        assert_eq!(ev.leds_on, 1);
        // Shift only as far as the furthest LED that changed (old off, new on).
        let Illumination::Led(led) = ev.illumination else {
            unreachable!()
        };
        let index = chain_index(&board(), led).unwrap() as usize;
        let furthest = prev_index.map_or(index, |p| p.max(index));
        assert_eq!(
            ev.light_on_us,
            prev_end + (furthest as u64 + 1) * 30 + 280,
            "step {i}"
        );
        assert_eq!(
            ev.trigger_us,
            ev.light_on_us + 1000 + trigger_dither_us(i as u16) + 100
        );
        assert_eq!(ev.end_us, ev.trigger_us + 5000);
        assert_eq!(ev.trigger_in_us, None);
        prev_end = ev.end_us;
        prev_index = Some(index);
    }
    assert_eq!(ends.len(), 1);
    assert_eq!(ends[0].outcome, SequenceOutcome::Done);
    assert_eq!(ends[0].completed, 30);
    assert_eq!(ends[0].end_us, prev_end);
    // Active-low trigger: idle high, one low pulse per step, idle high at the end.
    let levels = &dev.trigger().levels;
    let pulses = levels.windows(2).filter(|w| w[0] && !w[1]).count();
    assert_eq!(pulses, 30);
    assert_eq!(levels.last(), Some(&true));
    assert!(
        dev.strip().pixels.iter().all(|p| p.is_off()),
        "cleared at the end"
    );
    let status = ok::<SequenceStatusEndpoint>(&mut dev, &(), prev_end);
    assert_eq!(status.state, SequenceState::Ready);
    assert_eq!(status.completed, 30);
    assert_eq!(status.last_outcome, Some(SequenceOutcome::Done));
}

/// A strip whose shift runs later (a DMA task, as on the RP2040) reports when it
/// latched: a sequence step does not settle and trigger on the shift-time model but
/// from the reported time, however late it comes, and reports that as its light-on.
#[test]
fn a_step_waits_for_a_strip_that_latches_later() {
    let mut dev = device();
    dev.strip_mut().latches_later = true;
    upload(&mut dev, 5, &led_steps(2), timing(None));
    ok::<SequenceStartEndpoint>(&mut dev, &5, T0).unwrap();
    let mut wire = Wire::default();
    let next = dev.poll(T0, &mut |b: &[u8]| wire.bytes.extend_from_slice(b));
    // Written, not yet latched: no trigger pulse, only the report's grace deadline.
    assert_eq!(dev.strip().writes.len(), 1);
    let pulses = |dev: &Dev| {
        let levels = &dev.trigger().levels;
        levels.windows(2).filter(|w| w[0] && !w[1]).count()
    };
    assert_eq!(pulses(&dev), 0, "active-low trigger still idle");
    let model = T0 + 30 + 280;
    assert_eq!(next, Some(model + 100_000));
    // The shift really finished 2 ms late: settle and trigger delay count from there.
    let late = T0 + 2_000;
    let next = dev.strip_latched(late, late, &mut |b: &[u8]| wire.bytes.extend_from_slice(b));
    assert_eq!(next, Some(late + 1000 + 100));
    let frames = run_until(&mut dev, late, late + 50_000);
    let mut events = topics::<StepTopic>(&frames);
    let first = events.remove(0);
    assert_eq!(first.light_on_us, late);
    assert_eq!(first.trigger_us, late + 1000 + 100);
    // A shell that never reports does not hang the sequence: after the grace time the
    // model's latch is taken as now.
    let ends = topics::<SequenceEndTopic>(&frames);
    assert!(ends.is_empty(), "step 1 still waits for its report");
    let frames = run_until(&mut dev, late + 50_000, late + 1_000_000);
    let ends = topics::<SequenceEndTopic>(&frames);
    assert_eq!(ends.len(), 1);
    assert_eq!(ends[0].outcome, SequenceOutcome::Done);
}

#[test]
fn trigger_in_ends_each_step_at_the_camera_edge() {
    let mut dev = device();
    let steps = led_steps(5);
    upload(
        &mut dev,
        1,
        &steps,
        timing(Some(TriggerIn {
            edge: Edge::Falling,
            timeout_us: 50_000,
        })),
    );
    ok::<SequenceStartEndpoint>(&mut dev, &1, T0).unwrap();
    // Play the camera: 7 ms after each trigger pulse starts, a rising edge (ignored)
    // and then the falling edge the sequence waits for.
    let mut wire = Wire::default();
    let mut events = vec![];
    let mut ended = false;
    let mut next = Some(T0);
    let mut camera_edge: Option<u64> = None;
    let mut seen = dev.trigger().levels.len();
    for _ in 0..1000 {
        let now = match (next, camera_edge) {
            (Some(a), Some(b)) => a.min(b),
            (a, b) => a.or(b).expect("something is always due"),
        };
        let mut sink = |b: &[u8]| wire.bytes.extend_from_slice(b);
        if camera_edge == Some(now) {
            camera_edge = None;
            dev.trigger_edge(Edge::Rising, now - 10, now, &mut sink);
            next = dev.trigger_edge(Edge::Falling, now, now, &mut sink);
        } else {
            next = dev.poll(now, &mut sink);
        }
        let levels = &dev.trigger().levels;
        if levels[seen..].iter().any(|&high| !high) {
            camera_edge = Some(now + 7000);
        }
        seen = levels.len();
        let frames = wire.frames();
        events.extend(topics::<StepTopic>(&frames));
        if !topics::<SequenceEndTopic>(&frames).is_empty() {
            ended = true;
            break;
        }
    }
    assert!(ended);
    assert_eq!(events.len(), 5);
    for ev in &events {
        let edge = ev.trigger_in_us.expect("edge recorded");
        assert_eq!(edge, ev.trigger_us + 7000);
        assert_eq!(ev.end_us, edge);
    }
}

#[test]
fn a_missing_camera_edge_fails_the_sequence_with_the_step() {
    let mut dev = device();
    upload(
        &mut dev,
        2,
        &led_steps(3),
        timing(Some(TriggerIn {
            edge: Edge::Rising,
            timeout_us: 20_000,
        })),
    );
    ok::<SequenceStartEndpoint>(&mut dev, &2, T0).unwrap();
    let frames = run_until(&mut dev, T0, T0 + 1_000_000);
    assert!(topics::<StepTopic>(&frames).is_empty());
    let ends = topics::<SequenceEndTopic>(&frames);
    assert_eq!(ends.len(), 1);
    assert_eq!(
        ends[0].outcome,
        SequenceOutcome::Failed(DeviceError::TriggerTimeout { step: 0 })
    );
    assert_eq!(ends[0].completed, 0);
    assert!(dev.strip().pixels.iter().all(|p| p.is_off()));
    assert_eq!(
        dev.trigger().levels.last(),
        Some(&true),
        "active-low line back to idle"
    );
}

#[test]
fn while_running_only_status_and_abort_are_accepted() {
    let mut dev = device();
    upload(&mut dev, 3, &led_steps(100), timing(None));
    ok::<SequenceStartEndpoint>(&mut dev, &3, T0).unwrap();
    let frames = run_until(&mut dev, T0, T0 + 20_000);
    assert!(!topics::<StepTopic>(&frames).is_empty());
    let now = T0 + 20_000;
    assert_eq!(
        ok::<SetLedEndpoint>(
            &mut dev,
            &SetLed {
                led: LedIndex::new(0, 0),
                color: Rgb::WHITE
            },
            now
        ),
        Err(DeviceError::Busy)
    );
    assert_eq!(
        ok::<ClearEndpoint>(&mut dev, &(), now),
        Err(DeviceError::Busy)
    );
    assert_eq!(
        ok::<SequenceStartEndpoint>(&mut dev, &3, now),
        Err(DeviceError::Busy)
    );
    let def = SequenceDefine {
        id: 4,
        steps: 1,
        timing: timing(None),
    };
    assert_eq!(
        ok::<SequenceDefineEndpoint>(&mut dev, &def, now),
        Err(DeviceError::Busy)
    );
    assert_eq!(
        ok::<StatusEndpoint>(&mut dev, &(), now).sequence.state,
        SequenceState::Running
    );

    let (reply, frames) = call::<SequenceAbortEndpoint>(&mut dev, &(), now);
    let Reply::Ok(Ok(status)) = reply else {
        panic!("abort failed: {reply:?}")
    };
    assert_eq!(status.state, SequenceState::Ready);
    assert_eq!(status.last_outcome, Some(SequenceOutcome::Aborted));
    let ends = topics::<SequenceEndTopic>(&frames);
    assert_eq!(ends.len(), 1);
    assert_eq!(ends[0].outcome, SequenceOutcome::Aborted);
    assert!(dev.strip().pixels.iter().all(|p| p.is_off()));
    assert_eq!(
        ok::<SequenceAbortEndpoint>(&mut dev, &(), now),
        Err(DeviceError::NotRunning)
    );
    // It can run again.
    ok::<SequenceStartEndpoint>(&mut dev, &3, now).unwrap();
}

#[test]
fn uploads_are_checked() {
    let mut dev = device();
    let def = SequenceDefine {
        id: 5,
        steps: 4,
        timing: timing(None),
    };
    let chunk = |id, offset, steps: &[Step]| StepChunk {
        id,
        offset,
        steps: heapless::Vec::from_slice(steps).unwrap(),
    };
    // Before any define.
    assert_eq!(
        ok::<SequenceStepsEndpoint>(&mut dev, &chunk(5, 0, &led_steps(1)), T0),
        Err(DeviceError::WrongSequence {
            requested: 5,
            defined: 0
        })
    );
    ok::<SequenceDefineEndpoint>(&mut dev, &def, T0).unwrap();
    assert_eq!(
        ok::<SequenceStepsEndpoint>(&mut dev, &chunk(6, 0, &led_steps(1)), T0),
        Err(DeviceError::WrongSequence {
            requested: 6,
            defined: 5
        })
    );
    assert_eq!(
        ok::<SequenceStepsEndpoint>(&mut dev, &chunk(5, 1, &led_steps(1)), T0),
        Err(DeviceError::ChunkOutOfRange {
            offset: 1,
            len: 1,
            loaded: 0,
            total: 4
        })
    );
    assert_eq!(
        ok::<SequenceStepsEndpoint>(&mut dev, &chunk(5, 0, &led_steps(5)), T0),
        Err(DeviceError::ChunkOutOfRange {
            offset: 0,
            len: 5,
            loaded: 0,
            total: 4
        })
    );
    let bad = [Step {
        illumination: Illumination::Led(LedIndex::new(0, 30)),
        color: Rgb::WHITE,
    }];
    assert_eq!(
        ok::<SequenceStepsEndpoint>(&mut dev, &chunk(5, 0, &bad), T0),
        Err(DeviceError::BadLed { row: 0, col: 30 })
    );
    let greedy = [Step {
        illumination: Illumination::Pattern(Pattern::All),
        color: Rgb::WHITE,
    }];
    assert_eq!(
        ok::<SequenceStepsEndpoint>(&mut dev, &chunk(5, 0, &[led_steps(1)[0], greedy[0]]), T0),
        Err(DeviceError::OverBudget {
            required_ma: 441 * 60,
            limit_ma: 4000,
            step: Some(1)
        })
    );
    assert_eq!(
        ok::<SequenceStepsEndpoint>(&mut dev, &chunk(5, 0, &led_steps(2)), T0),
        Ok(StepsLoaded {
            loaded: 2,
            total: 4
        })
    );
    assert_eq!(
        ok::<SequenceStartEndpoint>(&mut dev, &5, T0),
        Err(DeviceError::Incomplete {
            loaded: 2,
            total: 4
        })
    );
    assert_eq!(
        ok::<SequenceStepsEndpoint>(&mut dev, &chunk(5, 2, &led_steps(2)), T0),
        Ok(StepsLoaded {
            loaded: 4,
            total: 4
        })
    );
    // Zero steps, zero pulse width and zero timeout are refused.
    let mut t = timing(None);
    assert_eq!(
        ok::<SequenceDefineEndpoint>(
            &mut dev,
            &SequenceDefine {
                id: 1,
                steps: 0,
                timing: t
            },
            T0
        ),
        Err(DeviceError::BadParam(Param::StepCount))
    );
    assert_eq!(
        ok::<SequenceDefineEndpoint>(
            &mut dev,
            &SequenceDefine {
                id: 1,
                steps: 2000,
                timing: t
            },
            T0
        ),
        Err(DeviceError::TooMany {
            requested: 2000,
            max: 1024
        })
    );
    t.trigger_out = Some(TriggerOut {
        delay_us: 0,
        pulse_us: 0,
        polarity: Polarity::ActiveHigh,
    });
    assert_eq!(
        ok::<SequenceDefineEndpoint>(
            &mut dev,
            &SequenceDefine {
                id: 1,
                steps: 1,
                timing: t
            },
            T0
        ),
        Err(DeviceError::BadParam(Param::PulseWidth))
    );
}

#[test]
fn protocol_errors_are_answered_and_counted() {
    let mut dev = device();
    // An unknown key (a peer built against a different schema).
    let hdr = VarHeader {
        key: VarKey::Key8(postcard_rpc::Key::for_path::<u64>("fpm/led/set")),
        seq_no: VarSeq::Seq4(3),
    };
    let mut raw = hdr.write_to_vec();
    raw.extend([1, 2, 3]);
    let mut wire = Wire::default();
    let mut frame = cobs::encode_vec(&raw);
    frame.push(0);
    dev.receive(&frame, T0, &mut |b: &[u8]| wire.bytes.extend_from_slice(b));
    let replies = wire.frames();
    assert_eq!(replies.len(), 1);
    assert_eq!(replies[0].0.seq_no, VarSeq::Seq4(3));
    let e: WireError = postcard::from_bytes(&replies[0].1).unwrap();
    assert_eq!(e, WireError::UnknownKey);

    // A known key with a truncated body, and one with trailing garbage.
    for body in [&[][..], &[0x01, 0x02][..]] {
        let hdr = VarHeader {
            key: VarKey::Key8(SetLedEndpoint::REQ_KEY),
            seq_no: VarSeq::Seq2(9),
        };
        let mut raw = hdr.write_to_vec();
        raw.extend(body);
        if body.len() == 2 {
            raw.clear();
            raw.extend(hdr.write_to_vec());
            raw.extend(
                postcard::to_stdvec(&SetLed {
                    led: LedIndex::new(0, 0),
                    color: Rgb::WHITE,
                })
                .unwrap(),
            );
            raw.push(0xAA);
        }
        let mut frame = cobs::encode_vec(&raw);
        frame.push(0);
        dev.receive(&frame, T0, &mut |b: &[u8]| wire.bytes.extend_from_slice(b));
        let replies = wire.frames();
        assert_eq!(replies.len(), 1);
        assert_eq!(replies[0].0.seq_no, VarSeq::Seq2(9));
        assert_eq!(
            postcard::from_bytes::<WireError>(&replies[0].1).unwrap(),
            WireError::DeserFailed
        );
    }
    assert!(
        dev.strip().writes.is_empty(),
        "a bad request lights nothing"
    );
    let stats = ok::<StatusEndpoint>(&mut dev, &(), T0).link;
    assert_eq!(stats.unknown_keys, 1);
    assert_eq!(stats.decode_errors, 2);
}

use postcard_rpc::Endpoint;

/// The reboot into BOOTSEL: refused while a sequence runs (a stray request must not
/// darken a capture), else answered, every LED written off, and the shell told; after
/// it the controller answers nothing (the next firmware will).
#[test]
fn bootsel_turns_every_led_off_then_leaves_the_restart_to_the_shell() {
    let mut dev = device();
    upload(&mut dev, 3, &led_steps(100), timing(None));
    ok::<SequenceStartEndpoint>(&mut dev, &3, T0).unwrap();
    run_until(&mut dev, T0, T0 + 20_000);
    let now = T0 + 20_000;
    assert_eq!(
        ok::<BootselEndpoint>(&mut dev, &(), now),
        Err(DeviceError::Busy)
    );
    assert!(!dev.bootsel_requested());
    ok::<SequenceAbortEndpoint>(&mut dev, &(), now).unwrap();

    let lit = SetLeds {
        leds: [LedIndex::new(10, 10), LedIndex::new(3, 4)]
            .into_iter()
            .collect(),
        color: Rgb::WHITE,
        keep_others: false,
    };
    ok::<SetLedsEndpoint>(&mut dev, &lit, now).unwrap();
    assert!(dev.current_ma() > 0);
    assert_eq!(ok::<BootselEndpoint>(&mut dev, &(), now), Ok(()));
    assert!(dev.bootsel_requested());
    assert_eq!(dev.current_ma(), 0);
    assert!(dev.strip().pixels.iter().all(|p| p.is_off()));
    let mut answered = vec![];
    let ping = encode_request::<PingEndpoint>(&1, 9);
    dev.receive(&ping, now, &mut |b: &[u8]| answered.extend_from_slice(b));
    assert!(answered.is_empty(), "answered after BOOTSEL: {answered:?}");
}
