//! `fpm doctor`: the machine checked the way a support thread would (fpm-doctor), one
//! line per finding with the action to take.

use std::net::SocketAddr;
use std::path::PathBuf;

use anyhow::{bail, Result};
use clap::Args;
use fpm_doctor::{Options, Status};
use fpm_serve::DEFAULT_PORT;

/// Check this machine for fpm: the udev rule, access to the board's port and to an
/// RP2040 in BOOTSEL, the board and its firmware and protocol versions against this
/// host's, the cameras aravis sees, iceoryx2's shared memory, free disk, and the
/// service's port. Each line is ok, warn or fail, with the action to take; the exit
/// status is 1 when one fails.
#[derive(Args, Debug)]
pub struct DoctorArgs {
    /// The board's serial port (omitted: every board connected, and the ports in
    /// FPM_EXTRA_PORTS).
    #[arg(long, env = "FPM_PORT")]
    pub port: Option<String>,
    /// Where `fpm serve` keeps its state (default: $XDG_STATE_HOME/fpm, else
    /// ~/.local/state/fpm).
    #[arg(long)]
    pub state_dir: Option<PathBuf>,
    /// A directory jobs write to, checked for free space (repeatable).
    #[arg(long = "out")]
    pub out_dirs: Vec<PathBuf>,
    /// Where `fpm serve` would listen.
    #[arg(long, default_value_t = SocketAddr::from(([127, 0, 0, 1], DEFAULT_PORT)))]
    pub listen: SocketAddr,
    /// Ask the camera at this address only (no discovery broadcast on the networks).
    #[arg(long)]
    pub camera_address: Option<String>,
    /// Remove the iceoryx2 shared memory that crashed processes left (a live
    /// process's is never touched).
    #[arg(long)]
    pub clean_shm: bool,
    /// Print machine-readable JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: DoctorArgs) -> Result<()> {
    let options = Options {
        port: a.port,
        state_dir: match a.state_dir {
            Some(d) => d,
            None => crate::serve::default_state_dir()?,
        },
        out_dirs: a.out_dirs,
        listen: a.listen,
        camera_address: a.camera_address,
        clean_shm: a.clean_shm,
    };
    let findings = fpm_doctor::examine(&options);
    if a.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&serde_json::json!({
                "ok": !fpm_doctor::any_failed(&findings),
                "findings": findings,
            }))?
        );
    } else {
        for f in &findings {
            let status = match f.status {
                Status::Ok => "ok  ",
                Status::Warn => "warn",
                Status::Fail => "FAIL",
            };
            println!("{status}  {:<13} {}", f.check, f.found);
            if let Some(action) = &f.action {
                println!("      {:<13} → {action}", "");
            }
        }
    }
    let failed = findings.iter().filter(|f| f.status == Status::Fail).count();
    if failed > 0 {
        bail!("{failed} check(s) failed: see their actions above");
    }
    Ok(())
}
