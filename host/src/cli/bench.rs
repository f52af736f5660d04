//! `fpm bench …`: performance measurements reported as percentiles, with the
//! conditions they were measured under.

use std::time::{Duration, Instant};

use anyhow::Result;
use clap::{Args, Subcommand};
use fpm_protocol::{Pattern, Rgb};
use serde::Serialize;

use crate::controller::scan::{scan_steps, Order, Selection};
use crate::controller::Controller;
use crate::emulator_process::EmulatorProcess;

#[derive(Subcommand, Debug)]
pub enum BenchCommand {
    /// Request round-trip over the serial link: ping and a 441-LED pattern.
    Link(LinkArgs),
    /// LED switch time of single-LED scans (the firmware's chain model): full chain
    /// versus partial shifts, for 1, 2 and 4 data lanes.
    LedSwitch {
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
}

#[derive(Args, Debug)]
pub struct LinkArgs {
    /// Controller port; without it an emulator is started on a pseudo-terminal.
    #[arg(long)]
    port: Option<String>,
    /// Requests per measurement.
    #[arg(long, default_value_t = 2000)]
    count: usize,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

/// Latency percentiles of a set of samples.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Percentiles {
    /// Number of samples.
    pub count: usize,
    /// Median, µs.
    pub p50_us: f64,
    /// 99th percentile, µs.
    pub p99_us: f64,
    /// Largest, µs.
    pub max_us: f64,
    /// Mean, µs.
    pub mean_us: f64,
}

impl Percentiles {
    /// Summarise samples in µs (sorts them).
    pub fn of(samples: &mut [f64]) -> Self {
        samples.sort_by(|a, b| a.total_cmp(b));
        let n = samples.len();
        let at = |q: f64| -> f64 {
            if n == 0 {
                return f64::NAN;
            }
            samples[((q * n as f64).ceil() as usize).clamp(1, n) - 1]
        };
        Self {
            count: n,
            p50_us: at(0.5),
            p99_us: at(0.99),
            max_us: at(1.0),
            mean_us: if n == 0 {
                f64::NAN
            } else {
                samples.iter().sum::<f64>() / n as f64
            },
        }
    }
}

#[derive(Serialize)]
struct LinkReport {
    port: String,
    emulated: bool,
    ping: Percentiles,
    pattern_all_441: Percentiles,
    pattern_leds_on: u16,
}

/// Run one benchmark.
pub fn run(cmd: BenchCommand) -> Result<()> {
    match cmd {
        BenchCommand::Link(a) => link(a),
        BenchCommand::LedSwitch { json } => led_switch(json),
    }
}

fn link(a: LinkArgs) -> Result<()> {
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
    for i in 0..50 {
        dev.ping(i)?;
    }
    let mut ping = Vec::with_capacity(count);
    for i in 0..count {
        let t = Instant::now();
        dev.ping(i as u32)?;
        ping.push(t.elapsed().as_secs_f64() * 1e6);
    }
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

#[derive(Serialize)]
struct SwitchRow {
    order: Order,
    lanes: u8,
    full_chain_ms: f64,
    partial_mean_ms: f64,
    partial_p50_ms: f64,
    partial_max_ms: f64,
    scan_shift_s: f64,
}

/// Shift time of every step of a single-LED scan, computed with the firmware's own
/// partial-shift rule (up to the furthest changed LED per lane).
fn led_switch(json: bool) -> Result<()> {
    use fpm_firmware::chain::{chain_index, lane_len, shift_lengths, update_time_us};
    use fpm_protocol::Illumination;
    let board = fpm_firmware::BoardConfig::PICO_21X21;
    let mut rows = vec![];
    for order in [Order::Nearest, Order::Raster] {
        for lanes in [1u8, 2, 4] {
            let mut g = board.geometry;
            g.lanes = lanes;
            let n = g.led_count() as usize;
            let full =
                update_time_us(&[lane_len(&g) as u16], board.led_shift_ns, board.latch_us) as f64;
            let mut shown = vec![Rgb::OFF; n];
            let mut times = vec![];
            for step in scan_steps(&g, Selection::All, order, Rgb::WHITE) {
                let mut next = vec![Rgb::OFF; n];
                if let Illumination::Led(led) = step.illumination {
                    if let Some(i) = chain_index(&g, led) {
                        next[i as usize] = Rgb::WHITE;
                    }
                }
                let shift = shift_lengths(&g, &shown, &next);
                times.push(update_time_us(&shift, board.led_shift_ns, board.latch_us) as f64);
                shown = next;
            }
            let total: f64 = times.iter().sum();
            let p = Percentiles::of(&mut times);
            rows.push(SwitchRow {
                order,
                lanes,
                full_chain_ms: full / 1e3,
                partial_mean_ms: p.mean_us / 1e3,
                partial_p50_ms: p.p50_us / 1e3,
                partial_max_ms: p.max_us / 1e3,
                scan_shift_s: total / 1e6,
            });
        }
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
        return Ok(());
    }
    println!("LED switch time per step of a 441-LED single-LED scan (30 µs per LED per lane, 280 µs latch):");
    println!("  order    lanes  full chain   partial mean   partial p50   partial max   441 steps (shift only)");
    for r in &rows {
        println!(
            "  {:<8} {:>5}  {:>8.2} ms   {:>9.2} ms   {:>8.2} ms   {:>8.2} ms   {:>8.2} s",
            format!("{:?}", r.order).to_lowercase(),
            r.lanes,
            r.full_chain_ms,
            r.partial_mean_ms,
            r.partial_p50_ms,
            r.partial_max_ms,
            r.scan_shift_s
        );
    }
    Ok(())
}
