//! `fpm camera`: real cameras into the frame contract.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Args, Subcommand};

/// Cameras.
#[derive(Subcommand, Debug)]
pub enum CameraCommand {
    /// List GenICam cameras (GigE Vision, USB3 Vision). Without --address this sends
    /// GigE Vision discovery broadcasts on every network interface; with it, only that
    /// address is asked.
    List(ListArgs),
    /// Run a GenICam camera through aravis, publishing every frame into
    /// `fpm/camera/<ID>/frames` with the camera's timestamp.
    Run(Box<RunArgs>),
}

/// `fpm camera list`.
#[derive(Args, Debug)]
pub struct ListArgs {
    /// Ask the camera at this IP address only (no broadcast).
    #[arg(long)]
    pub address: Option<String>,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// Run `fpm camera`.
pub fn run(cmd: CameraCommand) -> Result<()> {
    match cmd {
        CameraCommand::List(args) => {
            let cameras = fpm_camera::run::list(args.address.as_deref())?;
            if args.json {
                println!("{}", serde_json::to_string_pretty(&cameras)?);
            } else if cameras.is_empty() {
                println!("no GenICam camera found");
            } else {
                for c in &cameras {
                    println!(
                        "{}  {} {}  serial {}  {} {}",
                        c.id, c.vendor, c.model, c.serial, c.protocol, c.address
                    );
                }
            }
            Ok(())
        }
        CameraCommand::Run(args) => {
            fpm_rig_bus::stop::install().context("installing signal handlers")?;
            let mut rig = match &args.rig {
                Some(name) => Some(RigPulses(
                    fpm_rig_bus::RigListener::create(name)
                        .with_context(|| format!("listening to the virtual rig {name}"))?,
                )),
                None => None,
            };
            let hooks = fpm_camera::run::Hooks {
                pulses: rig
                    .as_mut()
                    .map(|r| r as &mut dyn fpm_camera::run::TriggerPulses),
                stop: &fpm_rig_bus::stop::requested,
            };
            let summary = fpm_camera::run::run(args.options(), hooks)?;
            tracing::info!(
                "camera stopped: {} frames published, {} incomplete, {} software triggers",
                summary.published,
                summary.incomplete,
                summary.triggers
            );
            Ok(())
        }
    }
}

/// `fpm camera run`: a GenICam camera (through aravis) as an fpm camera.
#[derive(Args, Debug, Clone)]
pub struct RunArgs {
    /// The camera: its aravis device id, or its IP address (by address nothing is
    /// broadcast: aravis asks that address only).
    #[arg(long, value_name = "DEVICE-ID-OR-IP")]
    pub aravis: String,
    /// Publish frames as this camera (`fpm/camera/<ID>/frames`).
    #[arg(long, default_value = "0")]
    pub camera: String,
    /// Camera settings (TOML: pixel_format, exposure_us, gain, roi, binning, trigger,
    /// trigger_activation); flags override it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// PixelFormat (Mono8, Mono10/12/14/16, Mono10p/12p, Mono10Packed/12Packed).
    #[arg(long)]
    pub pixel_format: Option<String>,
    /// ExposureTime, µs.
    #[arg(long)]
    pub exposure_us: Option<f64>,
    /// Gain (the camera's unit, usually dB).
    #[arg(long)]
    pub gain: Option<f64>,
    /// Region of interest: X,Y,WIDTH,HEIGHT.
    #[arg(long, value_parser = parse_roi)]
    pub roi: Option<[i32; 4]>,
    /// Binning, both directions.
    #[arg(long)]
    pub binning: Option<i32>,
    /// Trigger source for each frame: Line0 (the LED controller's trigger-out wired to
    /// the camera), Software, any source the camera offers, or Off (free running).
    #[arg(long)]
    pub trigger: Option<String>,
    /// TriggerActivation (RisingEdge, FallingEdge, ...).
    #[arg(long)]
    pub trigger_activation: Option<String>,
    /// Colour sensors (Bayer pixel formats): publish this channel (R, G or B), its own
    /// pixels, one per 2 × 2 cell (half the size, twice the pitch).
    #[arg(long)]
    pub channel: Option<String>,
    /// Fire a software trigger on each trigger-out pulse of this virtual rig
    /// (`fpm emulator --rig NAME`): a stand-in for the trigger cable. Sets the trigger
    /// to Software.
    #[arg(long)]
    pub rig: Option<String>,
    /// Buffers queued on the stream.
    #[arg(long, default_value_t = 8)]
    pub buffers: usize,
    /// Stop after this many frames.
    #[arg(long)]
    pub frames: Option<u64>,
    /// Write the settings in force (read back from the camera) here, as JSON.
    #[arg(long)]
    pub settings_out: Option<PathBuf>,
    /// Seconds without a frame or an answer after which the camera counts as gone.
    #[arg(long, default_value_t = 5.0)]
    pub lost_after_s: f64,
}

fn parse_roi(s: &str) -> Result<[i32; 4], String> {
    let v: Vec<i32> = s
        .split(',')
        .map(|p| p.trim().parse::<i32>())
        .collect::<Result<_, _>>()
        .map_err(|e| format!("{s}: {e} (expected X,Y,WIDTH,HEIGHT)"))?;
    <[i32; 4]>::try_from(v).map_err(|_| format!("{s}: expected X,Y,WIDTH,HEIGHT"))
}

/// A virtual rig's trigger-out pulses, each a software trigger (`--rig`).
struct RigPulses(fpm_rig_bus::RigListener);

impl fpm_camera::run::TriggerPulses for RigPulses {
    fn take(&mut self) -> Result<bool> {
        Ok(self.0.next_pulse(std::time::Duration::ZERO)?.is_some())
    }
}

impl RunArgs {
    fn options(&self) -> fpm_camera::run::RunOptions {
        fpm_camera::run::RunOptions {
            aravis: self.aravis.clone(),
            camera: self.camera.clone(),
            config: self.config.clone(),
            pixel_format: self.pixel_format.clone(),
            exposure_us: self.exposure_us,
            gain: self.gain,
            roi: self.roi,
            binning: self.binning,
            trigger: self.trigger.clone(),
            trigger_activation: self.trigger_activation.clone(),
            channel: self.channel.clone(),
            rig: self.rig.clone(),
            buffers: self.buffers,
            frames: self.frames,
            settings_out: self.settings_out.clone(),
            lost_after_s: self.lost_after_s,
        }
    }
}
