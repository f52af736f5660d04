//! `fpm bench frames`: camera frames handed over through iceoryx2 shared memory versus
//! the same frames sent over a Unix socket, measured in one run.

use std::io::{Read, Write};
use std::os::unix::net::UnixStream;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use fpm_frames::{
    FrameHeader, FramePublisher, FrameSubscriber, ServiceNames, SAMPLES_PER_PUBLISHER,
};
use serde::Serialize;

use crate::stats::Percentiles;

#[derive(Serialize)]
struct SizeResult {
    width: u32,
    height: u32,
    megabytes: f64,
    rounds: usize,
    iceoryx2_us: Percentiles,
    /// The same hand-off with the camera pausing [`SETTLE`] between writing the
    /// pixels and sending them: without the write-back of the frame just written.
    iceoryx2_settled_us: Percentiles,
    unix_socket_us: Percentiles,
    socket_over_iceoryx2_p50: f64,
    /// p50 minus the 16 × 16 frame's p50 (same run): what the frame's size costs.
    iceoryx2_size_cost_p50_us: f64,
    /// The same for the settled hand-off.
    iceoryx2_settled_size_cost_p50_us: f64,
    shared_memory_reserved_mb: f64,
}

/// The camera's pause between writing a frame and sending it, in the settled runs.
const SETTLE: Duration = Duration::from_millis(5);

#[derive(Serialize)]
struct Report {
    /// A 16 × 16 frame through the same path: the wake-up and bookkeeping that no
    /// frame size can avoid.
    tiny_frame_iceoryx2_us: Percentiles,
    /// The same, settled.
    tiny_frame_iceoryx2_settled_us: Percentiles,
    sizes: Vec<SizeResult>,
}

/// Run the benchmark for 2048² and 5472 × 3648 frames.
pub fn run(rounds: usize, json: bool) -> Result<()> {
    let mut results = vec![];
    let tiny = iceoryx2_handoff(16, 16, rounds.max(5), Duration::ZERO)?;
    let tiny_settled = iceoryx2_handoff(16, 16, rounds.max(5), SETTLE)?;
    for (w, h) in [(2048u32, 2048u32), (5472, 3648)] {
        let n = rounds.max(5);
        let ice = iceoryx2_handoff(w, h, n, Duration::ZERO)?;
        let settled = iceoryx2_handoff(w, h, n, SETTLE)?;
        let sock = socket_copy(w, h, n)?;
        let bytes = w as f64 * h as f64 * 2.0;
        let (ice, sock) = (ice, sock);
        results.push(SizeResult {
            width: w,
            height: h,
            megabytes: bytes / 1e6,
            rounds: n,
            socket_over_iceoryx2_p50: sock.p50_us / ice.p50_us,
            iceoryx2_size_cost_p50_us: ice.p50_us - tiny.p50_us,
            iceoryx2_settled_size_cost_p50_us: settled.p50_us - tiny_settled.p50_us,
            iceoryx2_us: ice,
            iceoryx2_settled_us: settled,
            unix_socket_us: sock,
            shared_memory_reserved_mb: bytes * SAMPLES_PER_PUBLISHER as f64 / 1e6,
        });
    }
    if json {
        let report = Report {
            tiny_frame_iceoryx2_us: tiny,
            tiny_frame_iceoryx2_settled_us: tiny_settled,
            sizes: results,
        };
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    println!("frame hand-off, camera thread → host thread (same machine, one run):");
    println!("  frame            size    iceoryx2 p50 / p99 µs   above 16×16   settled p50 / p99 µs   above 16×16   Unix socket p50 / p99 µs   socket/iceoryx2   shm reserved");
    println!(
        "  {:>4}×{:<4}  {:>7.1} kB   {:>9.1} / {:<9.1}   {:>11}   {:>8.1} / {:<9.1}",
        16, 16, 0.5, tiny.p50_us, tiny.p99_us, "", tiny_settled.p50_us, tiny_settled.p99_us
    );
    for r in &results {
        println!(
            "  {:>4}×{:<4}  {:>7.1} MB   {:>9.1} / {:<9.1}   {:>+11.1}   {:>8.1} / {:<9.1}   {:>+11.1}   {:>10.0} / {:<10.0}   {:>10.0}×   {:>7.0} MB",
            r.width,
            r.height,
            r.megabytes,
            r.iceoryx2_us.p50_us,
            r.iceoryx2_us.p99_us,
            r.iceoryx2_size_cost_p50_us,
            r.iceoryx2_settled_us.p50_us,
            r.iceoryx2_settled_us.p99_us,
            r.iceoryx2_settled_size_cost_p50_us,
            r.unix_socket_us.p50_us,
            r.unix_socket_us.p99_us,
            r.socket_over_iceoryx2_p50,
            r.shared_memory_reserved_mb
        );
    }
    println!("  iceoryx2: from right after the camera wrote every pixel into shared memory to the host holding the frame;");
    println!(
        "  settled: the same with the camera pausing {} ms before sending (the frame's write-back to memory done);",
        SETTLE.as_millis()
    );
    println!(
        "  above 16×16: p50 minus a 16×16 frame's p50 through the same path (what the size costs);"
    );
    println!("  socket: from the first byte written to the last byte read into a ready buffer.");
    Ok(())
}

/// Publish → receive through the frame service; the camera thread stamps the time
/// after filling its loan, right before sending.
fn iceoryx2_handoff(w: u32, h: u32, rounds: usize, settle: Duration) -> Result<Percentiles> {
    let names = ServiceNames::for_camera(&format!("bench-{}-{w}x{h}", std::process::id()));
    let subscriber = FrameSubscriber::create(&names)?;
    let base = Instant::now();
    let (ack_tx, ack_rx) = mpsc::channel::<()>();
    let (ready_tx, ready_rx) = mpsc::channel::<Result<(), String>>();
    let camera_names = names.clone();
    let stamp = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
    let camera_stamp = stamp.clone();
    let camera = std::thread::spawn(move || -> Result<(), String> {
        let publisher =
            FramePublisher::create(&camera_names, (w * h) as usize).map_err(|e| e.to_string())?;
        let _ = ready_tx.send(Ok(()));
        for n in 0..rounds as u64 {
            let header = FrameHeader {
                frame_number: n,
                width: w,
                height: h,
                bit_depth: 12,
                ..FrameHeader::default()
            };
            // The camera writes every pixel into the loaned buffer (as a driver's
            // decode does), then the clock starts, `settle` later, right before send.
            publisher
                .publish_filled(header, |px| {
                    px.fill(std::mem::MaybeUninit::new(n as u16));
                    if !settle.is_zero() {
                        std::thread::sleep(settle);
                    }
                    camera_stamp.store(
                        base.elapsed().as_nanos() as u64,
                        std::sync::atomic::Ordering::Release,
                    );
                    Ok::<(), String>(())
                })
                .map_err(|e| e.to_string())?;
            if ack_rx.recv_timeout(Duration::from_secs(10)).is_err() {
                return Err("the host side stopped acknowledging".into());
            }
        }
        Ok(())
    });
    ready_rx
        .recv_timeout(Duration::from_secs(10))
        .context("camera thread did not start")?
        .map_err(anyhow::Error::msg)?;
    let mut samples = Vec::with_capacity(rounds);
    for n in 0..rounds as u64 {
        let frame = subscriber
            .next(Duration::from_secs(10))?
            .with_context(|| format!("frame {n} did not arrive within 10 s"))?;
        let now = base.elapsed().as_nanos() as u64;
        let px = frame.pixels();
        anyhow::ensure!(
            frame.header().frame_number == n && px[0] == n as u16 && px[px.len() - 1] == n as u16,
            "frame {n} arrived wrong"
        );
        // Stored before send; the camera waits for the ack before the next frame.
        let sent = stamp.load(std::sync::atomic::Ordering::Acquire);
        samples.push(now.saturating_sub(sent) as f64 / 1e3);
        drop(frame);
        let _ = ack_tx.send(());
    }
    camera
        .join()
        .map_err(|_| anyhow::anyhow!("camera thread panicked"))?
        .map_err(anyhow::Error::msg)?;
    Ok(Percentiles::of(&mut samples[1..].to_vec()))
}

/// The same frames through a Unix socket pair: a full copy through the kernel.
fn socket_copy(w: u32, h: u32, rounds: usize) -> Result<Percentiles> {
    let bytes = (w * h) as usize * 2;
    let (mut tx, mut rx) = UnixStream::pair()?;
    let base = Instant::now();
    let (stamp_tx, stamp_rx) = mpsc::channel::<u128>();
    let writer = std::thread::spawn(move || -> std::io::Result<()> {
        let frame = vec![7u8; bytes];
        for _ in 0..rounds {
            let _ = stamp_tx.send(base.elapsed().as_nanos());
            tx.write_all(&frame)?;
        }
        Ok(())
    });
    let mut buf = vec![0u8; bytes];
    let mut samples = Vec::with_capacity(rounds);
    for _ in 0..rounds {
        let start = stamp_rx.recv_timeout(Duration::from_secs(10))?;
        rx.read_exact(&mut buf)?;
        samples.push((base.elapsed().as_nanos() - start) as f64 / 1e3);
    }
    writer
        .join()
        .map_err(|_| anyhow::anyhow!("writer thread panicked"))??;
    Ok(Percentiles::of(&mut samples[1..].to_vec()))
}
