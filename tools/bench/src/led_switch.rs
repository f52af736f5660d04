//! `fpm bench led-switch`: LED switch times of single-LED scans under the firmware's
//! chain model, full chain versus partial shifts, for 1, 2 and 4 data lanes.

use anyhow::Result;
use fpm_acquire::controller::scan::{scan_steps, Order, Selection};
use fpm_protocol::Rgb;
use serde::Serialize;

use crate::Percentiles;

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
pub fn run(json: bool) -> Result<()> {
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
