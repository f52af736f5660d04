//! `fpm serve`: the acquisition service on this machine's rig, or on a virtual rig it
//! starts itself (`--virtual`).

use std::io::Write;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::Args;
use fpm_acquire::controller::discover;
use fpm_acquire::{FocusStage, StageChoice};
use fpm_frames::ServiceNames;
use fpm_rig::process::VirtualRig;
use fpm_rig::stage::VirtualStage;
use fpm_serve::{Config, Rig, StageFactory, DEFAULT_PORT};

use crate::stage::StageArgs;

/// Run the acquisition service: a local HTTP/JSON API (OpenAPI at /openapi.json) that
/// queues jobs on the rig, with an event stream of their progress.
#[derive(Args, Debug)]
pub struct ServeArgs {
    /// Where to listen (loopback unless --public; port 0 picks a free one).
    #[arg(long, default_value_t = SocketAddr::from(([127, 0, 0, 1], DEFAULT_PORT)))]
    pub listen: SocketAddr,
    /// Allow a non-loopback --listen address (every request then needs the token as
    /// well).
    #[arg(long)]
    pub public: bool,
    /// Where the job database and the token live (default: $XDG_STATE_HOME/fpm, else
    /// ~/.local/state/fpm).
    #[arg(long)]
    pub state_dir: Option<PathBuf>,
    /// Start a virtual rig (emulated controller, virtual camera, virtual stage) as this
    /// service's children, stopped with it.
    #[arg(long, conflicts_with_all = ["port", "frames", "rig", "stage"])]
    pub r#virtual: bool,
    /// With --virtual: the virtual camera's sensor side, pixels.
    #[arg(long, default_value_t = 256, requires = "virtual")]
    pub virtual_size: usize,
    /// With --virtual: run the real firmware image (the UF2 users flash) in an emulated
    /// RP2040 as the controller, as `fpm demo --firmware` does, instead of the
    /// host-compiled controller logic.
    #[arg(long, value_name = "UF2", requires = "virtual")]
    pub virtual_firmware: Option<PathBuf>,
    /// With --virtual: the sample is a slide this wide, µm, larger than one field, and
    /// the stage's X and Y move over it (for scans); the stage misses each position by
    /// up to --virtual-stage-error-um. Absent: one field, wherever the stage is.
    #[arg(long, requires = "virtual")]
    pub virtual_slide_um: Option<f64>,
    /// With --virtual-slide-um: the virtual stage's hidden position error, µm.
    #[arg(long, default_value_t = 10.0, requires = "virtual_slide_um")]
    pub virtual_stage_error_um: f64,
    /// The LED controller's serial port (omitted: the one board connected).
    #[arg(long, env = "FPM_PORT")]
    pub port: Option<String>,
    /// The camera whose frames to take (`fpm/camera/<NAME>/frames` on iceoryx2).
    #[arg(long, default_value = "0")]
    pub frames: String,
    /// The focus stage, moved for calibration.
    #[command(flatten)]
    pub stage: StageArgs,
}

/// Run `fpm serve`.
pub fn run(a: ServeArgs) -> Result<()> {
    let state_dir = match &a.state_dir {
        Some(d) => d.clone(),
        None => default_state_dir()?,
    };
    // Before anything is written in it (the virtual rig's files too).
    fpm_serve::private_dir(&state_dir)?;
    // The virtual rig's processes live as long as this one (and die with it).
    let mut supervisor = None;
    let rig = if a.r#virtual {
        let (rig, started) = virtual_rig(&a, &state_dir)?;
        supervisor = Some(Supervisor::start(started)?);
        rig
    } else {
        real_rig(&a)?
    };
    let config = Config {
        listen: a.listen,
        state_dir,
        public: a.public,
    };
    fpm_serve::serve(config, rig, |started| {
        // One write, and a closed stdout (a launcher that read the first line and
        // went) is no reason for the service to stop.
        let text = format!(
            "fpm serve: listening on http://{}\ntoken (for requests that change the rig): {}\nthe page: {}\n",
            started.address,
            started.token_file.display(),
            started.page
        );
        let mut stdout = std::io::stdout();
        let _ = stdout
            .write_all(text.as_bytes())
            .and_then(|()| stdout.flush());
    })?;
    drop(supervisor);
    Ok(())
}

/// The virtual rig `fpm serve --virtual` starts beside itself (its processes, to be
/// supervised), and the service's view of it.
fn virtual_rig(a: &ServeArgs, state_dir: &Path) -> Result<(Rig, VirtualRig)> {
    let fpm = std::env::current_exe().context("locating the fpm executable")?;
    let name = format!("serve-{}", std::process::id());
    let size = a.virtual_size.to_string();
    let mut camera = vec!["--size".to_string(), size.clone()];
    if let Some(w) = a.virtual_slide_um {
        camera.extend([
            "--slide-um".into(),
            w.to_string(),
            "--stage-error-um".into(),
            a.virtual_stage_error_um.to_string(),
        ]);
    }
    let camera: Vec<&str> = camera.iter().map(String::as_str).collect();
    let started = VirtualRig::start_with_firmware(
        &fpm,
        &name,
        &state_dir.join("virtual-rig"),
        a.virtual_firmware.as_deref(),
        &camera,
    )?;
    let controller = match &a.virtual_firmware {
        Some(uf2) => format!("the firmware image {} in an emulated RP2040", uf2.display()),
        None => "emulated controller".to_string(),
    };
    let rig = Rig {
        port: started.emulator.port(),
        camera: ServiceNames::for_camera(&name),
        stage: virtual_stage(name.clone()),
        description: format!(
            "virtual rig {name}: {controller}, virtual {size}² camera, virtual stage"
        ),
    };
    Ok((rig, started))
}

/// The rig on this machine: the board on `--port` (or the only one plugged in), the
/// camera on `--frames`, the stage as `--stage` names it.
fn real_rig(a: &ServeArgs) -> Result<Rig> {
    let port = match &a.port {
        Some(p) => p.clone(),
        None => discover::the_only_board(std::time::Duration::from_secs(2))
            .map_err(anyhow::Error::msg)?,
    };
    // Each job opens the stage anew (and fails early here if it cannot be named).
    if a.stage.stage == StageChoice::Virtual && a.stage.rig.is_none() {
        anyhow::bail!("--stage virtual needs --rig NAME");
    }
    let args = a.stage.clone();
    let stage: StageFactory = Box::new(move || args.open_focus());
    Ok(Rig {
        description: format!("controller on {port}, camera {}", a.frames),
        port,
        camera: ServiceNames::for_camera(&a.frames),
        stage,
    })
}

/// A thread that starts the virtual rig's processes again when they exit (killed,
/// crashed), as a board plugged back in would come back; it stops the rig when dropped.
struct Supervisor {
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Supervisor {
    fn start(mut rig: VirtualRig) -> Result<Self> {
        use std::sync::atomic::Ordering;
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let flag = stop.clone();
        let thread = std::thread::Builder::new()
            .name("fpm-serve-virtual-rig".into())
            .spawn(move || {
                while !flag.load(Ordering::SeqCst) {
                    if let Err(e) = rig.revive() {
                        tracing::error!("the virtual rig could not be started again: {e:#}");
                    }
                    std::thread::sleep(std::time::Duration::from_millis(200));
                }
                drop(rig);
            })?;
        Ok(Self {
            stop,
            thread: Some(thread),
        })
    }
}

impl Drop for Supervisor {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn virtual_stage(rig: String) -> StageFactory {
    Box::new(move || Ok(Box::new(VirtualStage::open(&rig)?) as Box<dyn FocusStage>))
}

/// $XDG_STATE_HOME/fpm, else ~/.local/state/fpm.
pub(crate) fn default_state_dir() -> Result<PathBuf> {
    if let Some(d) = std::env::var_os("XDG_STATE_HOME").filter(|d| !d.is_empty()) {
        return Ok(PathBuf::from(d).join("fpm"));
    }
    let home = std::env::var_os("HOME")
        .context("no HOME to keep the service's state in; give --state-dir")?;
    Ok(PathBuf::from(home).join(".local/state/fpm"))
}
