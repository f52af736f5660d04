//! The emulator's event loop: bytes from the terminal, the device's deadlines and the
//! camera's edges, in time order.

use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use fpm_firmware::{BoardConfig, CalibrationStore, Device};
use nix::poll::{PollFd, PollFlags};
use nix::sys::time::TimeSpec;

use crate::args::EmulatorOptions;
use crate::flash::{EmulatedFlash, FlashFile};
use crate::hardware::{Camera, EmulatedStrip, EmulatedTrigger};
use crate::pty::{Link, Pty};

/// Longest sleep between checks for a stop signal.
const MAX_SLEEP: Duration = Duration::from_millis(100);

/// Run until SIGINT, SIGTERM or SIGHUP.
pub fn run(args: EmulatorOptions) -> Result<()> {
    if let Some(uf2) = &args.firmware {
        return crate::firmware::run_firmware(&args, uf2);
    }
    let board = board(&args)?;
    fpm_rig_bus::stop::install().context("installing signal handlers")?;

    let strip = EmulatedStrip::new(board.geometry);
    let mut flash = FlashFile::new(args.flash.as_deref());
    let store = CalibrationStore::new(flash.load()?, 0);
    let mut device = Device::new(board, args.serial, strip, EmulatedTrigger::default(), store)
        .map_err(|e| anyhow::anyhow!("invalid board: {e}"))?;
    let mut camera =
        (!args.no_camera).then(|| Camera::new(args.camera_latency_us, args.camera_exposure_us));

    let rig = match &args.rig {
        Some(name) => Some(
            fpm_rig_bus::PulsePublisher::create(name)
                .with_context(|| format!("opening the virtual rig {name}"))?,
        ),
        None => None,
    };
    let mut pulses = 0u64;
    let pty = Pty::open()?;
    let _link = Link::create(&args.link, pty.device_path())?;
    tracing::info!(
        "emulated LED controller ready on {} (linked at {}), {}x{} LEDs, {} lane(s), camera: {}",
        pty.device_path().display(),
        args.link.display(),
        args.rows,
        args.cols,
        args.lanes,
        if camera.is_some() {
            format!("{} µs exposures", args.camera_exposure_us)
        } else {
            "none".into()
        }
    );

    let start = Instant::now();
    let now_us = || start.elapsed().as_micros() as u64;
    let mut dropped_frames = 0u64;
    let mut next: Option<u64> = None;
    let mut buf = [0u8; 4096];

    while !fpm_rig_bus::stop::requested() {
        let mut send = |bytes: &[u8]| {
            if !pty.write_frame(&outgoing(bytes, args.report_protocol)) {
                dropped_frames += 1;
                tracing::warn!(
                    "no client is reading: dropped an outgoing frame ({dropped_frames} so far)"
                );
            }
        };

        // Camera edges and device deadlines that are due.
        let now = now_us();
        if let Some(cam) = camera.as_mut() {
            while let Some((at, edge)) = cam.due(now) {
                next = device.trigger_edge(edge, at, now, &mut send);
            }
        }
        if next.is_some_and(|t| t <= now) {
            next = device.poll(now, &mut send);
        }
        stamp_trigger(&device, camera.as_mut(), now, rig.as_ref(), &mut pulses);

        // Sleep until the next deadline, an edge, or bytes from the client.
        let wake = [next, camera.as_ref().and_then(Camera::next_edge_at)]
            .into_iter()
            .flatten()
            .min();
        let now = now_us();
        let sleep = match wake {
            Some(t) => Duration::from_micros(t.saturating_sub(now)).min(MAX_SLEEP),
            None => MAX_SLEEP,
        };
        let mut fds = [PollFd::new(pty.controller(), PollFlags::POLLIN)];
        let ready = match nix::poll::ppoll(&mut fds, Some(TimeSpec::from_duration(sleep)), None) {
            Ok(n) => n,
            Err(nix::errno::Errno::EINTR) => continue,
            Err(e) => return Err(e).context("waiting on the pseudo-terminal"),
        };
        if ready > 0 {
            let n = pty.read(&mut buf)?;
            if n > 0 {
                let now = now_us();
                next = device.receive(&buf[..n], now, &mut send);
                stamp_trigger(&device, camera.as_mut(), now, rig.as_ref(), &mut pulses);
                flash.save_if_changed(device.calibration_store().flash())?;
                if left_for_bootsel(&device, &args.link) {
                    break;
                }
            }
        }
    }
    tracing::info!(
        "emulated LED controller stopped (link stats: {:?})",
        device.link_stats()
    );
    Ok(())
}

/// `frame` as it goes out: the version request's answer reporting `report` instead
/// of the firmware's version where one is given.
fn outgoing(
    frame: &[u8],
    report: Option<fpm_protocol::ProtocolVersion>,
) -> std::borrow::Cow<'_, [u8]> {
    match report.and_then(|v| with_reported_version(frame, v)) {
        Some(changed) => std::borrow::Cow::Owned(changed),
        None => std::borrow::Cow::Borrowed(frame),
    }
}

/// `frame` (one COBS frame with its delimiter) with the version it reports replaced
/// by `version`, if it is the version request's answer.
fn with_reported_version(frame: &[u8], version: fpm_protocol::ProtocolVersion) -> Option<Vec<u8>> {
    use fpm_protocol::postcard_rpc::header::{VarHeader, VarKey};
    use fpm_protocol::postcard_rpc::Endpoint;
    let raw = cobs::decode_vec(frame.strip_suffix(&[0])?).ok()?;
    let (header, _) = VarHeader::take_from_slice(&raw)?;
    if header.key != VarKey::Key8(fpm_protocol::VersionEndpoint::RESP_KEY) {
        return None;
    }
    let mut answer = header.write_to_vec();
    answer.extend(postcard::to_stdvec(&version).ok()?);
    let mut out = cobs::encode_vec(&answer);
    out.push(0);
    Some(out)
}

/// The emulated board as `args` describe it.
fn board(args: &EmulatorOptions) -> Result<BoardConfig> {
    let mut board = BoardConfig::PICO_21X21;
    board.name = "fpm-emulator";
    board.geometry.rows = args.rows;
    board.geometry.cols = args.cols;
    board.geometry.center = fpm_protocol::LedIndex::new(args.rows / 2, args.cols / 2);
    board.geometry.lanes = args.lanes;
    board.max_current_ma = args.max_current_ma;
    board
        .validate()
        .map_err(|e| anyhow::anyhow!("invalid board: {e}"))?;
    Ok(board)
}

/// Whether the host asked the board to restart in BOOTSEL (then said so). A board
/// leaves its serial port there for the boot ROM's USB mode; there is no boot device
/// to emulate, so the emulator ends as the port does (a supervisor, as `fpm serve
/// --virtual`'s, starts it again as a flashed board would come back).
fn left_for_bootsel(
    device: &Device<EmulatedStrip, EmulatedTrigger, EmulatedFlash>,
    link: &std::path::Path,
) -> bool {
    if device.bootsel_requested() {
        // As the firmware does: the reply out to the host, the chain latched off.
        std::thread::sleep(Duration::from_millis(50));
        tracing::info!(
            "restarting in BOOTSEL, as asked: every LED off; a board now leaves {} and appears as the RP2040's boot device (USB 2e8a:0003); the emulator, which has none, stops",
            link.display()
        );
    }
    device.bootsel_requested()
}

/// Hand trigger-line changes to the camera, stamped with the time they happened, and
/// publish each active edge with what is lit on the virtual rig.
fn stamp_trigger(
    device: &Device<EmulatedStrip, EmulatedTrigger, EmulatedFlash>,
    mut camera: Option<&mut Camera>,
    now: u64,
    rig: Option<&fpm_rig_bus::PulsePublisher>,
    pulses: &mut u64,
) {
    let changes = device.trigger().take_changes();
    if changes.is_empty() {
        return;
    }
    let active_level = device.trigger_polarity() == fpm_protocol::Polarity::ActiveHigh;
    for level in changes {
        tracing::debug!(
            "trigger out {} at {now} µs",
            if level { "high" } else { "low" }
        );
        if let Some(cam) = camera.as_deref_mut() {
            cam.trigger_line(level, now, active_level);
        }
        if let (Some(rig), true) = (rig, level == active_level) {
            let lit = device.strip().lit(fpm_rig_bus::MAX_LIT);
            let pulse = fpm_rig_bus::TriggerPulse::new(
                *pulses,
                now,
                lit.into_iter()
                    .map(|(r, c, rgb)| (r, c, [rgb.r, rgb.g, rgb.b])),
            );
            if let Err(e) = rig.publish(&pulse) {
                tracing::warn!("virtual rig: {e}");
            }
            *pulses += 1;
        }
    }
}
