//! `fpm bench serve`: the acquisition service as its clients see it, on virtual rigs
//! started for the run.
//!
//! * API round trip: `GET /api/status` on loopback, a new connection per request (as a
//!   script's `urllib` makes them), from 1 client and from 50 at once.
//! * Event latency: a labelled frame's event, from the service publishing it (its
//!   `at_s`) to a client reading it off the event stream.
//! * Snapshot latency: from the event of the frame that completes a snapshot's count to
//!   the client holding that snapshot's PNG (the reconstruction's blend, the PNG's
//!   encoding and the request included).
//! * Pause: from the client's pause request to the job's progress saying `paused` (the
//!   capture sequence cut at its LED, the rig holding).
//! * Cancel: from the client's cancel request to the job's `cancelled` state (the
//!   sequence aborted, the frames so far labelled and written).
//! * Overhead: the same 441-LED acquisition run by `fpm acquire` and by the service,
//!   alternately, each on a virtual rig of its own: the capture's seconds (from
//!   `acquisition.json`) and the whole run's, as ratios service / CLI.

use std::net::SocketAddr;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use anyhow::{anyhow, bail, Context, Result};
use fpm_serve::client::{event_lines, send, VirtualService};
use serde::Serialize;

use crate::stats::Percentiles;

/// What to measure.
#[derive(Debug, Clone)]
pub struct ServeOptions {
    /// Requests per client count in the round-trip test.
    pub requests: usize,
    /// Concurrent clients in the loaded round-trip test.
    pub clients: usize,
    /// The virtual camera's side, pixels.
    pub size: usize,
    /// How long each LED is lit, ms.
    pub step_ms: f64,
    /// Acquisitions per side in the overhead comparison.
    pub rounds: usize,
    /// Print JSON.
    pub json: bool,
}

#[derive(Serialize)]
struct Report {
    virtual_camera_px: usize,
    step_ms: f64,
    round_trip_1_client: Percentiles,
    round_trip_clients: usize,
    round_trip_n_clients: Percentiles,
    frame_event_latency: Percentiles,
    snapshot_latency: Percentiles,
    pause_to_paused: Percentiles,
    cancel_to_cancelled: Percentiles,
    overhead: Overhead,
}

#[derive(Serialize)]
struct Overhead {
    rounds: usize,
    cli_capture_s: Vec<f64>,
    service_capture_s: Vec<f64>,
    cli_run_s: Vec<f64>,
    service_run_s: Vec<f64>,
    /// Median service / median CLI.
    capture_ratio: f64,
    run_ratio: f64,
}

fn now_s() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

fn median(v: &[f64]) -> f64 {
    fpm_physics::stats::median(&mut v.to_vec()).unwrap_or(f64::NAN)
}

/// Until job `id` is the one running.
fn wait_running(service: &VirtualService, id: i64) -> Result<()> {
    let start = Instant::now();
    while service.get("/api/status")?.json()?["running"].as_i64() != Some(id) {
        if start.elapsed() > Duration::from_secs(30) {
            bail!("job {id} never started");
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    Ok(())
}

/// `GET /api/status` from `clients` threads at once, `per_client` each: µs per request.
fn round_trips(address: SocketAddr, clients: usize, per_client: usize) -> Result<Percentiles> {
    let samples: Vec<Result<Vec<f64>>> = std::thread::scope(|s| {
        let workers: Vec<_> = (0..clients)
            .map(|_| {
                s.spawn(move || {
                    (0..per_client)
                        .map(|_| {
                            let t = Instant::now();
                            let r = send(address, "GET", "/api/status", &[], None)?;
                            if r.status != 200 {
                                bail!("GET /api/status: {}", r.status);
                            }
                            Ok(t.elapsed().as_secs_f64() * 1e6)
                        })
                        .collect()
                })
            })
            .collect();
        workers
            .into_iter()
            .map(|w| {
                w.join()
                    .unwrap_or_else(|_| Err(anyhow!("a client panicked")))
            })
            .collect()
    });
    let mut all = vec![];
    for s in samples {
        all.extend(s?);
    }
    Ok(Percentiles::of(&mut all))
}

/// A reconstructing acquisition followed on the event stream: frame-event latencies
/// and snapshot latencies, µs.
fn live_latencies(service: &VirtualService, step_ms: f64) -> Result<(Percentiles, Percentiles)> {
    let lines = event_lines(service.address, None)?;
    let job = service.submit(&serde_json::json!({"kind": "acquire", "step_ms": step_ms,
        "reconstruct": true, "snapshot_every": 25}))?;
    let (mut frame_us, mut snapshot_us) = (vec![], vec![]);
    // Publication time of the job's n-th capture frame (1-based).
    let mut frame_at: Vec<f64> = vec![];
    for line in lines {
        let Some(data) = line.strip_prefix("data:") else {
            continue;
        };
        let received = now_s();
        let event: serde_json::Value = serde_json::from_str(data.trim())?;
        if event["job"] != job {
            continue;
        }
        let at = event["at_s"].as_f64().unwrap_or(received);
        match event["event"].as_str() {
            Some("frame") => {
                frame_us.push((received - at) * 1e6);
                frame_at.push(at);
            }
            Some("snapshot") if event["finished"] == false => {
                let n = event["frames"].as_u64().unwrap_or(0) as usize;
                let seq = &event["seq"];
                let png = service.get(&format!(
                    "/api/jobs/{job}/snapshot/amplitude?format=png&seq={seq}"
                ))?;
                if png.status != 200 {
                    bail!("the snapshot: {}", png.body);
                }
                if let Some(&frame) = frame_at.get(n.wrapping_sub(1)) {
                    snapshot_us.push((now_s() - frame) * 1e6);
                }
            }
            Some("state") if !matches!(event["state"].as_str(), Some("queued" | "running")) => {
                if event["state"] != "done" {
                    bail!("the live job ended {}: {}", event["state"], event["error"]);
                }
                break;
            }
            _ => {}
        }
    }
    Ok((
        Percentiles::of(&mut frame_us),
        Percentiles::of(&mut snapshot_us),
    ))
}

/// Acquisitions paused a second into their capture, resumed, then cancelled: µs from
/// each request to the event that says it took effect (progress `paused`; the job
/// `cancelled`).
fn pauses_and_cancels(
    service: &VirtualService,
    step_ms: f64,
    count: usize,
) -> Result<(Percentiles, Percentiles)> {
    let (mut pauses, mut cancels) = (vec![], vec![]);
    for _ in 0..count {
        let mut lines = event_lines(service.address, None)?;
        let job = service.submit(&serde_json::json!({"kind": "acquire", "step_ms": step_ms}))?;
        wait_running(service, job)?;
        std::thread::sleep(Duration::from_secs(1));
        let mut until = |asked: f64, took_effect: &dyn Fn(&serde_json::Value) -> bool| {
            for line in lines.by_ref() {
                let Some(data) = line.strip_prefix("data:") else {
                    continue;
                };
                let event: serde_json::Value = serde_json::from_str(data.trim())?;
                if event["job"] == job && took_effect(&event) {
                    let at = event["at_s"].as_f64().unwrap_or_else(now_s);
                    return Ok((at - asked) * 1e6);
                }
            }
            Err(anyhow!("the event stream ended before job {job} answered"))
        };
        for (verb, samples) in [("pause", Some(&mut pauses)), ("resume", None)] {
            let asked = now_s();
            let r = service.post(&format!("/api/jobs/{job}/{verb}"), None)?;
            if r.status != 202 {
                bail!("{verb}: {}", r.body);
            }
            if let Some(samples) = samples {
                samples.push(until(asked, &|e| {
                    e["event"] == "progress" && e["progress"]["phase"] == "paused"
                })?);
            }
        }
        std::thread::sleep(Duration::from_millis(300));
        let asked = now_s();
        let r = service.post(&format!("/api/jobs/{job}/cancel"), None)?;
        if r.status != 202 {
            bail!("cancel: {}", r.body);
        }
        cancels.push(until(asked, &|e| {
            e["event"] == "state" && e["state"] == "cancelled"
        })?);
    }
    Ok((Percentiles::of(&mut pauses), Percentiles::of(&mut cancels)))
}

/// `fpm acquire` on a virtual rig of its own: (capture s, run s).
fn cli_acquisition(fpm: &Path, dir: &Path, size: usize, step_ms: f64) -> Result<(f64, f64)> {
    let name = format!(
        "bench-serve-{}-{}",
        std::process::id(),
        dir.file_name().and_then(|n| n.to_str()).unwrap_or("x")
    );
    let rig = fpm_rig::process::VirtualRig::start(
        fpm,
        &name,
        &dir.join("rig"),
        &["--size", &size.to_string()],
    )?;
    let out = dir.join("out");
    let start = Instant::now();
    let status = Command::new(fpm)
        .args(["acquire", "--port", &rig.emulator.port(), "--frames", &name])
        .args(["--stage", "virtual", "--rig", &name])
        .args(["--step-ms", &step_ms.to_string()])
        .arg("--out")
        .arg(&out)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()?;
    let run_s = start.elapsed().as_secs_f64();
    if !status.success() {
        bail!("fpm acquire failed ({status})");
    }
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("acquisition.json"))?)?;
    Ok((capture_seconds(&summary)?, run_s))
}

fn capture_seconds(summary: &serde_json::Value) -> Result<f64> {
    summary["capture"]["seconds"]
        .as_f64()
        .ok_or_else(|| anyhow!("no capture.seconds in the acquisition's summary"))
}

/// The service's acquisition: (capture s, run s from running to its end).
fn service_acquisition(service: &VirtualService, step_ms: f64) -> Result<(f64, f64)> {
    let job = service.submit(&serde_json::json!({"kind": "acquire", "step_ms": step_ms}))?;
    let record = service.wait(job, Duration::from_secs(600))?;
    if record["state"] != "done" {
        bail!(
            "the service's acquisition ended {}: {}",
            record["state"],
            record["error"]
        );
    }
    let run = record["finished_s"].as_f64().unwrap_or(f64::NAN)
        - record["started_s"].as_f64().unwrap_or(f64::NAN);
    Ok((capture_seconds(&record["summary"])?, run))
}

/// Run the benchmark.
pub fn run(o: ServeOptions) -> Result<()> {
    let fpm = std::env::current_exe().context("locating the fpm executable")?;
    let scratch = tempfile::Builder::new()
        .prefix("fpm-bench-serve")
        .tempdir()?;
    let dir = scratch.path();
    let say = |what: &str| {
        if !o.json {
            eprintln!("{what}");
        }
    };
    say("starting fpm serve --virtual …");
    let service = VirtualService::start(&fpm, &dir.join("state"), o.size, Stdio::null())?;
    say("API round trips …");
    let one = round_trips(service.address, 1, o.requests)?;
    let many = round_trips(service.address, o.clients, o.requests.div_ceil(o.clients))?;
    say("a reconstructing acquisition, followed live …");
    let (frame_event, snapshot) = live_latencies(&service, o.step_ms)?;
    say("pauses and cancels …");
    let (pause, cancel) = pauses_and_cancels(&service, o.step_ms, 5)?;
    let mut overhead = Overhead {
        rounds: o.rounds,
        cli_capture_s: vec![],
        service_capture_s: vec![],
        cli_run_s: vec![],
        service_run_s: vec![],
        capture_ratio: f64::NAN,
        run_ratio: f64::NAN,
    };
    for round in 0..o.rounds {
        say(&format!("overhead, round {} of {} …", round + 1, o.rounds));
        let (c, r) = cli_acquisition(&fpm, &dir.join(format!("cli-{round}")), o.size, o.step_ms)?;
        overhead.cli_capture_s.push(c);
        overhead.cli_run_s.push(r);
        let (c, r) = service_acquisition(&service, o.step_ms)?;
        overhead.service_capture_s.push(c);
        overhead.service_run_s.push(r);
    }
    overhead.capture_ratio = median(&overhead.service_capture_s) / median(&overhead.cli_capture_s);
    overhead.run_ratio = median(&overhead.service_run_s) / median(&overhead.cli_run_s);
    let report = Report {
        virtual_camera_px: o.size,
        step_ms: o.step_ms,
        round_trip_1_client: one,
        round_trip_clients: o.clients,
        round_trip_n_clients: many,
        frame_event_latency: frame_event,
        snapshot_latency: snapshot,
        pause_to_paused: pause,
        cancel_to_cancelled: cancel,
        overhead,
    };
    if o.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    let ms =
        |p: &Percentiles| format!("p50 {:.2} ms, p99 {:.2} ms", p.p50_us / 1e3, p.p99_us / 1e3);
    println!(
        "fpm serve on a virtual rig ({}² camera, {} ms per LED)",
        o.size, o.step_ms
    );
    println!(
        "  GET /api/status, 1 client:     {}",
        ms(&report.round_trip_1_client)
    );
    println!(
        "  GET /api/status, {} clients:   {}",
        o.clients,
        ms(&report.round_trip_n_clients)
    );
    println!(
        "  frame event → client:          {}",
        ms(&report.frame_event_latency)
    );
    println!(
        "  frame → snapshot PNG at client: {}",
        ms(&report.snapshot_latency)
    );
    println!(
        "  pause → holding:               {}",
        ms(&report.pause_to_paused)
    );
    println!(
        "  cancel → job cancelled:        {}",
        ms(&report.cancel_to_cancelled)
    );
    let o = &report.overhead;
    println!(
        "  441-LED acquisition, service / fpm acquire (median of {}): capture {:.4}×, whole run {:.4}×",
        o.rounds, o.capture_ratio, o.run_ratio
    );
    Ok(())
}
