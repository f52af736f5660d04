//! `fpm camera`: real cameras into the frame contract.

use anyhow::Result;
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
    Run(Box<fpm_camera::run::RunArgs>),
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
            let summary = fpm_camera::run::run(*args)?;
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
