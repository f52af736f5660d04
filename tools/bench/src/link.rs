//! `fpm bench link`: request round-trips over the serial link (ping, a 441-LED pattern).

use std::time::{Duration, Instant};

use anyhow::Result;
use fpm_acquire::controller::Controller;
use fpm_protocol::{Pattern, Rgb};
use fpm_rig::process::EmulatorProcess;
use serde::Serialize;

use crate::{LinkOptions, Percentiles};

#[derive(Serialize)]
struct LinkReport {
    port: String,
    emulated: bool,
    ping: Percentiles,
    pattern_all_441: Percentiles,
    pattern_leds_on: u16,
}

pub fn run(a: LinkOptions) -> Result<()> {
    let emulator = match &a.port {
        Some(_) => None,
        None => Some(EmulatorProcess::start(&[])?),
    };
    let port = match (&a.port, &emulator) {
        (Some(p), _) => p.clone(),
        (None, Some(e)) => e.link.to_string_lossy().into_owned(),
        (None, None) => unreachable!("an emulator is started when no port is given"),
    };
    let dev = Controller::open(&port, Duration::from_secs(2))?;
    let count = a.count.max(10);

    // Warm up both paths, then measure.
    let mut ping = dev.ping_round_trips(50, count as u32)?;
    // Every LED lit, dim enough to stay within any budget the board may have.
    let all = Pattern::All;
    let dim = Rgb::new(4, 4, 4);
    let mut pattern = Vec::with_capacity(count);
    let mut leds_on = 0;
    for i in 0..count {
        // Alternate colours so every request really changes all 441 LEDs.
        let color = if i % 2 == 0 { dim } else { Rgb::new(5, 5, 5) };
        let t = Instant::now();
        leds_on = dev.pattern(all, color)?.leds_on;
        pattern.push(t.elapsed().as_secs_f64() * 1e6);
    }
    dev.clear()?;
    let report = LinkReport {
        port,
        emulated: emulator.is_some(),
        ping: Percentiles::of(&mut ping),
        pattern_all_441: Percentiles::of(&mut pattern),
        pattern_leds_on: leds_on,
    };
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!(
            "request round-trip over {} ({}), {} requests each:",
            report.port,
            if report.emulated {
                "emulator on a pseudo-terminal"
            } else {
                "device"
            },
            count
        );
        for (name, p) in [
            ("ping", &report.ping),
            ("pattern, all LEDs", &report.pattern_all_441),
        ] {
            println!(
                "  {name:<18} p50 {:>7.1} µs   p99 {:>7.1} µs   max {:>8.1} µs   mean {:>7.1} µs",
                p.p50_us, p.p99_us, p.max_us, p.mean_us
            );
        }
        println!(
            "  (the pattern lit {} LEDs each time)",
            report.pattern_leds_on
        );
    }
    Ok(())
}
