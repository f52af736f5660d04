//! `fpm bench serve`: the acquisition service as its clients see it, on virtual rigs
//! started for the run.
//!
//! * API round trip: `GET /api/status` on loopback, a new connection per request (as a
//!   script's `urllib` makes them), from 1 client and from 50 at once.
//! * Event latency: a labelled frame's event, from the service publishing it (its
//!   `at_s`) to a client reading it off the event stream.
//! * Snapshot age: from the event of the frame that completes a snapshot's count to
//!   the client holding that snapshot's PNG (the reconstruction's blend, the PNG's
//!   encoding and the request included).
//! * Live labelling: the share of the capture's frames labelled while its sequence ran,
//!   and a frame's arrival → its label, p50 and p99 (the capture's own figures).
//! * ETA: `/api/status`'s time left when a quarter, half and three quarters of the
//!   frames are labelled, against the capture's actual end.
//! * Pause: from the client's pause request to the job's progress saying `paused` (the
//!   capture sequence cut at its LED, the rig holding).
//! * Cancel: from the client's cancel request to the job's `cancelled` state (the
//!   sequence aborted, the frames so far labelled and written); and from the service
//!   taking the request to the controller's answer that the sequence is aborted, its
//!   LEDs committed dark (the capture's own figure, `acquisition.json`'s
//!   `capture.cancel_to_leds_off_ms`; the request's way to the service, a loopback
//!   round trip, is the first figure's).
//! * Each of the live figures, pause and cancel twice: with the machine idle, and with
//!   a CPU hog beside the service (two busy threads of the bench's own, stopped
//!   afterwards), as a lab's PC running napari or the previous field's reconstruction.
//! * Overhead: the same 441-LED acquisition run by `fpm acquire` and by the service,
//!   alternately, each on a virtual rig of its own: the capture's seconds (from
//!   `acquisition.json`) and the whole run's, as ratios service / CLI.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
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
    /// The virtual camera's side, pixels (None: `fpm serve --virtual`'s default).
    pub size: Option<usize>,
    /// How long each LED is lit, ms (None: the default).
    pub step_ms: Option<f64>,
    /// Acquisitions per side in the overhead comparison.
    pub rounds: usize,
    /// The controller the real firmware image (a UF2) in an emulated RP2040 (None: the
    /// host-compiled controller logic).
    pub firmware: Option<PathBuf>,
    /// Print JSON.
    pub json: bool,
}

#[derive(Serialize)]
struct Report {
    /// None: the service's defaults.
    virtual_camera_px: Option<usize>,
    step_ms: Option<f64>,
    /// The controller: "host-compiled emulator" or the firmware image's path.
    controller: String,
    round_trip_1_client: Percentiles,
    round_trip_clients: usize,
    round_trip_n_clients: Percentiles,
    /// The machine idle, then with the hog.
    idle: Live,
    hog: Live,
    overhead: Overhead,
}

/// A reconstructing acquisition as a client follows it, and pauses and cancels.
#[derive(Serialize)]
struct Live {
    frame_event_latency: Percentiles,
    /// The newest frame in a snapshot (its event) → the client holding its PNG.
    snapshot_age: Percentiles,
    /// Frames labelled while the controller's sequence ran, of those labelled.
    labelled_live_share: f64,
    label_lag_p50_ms: f64,
    label_lag_p99_ms: f64,
    eta: Vec<Eta>,
    pause_to_paused: Percentiles,
    cancel_to_cancelled: Percentiles,
    /// The service taking the cancel → the controller's LEDs off (over the cancels
    /// that found a sequence running).
    cancel_to_leds_off: Percentiles,
}

/// One poll of `/api/status` while the job ran.
struct Polled {
    at_s: f64,
    frames: f64,
    of: f64,
    eta_s: Option<f64>,
    capturing: bool,
}

/// `/api/status`'s time left at a share of the capture's frames, against the actual.
#[derive(Serialize)]
struct Eta {
    share: f64,
    eta_s: f64,
    actual_s: f64,
    /// (ETA − actual) / actual.
    error: f64,
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

/// An acquire job's request, with `step_ms` or the service's default.
fn acquire_request(step_ms: Option<f64>) -> serde_json::Value {
    let mut request = serde_json::json!({"kind": "acquire"});
    if let Some(ms) = step_ms {
        request["step_ms"] = ms.into();
    }
    request
}

/// `[flag, value]` when there is a value, for a command line.
fn optional_flag<'a>(flag: &'a str, value: &'a Option<String>) -> impl Iterator<Item = &'a str> {
    value.iter().flat_map(move |v| [flag, v.as_str()])
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

/// A reconstructing acquisition followed on the event stream (frame-event latencies
/// and snapshot ages, µs), with `/api/status` polled beside it for the ETA; then its
/// record for the capture's live-labelling figures. Pause and cancel are left empty.
fn follow_live(service: &VirtualService, step_ms: Option<f64>) -> Result<Live> {
    let lines = event_lines(service.address, None)?;
    let mut request = acquire_request(step_ms);
    request["reconstruct"] = true.into();
    request["snapshot_every"] = 25.into();
    let job = service.submit(&request)?;
    let (mut frame_us, mut snapshot_us) = (vec![], vec![]);
    // Publication time of the job's n-th capture frame (1-based).
    let mut frame_at: Vec<f64> = vec![];
    let stop = AtomicBool::new(false);
    // /api/status every 50 ms while the job runs.
    let polled = std::thread::scope(|s| -> Result<Vec<Polled>> {
        let poller = s.spawn(|| {
            let mut seen = vec![];
            while !stop.load(Ordering::Relaxed) {
                if let Ok(status) = service.get("/api/status").and_then(|r| r.json()) {
                    if status["running"].as_i64() == Some(job) {
                        let p = &status["progress"];
                        seen.push(Polled {
                            at_s: now_s(),
                            frames: p["frames"].as_f64().unwrap_or(0.0),
                            of: p["of"].as_f64().unwrap_or(0.0),
                            eta_s: status["eta_s"].as_f64(),
                            capturing: p["phase"] == "capturing",
                        });
                    }
                }
                std::thread::sleep(Duration::from_millis(50));
            }
            seen
        });
        let followed = (|| -> Result<()> {
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
                    Some("state")
                        if !matches!(event["state"].as_str(), Some("queued" | "running")) =>
                    {
                        if event["state"] != "done" {
                            bail!("the live job ended {}: {}", event["state"], event["error"]);
                        }
                        return Ok(());
                    }
                    _ => {}
                }
            }
            bail!("the event stream ended before job {job} did")
        })();
        stop.store(true, Ordering::Relaxed);
        let seen = poller
            .join()
            .map_err(|_| anyhow!("the status poller panicked"))?;
        followed.map(|()| seen)
    })?;
    let record = service.get(&format!("/api/jobs/{job}"))?.json()?;
    let capture = &record["summary"]["capture"];
    let number = |field: &str| {
        capture[field]
            .as_f64()
            .ok_or_else(|| anyhow!("no capture.{field} in job {job}'s summary: {capture}"))
    };
    Ok(Live {
        frame_event_latency: Percentiles::of(&mut frame_us),
        snapshot_age: Percentiles::of(&mut snapshot_us),
        labelled_live_share: number("labelled_live")? / number("labelled")?.max(1.0),
        label_lag_p50_ms: number("label_lag_p50_ms")?,
        label_lag_p99_ms: number("label_lag_p99_ms")?,
        eta: eta_errors(&polled),
        pause_to_paused: Percentiles::of(&mut []),
        cancel_to_cancelled: Percentiles::of(&mut []),
        cancel_to_leds_off: Percentiles::of(&mut []),
    })
}

/// The ETA the status gave when a quarter, half and three quarters of the frames were
/// labelled, against the time the capture actually ended (its last poll as capturing).
fn eta_errors(polled: &[Polled]) -> Vec<Eta> {
    let capturing = || polled.iter().filter(|p| p.capturing);
    let Some(end) = capturing().map(|p| p.at_s).reduce(f64::max) else {
        return vec![];
    };
    [0.25, 0.5, 0.75]
        .into_iter()
        .filter_map(|share| {
            let at = capturing().find(|p| p.of > 0.0 && p.frames >= share * p.of)?;
            let (eta_s, actual_s) = (at.eta_s?, end - at.at_s);
            Some(Eta {
                share,
                eta_s,
                actual_s,
                error: (eta_s - actual_s) / actual_s.max(1e-3),
            })
        })
        .collect()
}

/// Two threads that spin until dropped: the CPU hog beside the service.
struct Hog {
    stop: Arc<AtomicBool>,
    threads: Vec<std::thread::JoinHandle<()>>,
}

impl Hog {
    fn start(threads: usize) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let threads = (0..threads)
            .map(|_| {
                let stop = stop.clone();
                std::thread::spawn(move || {
                    let mut x = 1u64;
                    while !stop.load(Ordering::Relaxed) {
                        for _ in 0..10_000 {
                            x = std::hint::black_box(x.wrapping_mul(6_364_136_223_846_793_005) + 1);
                        }
                    }
                })
            })
            .collect();
        Self { stop, threads }
    }
}

impl Drop for Hog {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// Acquisitions paused a second into their capture, resumed, then cancelled: µs from
/// each request to the event that says it took effect (progress `paused`; the job
/// `cancelled`), and from the service taking the cancel to the LEDs off (as the
/// capture measured it).
fn pauses_and_cancels(
    service: &VirtualService,
    step_ms: Option<f64>,
    count: usize,
) -> Result<(Percentiles, Percentiles, Percentiles)> {
    let (mut pauses, mut cancels, mut dark) = (vec![], vec![], vec![]);
    for _ in 0..count {
        let mut lines = event_lines(service.address, None)?;
        let job = service.submit(&acquire_request(step_ms))?;
        wait_running(service, job)?;
        std::thread::sleep(Duration::from_secs(1));
        let mut until = |asked: f64, took_effect: &dyn Fn(&serde_json::Value) -> bool| {
            for line in lines.by_ref() {
                let Some(data) = line.strip_prefix("data:") else {
                    continue;
                };
                let event: serde_json::Value = serde_json::from_str(data.trim())?;
                if event["job"] == job && event["event"] == "state" && event["state"] == "failed" {
                    bail!("job {job} failed: {}", event["error"]);
                }
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
        let record = service.get(&format!("/api/jobs/{job}"))?.json()?;
        let out = record["out"].as_str().unwrap_or_default();
        let summary = Path::new(out).join("acquisition.json");
        let Ok(text) = std::fs::read_to_string(&summary) else {
            // (On stderr, which --json leaves to the log: stdout is the report.)
            eprintln!(
                "  (job {job} was cancelled before its capture wrote {})",
                summary.display()
            );
            continue;
        };
        let summary: serde_json::Value =
            serde_json::from_str(&text).with_context(|| format!("{}", summary.display()))?;
        // None when the cancel found no sequence running (between the paused
        // sequence and the next): the LEDs were off already.
        if let Some(off) = summary["capture"]["cancel_to_leds_off_ms"].as_f64() {
            dark.push(off * 1e3);
        }
    }
    Ok((
        Percentiles::of(&mut pauses),
        Percentiles::of(&mut cancels),
        Percentiles::of(&mut dark),
    ))
}

/// `fpm acquire` on a virtual rig of its own: (capture s, run s).
fn cli_acquisition(
    fpm: &Path,
    dir: &Path,
    size: Option<usize>,
    step_ms: Option<f64>,
    firmware: Option<&Path>,
) -> Result<(f64, f64)> {
    let name = format!(
        "bench-serve-{}-{}",
        std::process::id(),
        dir.file_name().and_then(|n| n.to_str()).unwrap_or("x")
    );
    let (size, step) = (
        size.map(|s| s.to_string()),
        step_ms.map(|ms| ms.to_string()),
    );
    let rig_args: Vec<&str> = optional_flag("--size", &size).collect();
    let rig = fpm_rig::process::VirtualRig::start_with_firmware(
        fpm,
        &name,
        &dir.join("rig"),
        firmware,
        &rig_args,
    )?;
    let out = dir.join("out");
    let start = Instant::now();
    let status = Command::new(fpm)
        .args(["acquire", "--port", &rig.emulator.port(), "--frames", &name])
        .args(["--stage", "virtual", "--rig", &name])
        .args(optional_flag("--step-ms", &step))
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
fn service_acquisition(service: &VirtualService, step_ms: Option<f64>) -> Result<(f64, f64)> {
    let job = service.submit(&acquire_request(step_ms))?;
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
    let size = o.size.map(|s| s.to_string());
    let firmware = o
        .firmware
        .as_ref()
        .map(|p| p.to_string_lossy().into_owned());
    let serve_args: Vec<&str> = optional_flag("--virtual-size", &size)
        .chain(optional_flag("--virtual-firmware", &firmware))
        .collect();
    let service = VirtualService::start_with(&fpm, &dir.join("state"), &serve_args, Stdio::null())?;
    say("API round trips …");
    let one = round_trips(service.address, 1, o.requests)?;
    let many = round_trips(service.address, o.clients, o.requests.div_ceil(o.clients))?;
    let live = |hog: bool| -> Result<Live> {
        let _hog = hog.then(|| Hog::start(2));
        let beside = if hog { " beside a CPU hog" } else { "" };
        say(&format!(
            "a reconstructing acquisition, followed live{beside} …"
        ));
        let mut live = follow_live(&service, o.step_ms)?;
        say(&format!("pauses and cancels{beside} …"));
        (
            live.pause_to_paused,
            live.cancel_to_cancelled,
            live.cancel_to_leds_off,
        ) = pauses_and_cancels(&service, o.step_ms, 5)?;
        Ok(live)
    };
    let (idle, hog) = (live(false)?, live(true)?);
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
        let (c, r) = cli_acquisition(
            &fpm,
            &dir.join(format!("cli-{round}")),
            o.size,
            o.step_ms,
            o.firmware.as_deref(),
        )?;
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
        controller: firmware
            .clone()
            .unwrap_or_else(|| "host-compiled emulator".into()),
        round_trip_1_client: one,
        round_trip_clients: o.clients,
        round_trip_n_clients: many,
        idle,
        hog,
        overhead,
    };
    if o.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    let ms =
        |p: &Percentiles| format!("p50 {:.2} ms, p99 {:.2} ms", p.p50_us / 1e3, p.p99_us / 1e3);
    let rig = match (o.size, o.step_ms) {
        (None, None) => "fpm serve --virtual's defaults".to_string(),
        (size, step) => format!(
            "{} camera, {} per LED",
            size.map_or("default".into(), |s| format!("{s}²")),
            step.map_or("default".into(), |ms| format!("{ms} ms"))
        ),
    };
    println!(
        "fpm serve on a virtual rig ({rig}; controller: {})",
        report.controller
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
    for (name, live) in [("idle", &report.idle), ("beside a CPU hog", &report.hog)] {
        println!("  {name}:");
        println!(
            "    frames labelled while the sequence ran: {:.1} %; arrival → label p50 {:.0} ms, p99 {:.0} ms",
            100.0 * live.labelled_live_share,
            live.label_lag_p50_ms,
            live.label_lag_p99_ms
        );
        println!(
            "    frame event → client:          {}",
            ms(&live.frame_event_latency)
        );
        println!(
            "    snapshot age at the client:    {}",
            ms(&live.snapshot_age)
        );
        for e in &live.eta {
            println!(
                "    ETA at {:.0} % of the frames: {:.1} s for {:.1} s ({:+.0} %)",
                100.0 * e.share,
                e.eta_s,
                e.actual_s,
                100.0 * e.error
            );
        }
        println!(
            "    pause → holding:               {}",
            ms(&live.pause_to_paused)
        );
        println!(
            "    cancel → job cancelled:        {}",
            ms(&live.cancel_to_cancelled)
        );
        println!(
            "    cancel → LEDs off:             {}",
            ms(&live.cancel_to_leds_off)
        );
    }
    let o = &report.overhead;
    println!(
        "  441-LED acquisition, service / fpm acquire (median of {}): capture {:.4}×, whole run {:.4}×",
        o.rounds, o.capture_ratio, o.run_ratio
    );
    Ok(())
}
