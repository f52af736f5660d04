//! `fpm camera run --aravis`: a GenICam camera publishing into the frame contract.
//! Buffers go back to the stream as soon as their pixels are in shared memory; a
//! camera that stops answering ends the run with an error naming it.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use fpm_frames::{FrameHeader, FramePublisher, ServiceNames};

use crate::aravis::{Aravis, Camera, Stream, StreamStats};
use crate::pixels::{decode, decode_channel, Channel, PixelFormat};
use crate::settings::{AppliedSettings, CameraSettings};

/// Run a GenICam camera (through aravis) as an fpm camera.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// The camera: its aravis device id, or its IP address (by address nothing is
    /// broadcast: aravis asks that address only).
    pub aravis: String,
    /// Publish frames as this camera (`fpm/camera/<ID>/frames`).
    pub camera: String,
    /// Camera settings (TOML: pixel_format, exposure_us, gain, roi, binning, trigger,
    /// trigger_activation); flags override it.
    pub config: Option<PathBuf>,
    /// PixelFormat (Mono8, Mono10/12/14/16, Mono10p/12p, Mono10Packed/12Packed).
    pub pixel_format: Option<String>,
    /// ExposureTime, µs.
    pub exposure_us: Option<f64>,
    /// Gain (the camera's unit, usually dB).
    pub gain: Option<f64>,
    /// Region of interest: X,Y,WIDTH,HEIGHT.
    pub roi: Option<[i32; 4]>,
    /// Binning, both directions.
    pub binning: Option<i32>,
    /// Trigger source for each frame: Line0 (the LED controller's trigger-out wired to
    /// the camera), Software, any source the camera offers, or Off (free running).
    pub trigger: Option<String>,
    /// TriggerActivation (RisingEdge, FallingEdge, ...).
    pub trigger_activation: Option<String>,
    /// Colour sensors (Bayer pixel formats): publish this channel (R, G or B), its own
    /// pixels, one per 2 × 2 cell (half the size, twice the pitch).
    pub channel: Option<String>,
    /// Fire a software trigger on each trigger-out pulse of this virtual rig
    /// (`fpm emulator --rig NAME`): a stand-in for the trigger cable. Sets the trigger
    /// to Software.
    pub rig: Option<String>,
    /// Buffers queued on the stream.
    pub buffers: usize,
    /// Stop after this many frames.
    pub frames: Option<u64>,
    /// Write the settings in force (read back from the camera) here, as JSON.
    pub settings_out: Option<PathBuf>,
    /// Seconds without a frame or an answer after which the camera counts as gone.
    pub lost_after_s: f64,
}

impl RunOptions {
    /// The settings asked for: the file, then the flags.
    pub fn settings(&self) -> Result<CameraSettings> {
        let file = match &self.config {
            Some(path) => CameraSettings::load(path)?,
            None => CameraSettings::default(),
        };
        let trigger = match (&self.rig, &self.trigger) {
            (Some(_), Some(t)) if !t.eq_ignore_ascii_case("software") => {
                bail!("--rig fires software triggers; it cannot go with --trigger {t}")
            }
            (Some(_), _) => Some("Software".to_owned()),
            (None, t) => t.clone(),
        };
        Ok(file.overridden_by(CameraSettings {
            pixel_format: self.pixel_format.clone(),
            exposure_us: self.exposure_us,
            gain: self.gain,
            roi: self.roi,
            binning: self.binning,
            trigger,
            trigger_activation: self.trigger_activation.clone(),
            channel: self.channel.clone(),
        }))
    }
}

/// What a run did.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct RunSummary {
    /// Frames published.
    pub published: u64,
    /// Buffers that arrived incomplete (a gap in frame numbers each).
    pub incomplete: u64,
    /// Software triggers fired for the rig.
    pub triggers: u64,
    /// The stream's counters at the end.
    pub stream: StreamStats,
    /// Per published frame, µs from the filled buffer leaving the stream to the frame
    /// being sent to the subscribers (decode into shared memory, send, signal).
    pub handoff_us: Vec<f64>,
    /// This process's CPU time per published frame, ms (Linux; None elsewhere).
    pub cpu_ms_per_frame: Option<f64>,
}

impl RunSummary {
    /// The hand-off time at quantile `q` (0–1), µs.
    pub fn handoff_quantile_us(&self, q: f64) -> Option<f64> {
        let mut t = self.handoff_us.clone();
        if t.is_empty() {
            return None;
        }
        t.sort_by(f64::total_cmp);
        Some(t[((t.len() - 1) as f64 * q).round() as usize])
    }
}

/// CPU time this process has used, s (user + system, from /proc; None elsewhere).
fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name (which may contain spaces) in parentheses.
    let rest = stat.rsplit_once(')')?.1;
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let utime: f64 = fields.get(11)?.parse().ok()?;
    let stime: f64 = fields.get(12)?.parse().ok()?;
    // The kernel's USER_HZ is 100 on every Linux configuration in use.
    Some((utime + stime) / 100.0)
}

/// Pulses that each fire one software trigger: a stand-in for the trigger cable (a
/// virtual rig's trigger-out). The caller wires them, so the driver knows nothing of
/// where they come from.
pub trait TriggerPulses {
    /// Whether a pulse is waiting now (taken: each `true` fires one trigger).
    fn take(&mut self) -> Result<bool>;
}

/// What drives a run from outside the driver.
pub struct Hooks<'a> {
    /// With [`RunOptions::rig`]: the pulses to trigger on.
    pub pulses: Option<&'a mut dyn TriggerPulses>,
    /// Polled between frames: true ends the run (a signal, say).
    pub stop: &'a dyn Fn() -> bool,
}

/// Run until `hooks.stop`, `--frames`, or the camera is lost (an error).
pub fn run(args: RunOptions, hooks: Hooks<'_>) -> Result<RunSummary> {
    if args.rig.is_some() != hooks.pulses.is_some() {
        bail!(
            "camera {}: RunOptions::rig ({:?}) and Hooks::pulses go together: the rig's name sets the trigger to Software, its pulses fire it",
            args.aravis,
            args.rig
        );
    }
    let settings = args.settings()?;
    let aravis = Aravis::load()?;
    let camera = aravis.open(&args.aravis)?;
    settings
        .apply(&camera)
        .with_context(|| format!("configuring camera {}", args.aravis))?;
    let mut applied = AppliedSettings::read(&camera)?;
    let channel = colour_channel(&args.aravis, &settings, &mut applied)?;
    tracing::info!(
        "camera {} {} (serial {}): {} {}x{} at ({}, {}), binning {}x{}, exposure {}, gain {:?}, trigger {} {}",
        applied.vendor,
        applied.model,
        applied.serial,
        applied.pixel_format,
        applied.roi[2],
        applied.roi[3],
        applied.roi[0],
        applied.roi[1],
        applied.binning[0],
        applied.binning[1],
        applied
            .exposure_us
            .map_or("per frame".to_string(), |us| format!("{us} µs")),
        applied.gain,
        applied.trigger_mode.as_deref().unwrap_or("?"),
        applied.trigger_source.as_deref().unwrap_or("")
    );
    if applied.bit_depth.is_none() {
        bail!(
            "camera {}: pixel format {} cannot be decoded (choose Mono8/10/12/14/16, Mono10p/12p or Mono10Packed/12Packed with --pixel-format)",
            args.aravis,
            applied.pixel_format
        );
    }
    match applied.encoding_gamma {
        Some(g) if (g - 1.0).abs() > 1e-6 => tracing::warn!(
            "camera {}: its gamma is on (frames encoded for display, decoded with {g:.3} as the dataset will state); decoding undoes the curve but not its rounding: for raw counts set Gamma to 1 or GammaEnable to false",
            args.aravis
        ),
        None => tracing::warn!(
            "camera {}: a lookup table is on (LUTEnable), so its frames may not be linear in the light and the dataset cannot state how; `fpm reconstruct` reads a gamma from the frames, but for raw counts set LUTEnable to false",
            args.aravis
        ),
        Some(_) => {}
    }
    if let Some(path) = &args.settings_out {
        std::fs::write(path, serde_json::to_string_pretty(&applied)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    let names = ServiceNames::for_camera(&args.camera);
    // For the acquisition's record (acquisition.json): what the camera applied.
    let settings_channel =
        fpm_frames::SettingsPublisher::create(&names, &serde_json::to_string(&applied)?)?;
    let max_pixels =
        (applied.published_size[0].max(1) as usize) * (applied.published_size[1].max(1) as usize);
    let publisher = FramePublisher::create(&names, max_pixels)?;
    let stream = camera.stream()?;
    let payload = camera.payload()?;
    for _ in 0..args.buffers.max(2) {
        stream.push(stream.new_buffer(payload)?);
    }
    camera.start()?;
    let cpu_at_start = cpu_seconds();
    tracing::info!(
        "publishing on {} ({} buffers of {payload} bytes)",
        names.frames,
        args.buffers
    );
    let ends = Ends {
        camera: &camera,
        stream: &stream,
        publisher: &publisher,
        settings: &settings_channel,
    };
    let result = stream_frames(&args, channel, &ends, hooks, &applied);
    let stats = stream.stats();
    if let Err(e) = camera.stop() {
        tracing::debug!("stopping the acquisition: {e}");
    }
    log_stats(&stats);
    let mut summary = result?;
    summary.stream = stats;
    if let (Some(a), Some(b)) = (cpu_at_start, cpu_seconds()) {
        if summary.published > 0 {
            summary.cpu_ms_per_frame = Some((b - a) * 1e3 / summary.published as f64);
        }
    }
    if let (Some(p50), Some(p99)) = (
        summary.handoff_quantile_us(0.5),
        summary.handoff_quantile_us(0.99),
    ) {
        tracing::info!(
            "hand-off, camera buffer to subscribers: p50 {p50:.0} µs, p99 {p99:.0} µs over {} frames of {}x{}; CPU {} per frame",
            summary.handoff_us.len(),
            applied.roi[2],
            applied.roi[3],
            summary
                .cpu_ms_per_frame
                .map_or("n/a".into(), |c| format!("{c:.2} ms"))
        );
    }
    Ok(summary)
}

/// The channel to publish: required for a colour mosaic, refused for a mono format;
/// recorded in `applied` with the published size.
fn colour_channel(
    camera: &str,
    settings: &CameraSettings,
    applied: &mut AppliedSettings,
) -> Result<Option<Channel>> {
    let asked = match &settings.channel {
        Some(c) => Some(c.parse::<Channel>().map_err(anyhow::Error::msg)?),
        None => None,
    };
    match (&applied.bayer, asked) {
        (Some(pattern), None) => bail!(
            "camera {camera}: pixel format {} is a colour mosaic ({pattern}); choose the channel the LEDs light with --channel R|G|B",
            applied.pixel_format
        ),
        (None, Some(_)) => bail!(
            "camera {camera}: --channel is for colour mosaics, and {} is not one",
            applied.pixel_format
        ),
        (Some(_), Some(ch)) => {
            let [_, _, w, h] = applied.roi;
            if w % 2 == 1 || h % 2 == 1 {
                bail!("camera {camera}: a mosaic's channel needs an even region, not {w}x{h}");
            }
            applied.channel = Some(format!("{ch:?}"));
            applied.published_size = [w / 2, h / 2];
            applied.published_pixel_factor = 2;
            Ok(Some(ch))
        }
        (None, None) => Ok(None),
    }
}

fn log_stats(s: &StreamStats) {
    tracing::info!(
        "stream: {} completed, {} failed, {} underruns, {} packets resent, {} missing",
        s.completed,
        s.failures,
        s.underruns,
        s.resent_packets,
        s.missing_packets
    );
}

/// Both ends of the driver: the camera and its stream, the frame contract's services.
struct Ends<'a> {
    camera: &'a Camera,
    stream: &'a Stream,
    publisher: &'a FramePublisher,
    settings: &'a fpm_frames::SettingsPublisher,
}

fn stream_frames(
    args: &RunOptions,
    channel: Option<Channel>,
    ends: &Ends<'_>,
    hooks: Hooks<'_>,
    applied: &AppliedSettings,
) -> Result<RunSummary> {
    let Hooks { mut pulses, stop } = hooks;
    let Ends {
        camera,
        stream,
        publisher,
        settings: settings_channel,
    } = *ends;
    let mut summary = RunSummary::default();
    let mut frame_number = 0u64;
    // A GenICam camera's exposure, read back when the settings were (always there).
    let exposure_us = applied
        .exposure_us
        .unwrap_or(0.0)
        .round()
        .clamp(0.0, u32::MAX as f64) as u32;
    let lost_after = Duration::from_secs_f64(args.lost_after_s.max(0.5));
    let mut last_sign_of_life = Instant::now();
    let mut last_stats = Instant::now();
    let poll = if pulses.is_some() {
        Duration::from_millis(1)
    } else {
        Duration::from_millis(20)
    };
    while !stop() {
        if args.frames.is_some_and(|n| summary.published >= n) {
            break;
        }
        settings_channel.serve();
        if let Some(pulses) = pulses.as_deref_mut() {
            while pulses.take()? {
                camera
                    .software_trigger()
                    .with_context(|| format!("camera {} is gone", args.aravis))?;
                summary.triggers += 1;
            }
        }
        let Some(buffer) = stream.pop(poll) else {
            if last_sign_of_life.elapsed() >= lost_after {
                // Idle, or gone? Ask it something.
                camera.exposure_us().with_context(|| {
                    format!(
                        "camera {} stopped answering after {} frames",
                        args.aravis, summary.published
                    )
                })?;
                last_sign_of_life = Instant::now();
            }
            continue;
        };
        last_sign_of_life = Instant::now();
        if !buffer.is_complete() {
            tracing::warn!(
                "frame {frame_number} arrived incomplete (aravis status {}): dropped",
                buffer.status()
            );
            summary.incomplete += 1;
            frame_number += 1;
            stream.push(buffer);
            continue;
        }
        let popped = Instant::now();
        let (width, height, code) = buffer.image();
        let format =
            PixelFormat::from_pfnc(code).with_context(|| format!("camera {}", args.aravis))?;
        let (out_w, out_h) = match channel {
            Some(_) => (width / 2, height / 2),
            None => (width, height),
        };
        let header = FrameHeader {
            frame_number,
            timestamp_ns: buffer.timestamp_ns(),
            exposure_us,
            width: out_w,
            height: out_h,
            bit_depth: format.bit_depth(),
            ..FrameHeader::default()
        };
        let sent = publisher.publish_filled(header, |dst| match channel {
            Some(ch) => decode_channel(format, width, height, buffer.data(), ch, dst),
            None => decode(format, width, height, buffer.data(), dst),
        });
        summary
            .handoff_us
            .push(popped.elapsed().as_secs_f64() * 1e6);
        stream.push(buffer);
        sent.with_context(|| format!("publishing frame {frame_number}"))?;
        summary.published += 1;
        frame_number += 1;
        if last_stats.elapsed() >= Duration::from_secs(10) {
            last_stats = Instant::now();
            log_stats(&stream.stats());
        }
    }
    Ok(summary)
}

/// `fpm camera list`: one camera asked by address (no broadcast), or every camera
/// aravis discovers.
pub fn list(address: Option<&str>) -> Result<Vec<crate::aravis::DeviceInfo>> {
    let aravis = Aravis::load()?;
    match address {
        Some(address) => {
            let camera = aravis.open(address)?;
            Ok(vec![crate::aravis::DeviceInfo {
                id: camera.device_id().unwrap_or_default(),
                address: address.to_owned(),
                vendor: camera.vendor().unwrap_or_default(),
                model: camera.model().unwrap_or_default(),
                serial: camera.serial().unwrap_or_default(),
                protocol: if camera.is_gige() {
                    "GigEVision".into()
                } else {
                    String::new()
                },
            }])
        }
        None => Ok(aravis.discover()),
    }
}
