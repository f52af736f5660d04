//! The virtual microscope's parts as separate processes: the emulated controller
//! publishing its light and trigger pulses on an iceoryx2 rig bus, the virtual camera
//! rendering each exposure with the wave-optics model and publishing frames, and the
//! host receiving them from shared memory while driving a real capture sequence.

use std::time::{Duration, Instant};

use fpm_acquire::controller::{Controller, SequenceEvent};
use fpm_frames::{FrameSubscriber, ServiceNames};
use fpm_protocol::*;
use fpm_rig::process::VirtualCameraProcess;
use fpm_rig_bus::{Stage, StageControl};
use fpm_tests::{fpm_bin, TempDir};

use crate::TARGET;

#[test]
fn triggered_exposures_arrive_as_frames_with_the_step_timestamps() {
    let id = format!("vb-{}-{:?}", std::process::id(), TARGET);
    let dir = TempDir::new("virtual-rig");
    let emu = TARGET.start(&dir.0.join("ctl.tty"), &["--rig", &id]);
    // The host's frame reader on its own thread (iceoryx2 ports stay on the thread that
    // made them), reading while the sequence runs: the service buffers only two frames.
    let names = ServiceNames::for_camera(&id);
    let (ready_tx, ready_rx) = std::sync::mpsc::channel();
    let reader = std::thread::spawn(move || {
        let frames = FrameSubscriber::create(&names).unwrap();
        ready_tx.send(()).unwrap();
        let mut got = vec![];
        let deadline = Instant::now() + Duration::from_secs(30);
        while got.len() < 4 && Instant::now() < deadline {
            if let Some(f) = frames.next(Duration::from_millis(200)).unwrap() {
                let mean =
                    f.pixels().iter().map(|&v| v as f64).sum::<f64>() / f.pixels().len() as f64;
                got.push((*f.header(), mean));
            }
        }
        got
    });
    ready_rx.recv().unwrap();
    let stage = StageControl::create(&id).unwrap();
    stage.set(Stage::default()).unwrap();
    // Ready once it has written its truth, which it does once it listens to the rig.
    let _camera = VirtualCameraProcess::start(
        fpm_bin(),
        &id,
        &id,
        &dir.0.join("truth"),
        &[
            "--size",
            "64",
            "--dx-mm",
            "0",
            "--dy-mm",
            "0",
            "--theta-deg",
            "0",
            "--height-mm",
            "92",
            "--readout-ms",
            "1",
        ],
    )
    .unwrap_or_else(|e| panic!("{e:#}"));

    let dev = Controller::open(&emu.port(), Duration::from_secs(2)).unwrap();
    // Centre, two bright-field neighbours, then one far dark-field LED.
    let leds = [(10, 10), (10, 11), (9, 10), (0, 0)];
    let steps: Vec<Step> = leds
        .iter()
        .map(|&(r, c)| Step {
            illumination: Illumination::Led(LedIndex::new(r, c)),
            color: Rgb::new(0, 0, 255),
        })
        .collect();
    let timing = SequenceTiming {
        settle_us: 300,
        exposure_us: 60_000,
        trigger_out: Some(TriggerOut {
            delay_us: 50,
            pulse_us: 100,
            polarity: Polarity::ActiveHigh,
        }),
        trigger_in: None,
        clear_at_end: true,
    };
    dev.upload_sequence(5, &steps, timing).unwrap();
    let mut events = dev.subscribe().unwrap();
    dev.start_sequence(5).unwrap();
    let mut triggers = vec![];
    loop {
        match events.next(Duration::from_secs(5)).expect("sequence event") {
            SequenceEvent::Step(s) => triggers.push(s.trigger_us),
            SequenceEvent::SetStep(s) => panic!("no LED set was uploaded: {s:?}"),
            SequenceEvent::End(e) => {
                assert_eq!(e.outcome, SequenceOutcome::Done);
                break;
            }
        }
    }
    let got = reader.join().unwrap();
    assert_eq!(got.len(), leds.len(), "one frame per trigger");
    for (k, ((h, _), trigger)) in got.iter().zip(&triggers).enumerate() {
        assert_eq!(h.frame_number, k as u64);
        assert_eq!((h.width, h.height, h.bit_depth), (64, 64, 12));
        let t = trigger * 1000;
        assert!(
            h.timestamp_ns.abs_diff(t) <= 200_000,
            "frame {k}: stamped {} ns, trigger at {t} ns",
            h.timestamp_ns
        );
    }
    // Per unit exposure, bright-field frames are far brighter than the dark-field one.
    let rate = |k: usize| (got[k].1 - 100.0) / got[k].0.exposure_us as f64;
    assert!(
        rate(0) > 20.0 * rate(3),
        "bright {} vs dark {}",
        rate(0),
        rate(3)
    );
    assert!(rate(1) > 20.0 * rate(3) && rate(2) > 20.0 * rate(3));
}
