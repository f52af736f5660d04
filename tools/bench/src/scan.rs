//! `fpm bench scan`: fields per hour of a whole-slide scan on the virtual rig, each
//! field reconstructed while the next is acquired, against the same scan reconstructing
//! the fields after it (one after another) in the same run: the ratio is what the
//! overlap buys on this machine.

use std::path::Path;

use anyhow::Result;
use fpm_rig::demo::{run_scan, ScanDemo};
use serde::Serialize;

/// What to measure.
#[derive(Debug, Clone)]
pub struct ScanOptions {
    pub rows: usize,
    pub cols: usize,
    /// Sensor side, pixels.
    pub size: usize,
    /// The central LEDS × LEDS per field (None: all 441).
    pub leds: Option<usize>,
    pub json: bool,
}

/// One way of running the scan.
#[derive(Debug, Clone, Serialize)]
pub struct Run {
    /// From the first move to the stitched mosaic, s.
    pub seconds: f64,
    pub fields_per_hour: f64,
    /// The mosaic's complex NRMSE against the hidden slide.
    pub mosaic_complex_nrmse: Option<f64>,
}

/// The measurement.
#[derive(Debug, Clone, Serialize)]
pub struct ScanBench {
    pub fields: usize,
    pub size: usize,
    pub leds: Option<usize>,
    /// Each field reconstructed while the next is acquired.
    pub overlapped: Run,
    /// The fields reconstructed after the scan.
    pub sequential: Run,
    /// overlapped fields per hour / sequential.
    pub speedup: f64,
}

/// Run it; `fpm` is the `fpm` executable.
pub fn run(o: &ScanOptions, fpm: &Path) -> Result<ScanBench> {
    let dir = std::env::temp_dir().join(format!("fpm-bench-scan-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let once = |overlapped: bool| -> Result<Run> {
        let demo = ScanDemo {
            out: Some(dir.join(if overlapped {
                "overlapped"
            } else {
                "sequential"
            })),
            rows: o.rows,
            cols: o.cols,
            size: o.size,
            leds: o.leds,
            reconstruct_while_scanning: overlapped,
            ..ScanDemo::default()
        };
        let report = run_scan(&demo, fpm, |_, _| {})?;
        Ok(Run {
            seconds: report.seconds,
            fields_per_hour: (o.rows * o.cols) as f64 / report.seconds * 3600.0,
            mosaic_complex_nrmse: report.stitch.versus_truth.map(|t| t.complex_nrmse),
        })
    };
    // Sequential first, then overlapped: each on a rig of its own.
    let sequential = once(false)?;
    let overlapped = once(true)?;
    let _ = std::fs::remove_dir_all(&dir);
    let bench = ScanBench {
        fields: o.rows * o.cols,
        size: o.size,
        leds: o.leds,
        speedup: overlapped.fields_per_hour / sequential.fields_per_hour,
        overlapped,
        sequential,
    };
    if o.json {
        println!("{}", serde_json::to_string_pretty(&bench)?);
    } else {
        println!(
            "scan of {} fields of {}² ({} LEDs each) on the virtual rig, to the stitched mosaic:",
            bench.fields,
            bench.size,
            o.leds.map_or("441".to_string(), |n| (n * n).to_string())
        );
        for (name, r) in [
            ("reconstructed while scanning", &bench.overlapped),
            ("reconstructed after", &bench.sequential),
        ] {
            println!(
                "  {name:<30} {:>7.1} s  {:>6.0} fields/h  mosaic NRMSE {}",
                r.seconds,
                r.fields_per_hour,
                r.mosaic_complex_nrmse
                    .map_or("-".into(), |v| format!("{v:.3}"))
            );
        }
        println!("  overlap speedup {:.2}×", bench.speedup);
    }
    Ok(bench)
}
