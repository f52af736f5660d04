//! `fpm demo`: the virtual microscope, with no hardware. Today it runs the LED side of
//! an acquisition — an emulated controller process on a pseudo-terminal with an
//! emulated camera on its trigger lines — and reports what a real run would see.
//! The simulated camera, calibration and reconstruction join it as they land.

use std::time::{Duration, Instant};

use anyhow::{bail, Result};
use clap::Args;
use fpm_protocol::*;
use indicatif::{ProgressBar, ProgressStyle};

use crate::controller::scan::{scan_steps, Order, Selection};
use crate::controller::{Controller, SequenceEvent};
use crate::emulator_process::EmulatorProcess;

/// Run the virtual microscope.
#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Camera exposure per LED, µs.
    #[arg(long, default_value_t = 2_000)]
    exposure_us: u32,
    /// WS2812 data lanes on the emulated board (more lanes switch LEDs faster).
    #[arg(long, default_value_t = 1)]
    lanes: u8,
}

/// Run the demo.
pub fn run(a: DemoArgs) -> Result<()> {
    println!("fpm demo: a virtual FPM microscope, no hardware needed\n");
    let exposure = a.exposure_us.to_string();
    let lanes = a.lanes.to_string();
    let emulator = EmulatorProcess::start(&["--camera-exposure-us", &exposure, "--lanes", &lanes])?;
    let port = emulator.link.to_string_lossy().into_owned();
    let dev = Controller::open(&port, Duration::from_secs(2))?;
    let info = dev.info().clone();
    let g = info.geometry;
    println!(
        "LED controller  {} (emulated, separate process) on {port}\n                firmware {}, protocol {}, {}x{} LEDs at {:.1} mm pitch, {} lane(s)",
        info.board,
        info.firmware,
        info.protocol,
        g.rows,
        g.cols,
        g.pitch_um as f64 / 1000.0,
        g.lanes
    );

    // Patterns a microscopist uses, computed on the device from its geometry.
    let na = 0.1;
    let bf = dev.pattern(Pattern::BrightField { na }, Rgb::WHITE)?;
    let df = dev.pattern(Pattern::DarkField { na }, Rgb::new(2, 2, 2))?;
    let dpc = dev.pattern(
        Pattern::HalfCircle {
            na,
            half: Half::Left,
        },
        Rgb::WHITE,
    )?;
    dev.clear()?;
    println!(
        "patterns        objective NA {na}: bright-field {} LEDs ({} mA), dark-field {} LEDs, DPC half {} LEDs",
        bf.leds_on, bf.current_ma, df.leds_on, dpc.leds_on
    );

    // The capture sequence of an FPM acquisition: every LED, nearest-first, each step
    // ended by the camera's exposure signal on the trigger input.
    let steps = scan_steps(&g, Selection::All, Order::Nearest, Rgb::new(0, 0, 255));
    let timing = SequenceTiming {
        settle_us: 200,
        exposure_us: a.exposure_us,
        trigger_out: Some(TriggerOut {
            delay_us: 0,
            pulse_us: 100,
            polarity: Polarity::ActiveHigh,
        }),
        trigger_in: Some(TriggerIn {
            edge: Edge::Falling,
            timeout_us: 1_000_000,
        }),
        clear_at_end: true,
    };
    let upload_start = Instant::now();
    dev.upload_sequence(1, &steps, timing)?;
    let upload = upload_start.elapsed();
    let mut events = dev.subscribe()?;
    let started = dev.start_sequence(1)?;
    let bar = ProgressBar::new(steps.len() as u64).with_style(
        ProgressStyle::with_template("scan            [{bar:40}] {pos}/{len} LEDs {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let wall = Instant::now();
    let mut switch_us = Vec::with_capacity(steps.len());
    let mut prev_end = started.started_us;
    let end = loop {
        match events.next(Duration::from_secs(5))? {
            SequenceEvent::Step(s) => {
                switch_us.push((s.light_on_us - prev_end) as f64);
                prev_end = s.end_us;
                bar.inc(1);
            }
            SequenceEvent::End(e) => break e,
        }
    };
    bar.finish_and_clear();
    let wall = wall.elapsed();
    if end.outcome != SequenceOutcome::Done {
        bail!(
            "the scan ended with {:?} after {} steps",
            end.outcome,
            end.completed
        );
    }
    let device_s = (end.end_us - started.started_us) as f64 * 1e-6;
    let full_chain_us = (g.led_count() as f64 * info.limits.led_shift_ns as f64 / 1000.0)
        / g.lanes.max(1) as f64
        + info.limits.latch_us as f64;
    let switch = super::bench::Percentiles::of(&mut switch_us);
    println!(
        "scan            {} LEDs nearest-first with camera trigger-in: {:.2} s device time, {:.2} s wall ({:.1} frames/s)",
        end.completed,
        device_s,
        wall.as_secs_f64(),
        end.completed as f64 / device_s
    );
    println!(
        "LED switching   p50 {:.2} ms, mean {:.2} ms per step: data shifted only up to the furthest changed LED\n                (a full-chain update takes {:.2} ms; the emulator's wake-up latency is included)",
        switch.p50_us / 1e3,
        switch.mean_us / 1e3,
        full_chain_us / 1e3
    );
    println!(
        "upload          {} steps in {:.1} ms",
        steps.len(),
        upload.as_secs_f64() * 1e3
    );

    for i in 0..50u32 {
        dev.ping(i)?; // warm-up
    }
    let mut rtt = Vec::with_capacity(500);
    for i in 0..500u32 {
        let t = Instant::now();
        dev.ping(i)?;
        rtt.push(t.elapsed().as_secs_f64() * 1e6);
    }
    let rtt = super::bench::Percentiles::of(&mut rtt);
    println!(
        "link            request round-trip p50 {:.0} µs, p99 {:.0} µs (500 pings)",
        rtt.p50_us, rtt.p99_us
    );
    let link = dev.status()?.link;
    println!(
        "                {} frames, {} dropped, {} unknown keys, {} decode errors",
        link.frames_ok, link.frames_dropped, link.unknown_keys, link.decode_errors
    );
    drop(events);
    drop(dev);
    drop(emulator);
    println!("\nthe emulator has stopped; run `fpm emulator --link /tmp/fpm.tty` to keep one up and drive it with `fpm device --port /tmp/fpm.tty …`");
    Ok(())
}
