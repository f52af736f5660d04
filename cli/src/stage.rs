//! `fpm stage`: motorised stages (GRBL, Marlin, Sangaboard) from the terminal, and the
//! `--stage` options every rig command shares.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use fpm_acquire::{FocusStage, ManualStage, MotorisedFocus, StageChoice, TowardLeds};
use fpm_rig::stage::VirtualStage;
use fpm_stage::{Connection, Limits, Stage, StageOptions, Target};
use fpm_stage_emulator::{Config, Emulator, Kind};

/// Which focus stage to use and how to drive it.
#[derive(Args, Debug, Clone)]
pub struct StageArgs {
    /// The focus stage: `manual` (asked on the terminal), `virtual` (the virtual rig's,
    /// with --rig), or a motorised stage: `gcode:PORT` (GRBL 1.1, Marlin 2) or
    /// `sangaboard:PORT` (OpenFlexure), `@BAUD` after the port if not 115200.
    #[arg(long, default_value = "manual")]
    pub stage: StageChoice,
    /// The virtual rig whose stage to move (with `--stage virtual`).
    #[arg(long)]
    pub rig: Option<String>,
    #[command(flatten)]
    pub motor: MotorArgs,
}

/// How to drive a motorised stage.
#[derive(Args, Debug, Clone)]
pub struct MotorArgs {
    /// Wait after each move for the mechanics to settle, ms.
    #[arg(long, default_value_t = 200)]
    pub stage_settle_ms: u64,
    /// The play in each axis's drive, µm, as X,Y,Z: targets are approached from below
    /// by this much, so the play is always taken up the same way.
    #[arg(long, value_parser = xyz, default_value = "0,0,0")]
    pub stage_backlash_um: XyzArg,
    /// A Sangaboard's travel per motor step on X,Y,Z, µm (measure it with a slide of
    /// known pitch; G-code firmware works in mm already).
    #[arg(long, value_parser = xyz)]
    pub stage_um_per_step: Option<XyzArg>,
    /// Limits of your own on top of the firmware's, µm in machine coordinates, e.g.
    /// `z=-2000:0,x=0:15000` (the slide holder's reach, the objective's clearance).
    #[arg(long)]
    pub stage_limits: Option<Limits>,
    /// The direction of the stage's Z that moves the sample toward the LEDs, relative
    /// to the objective (`minus` when Z raises the sample toward an objective above
    /// it; `plus` when Z raises that objective).
    #[arg(long, default_value = "minus")]
    pub stage_z_to_leds: TowardLeds,
}

/// Three numbers, X,Y,Z.
#[derive(Debug, Clone, Copy)]
pub struct XyzArg(pub [f64; 3]);

fn xyz(s: &str) -> Result<XyzArg, String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|t| t.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("`{s}`: give three numbers X,Y,Z"))?;
    match v[..] {
        [x, y, z] if v.iter().all(|v| v.is_finite() && *v >= 0.0) => Ok(XyzArg([x, y, z])),
        _ => Err(format!("`{s}`: give three numbers X,Y,Z, none negative")),
    }
}

impl MotorArgs {
    /// Open the motorised stage on `connection`.
    pub fn open(&self, connection: &Connection) -> Result<Box<dyn Stage>> {
        let options = StageOptions {
            settle: Duration::from_millis(self.stage_settle_ms),
            backlash_um: self.stage_backlash_um.0,
            limits: self.stage_limits.unwrap_or_default(),
            ..StageOptions::default()
        };
        if let Some(XyzArg(s)) = self.stage_um_per_step {
            if s.iter().any(|v| *v <= 0.0) {
                bail!("--stage-um-per-step: every axis needs a step size above 0");
            }
        }
        Ok(connection.open(options, self.stage_um_per_step.map(|s| s.0))?)
    }
}

impl StageArgs {
    /// The stage these options name, for a scan: it must move over the slide.
    pub fn open_scan(&self) -> Result<Box<dyn fpm_acquire::scan::ScanStage>> {
        self.open_motorised()?.context(
            "a scan needs a motorised stage: give --stage gcode:PORT, sangaboard:PORT, or virtual (with --rig)",
        )
    }

    /// The focus stage these options name.
    pub fn open_focus(&self) -> Result<Box<dyn FocusStage>> {
        Ok(match self.open_motorised()? {
            Some(stage) => stage,
            None => Box::new(ManualStage),
        })
    }

    /// The motorised stage these options name (None: `manual`).
    fn open_motorised(&self) -> Result<Option<Box<dyn fpm_acquire::scan::ScanStage>>> {
        Ok(match &self.stage {
            StageChoice::Manual => None,
            StageChoice::Virtual => Some(Box::new(VirtualStage::open(
                self.rig
                    .as_deref()
                    .context("--stage virtual needs --rig NAME")?,
            )?)),
            StageChoice::Motorised(c) => Some(Box::new(MotorisedFocus::new(
                self.motor.open(c)?,
                self.motor.stage_z_to_leds,
            ))),
        })
    }
}

/// Motorised stages from the terminal.
#[derive(Subcommand, Debug)]
pub enum StageCommand {
    /// Which firmware the stage runs, its limits and where it is.
    Info(StageCmdArgs),
    /// Move to a position (µm, machine coordinates); axes not given stay.
    Move(MoveArgs),
    /// Find the end stops (GRBL `$H`, Marlin `G28`); unlocks GRBL after an alarm.
    Home(StageCmdArgs),
    /// Emulate a stage's firmware on a pseudo-terminal (for trying fpm without one).
    Emulate(EmulateArgs),
}

/// A motorised stage.
#[derive(Args, Debug)]
pub struct StageCmdArgs {
    /// The stage: `gcode:PORT` (GRBL 1.1, Marlin 2) or `sangaboard:PORT`.
    #[arg(long)]
    pub stage: Connection,
    #[command(flatten)]
    pub motor: MotorArgs,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// `fpm stage move`.
#[derive(Args, Debug)]
pub struct MoveArgs {
    #[command(flatten)]
    pub on: StageCmdArgs,
    /// X, µm.
    #[arg(long, allow_hyphen_values = true)]
    pub x: Option<f64>,
    /// Y, µm.
    #[arg(long, allow_hyphen_values = true)]
    pub y: Option<f64>,
    /// Z, µm.
    #[arg(long, allow_hyphen_values = true)]
    pub z: Option<f64>,
}

/// `fpm stage emulate`.
#[derive(Args, Debug)]
pub struct EmulateArgs {
    /// The firmware: grbl, marlin or sangaboard.
    #[arg(long)]
    pub firmware: Kind,
    /// Also make this symlink to the terminal (e.g. /tmp/fpm-stage).
    #[arg(long)]
    pub link: Option<PathBuf>,
    /// The play in each axis's drive, µm, X,Y,Z.
    #[arg(long, value_parser = xyz, default_value = "0,0,0")]
    pub backlash_um: XyzArg,
}

/// Run `fpm stage …`.
pub fn run(cmd: StageCommand) -> Result<()> {
    match cmd {
        StageCommand::Info(a) => {
            let mut stage = a.motor.open(&a.stage)?;
            let info = stage.info();
            let at = stage.position()?;
            if a.json {
                println!("{}", serde_json::json!({ "info": info, "position": at }));
            } else {
                println!("{} on {}", info.firmware, info.port);
                println!("position: {at}");
                for axis in fpm_stage::Axis::ALL {
                    match info.limits.get(axis) {
                        Some(r) => println!("{axis} limits: {:.1} … {:.1} µm", r.min_um, r.max_um),
                        None => println!("{axis} limits: none (give --stage-limits)"),
                    }
                }
                println!("homing: {}", if info.can_home { "yes" } else { "no" });
            }
        }
        StageCommand::Move(a) => {
            if a.x.is_none() && a.y.is_none() && a.z.is_none() {
                bail!("give at least one of --x, --y, --z (µm)");
            }
            let mut stage = a.on.motor.open(&a.on.stage)?;
            let at = stage.move_to(Target {
                x_um: a.x,
                y_um: a.y,
                z_um: a.z,
            })?;
            print_position(at, a.on.json);
        }
        StageCommand::Home(a) => {
            let mut stage = a.motor.open(&a.stage)?;
            let at = stage.home()?;
            print_position(at, a.json);
        }
        StageCommand::Emulate(a) => {
            let mut config = Config::new(a.firmware);
            config.backlash_um = a.backlash_um.0;
            let emulator = Emulator::start(config, a.link.as_deref())?;
            let path = a
                .link
                .clone()
                .unwrap_or_else(|| emulator.path().to_path_buf());
            println!("{:?} stage emulated on {}", a.firmware, path.display());
            // Until Ctrl-C or SIGTERM; dropping the emulator removes the link.
            let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
            for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
                signal_hook::flag::register(signal, stop.clone())
                    .context("installing the signal handler")?;
            }
            while !stop.load(std::sync::atomic::Ordering::SeqCst) {
                std::thread::sleep(Duration::from_millis(100));
            }
        }
    }
    Ok(())
}

fn print_position(at: fpm_stage::Position, json: bool) {
    if json {
        println!("{}", serde_json::json!({ "position": at }));
    } else {
        println!("{at}");
    }
}
