//! # fpm-serve
//!
//! The acquisition service: one long-lived process owns the rig (controller, camera,
//! focus stage), runs jobs from a queue one at a time, keeps their history in SQLite,
//! and answers an HTTP/JSON API on 127.0.0.1 with its OpenAPI document and a
//! server-sent event stream of progress. The acquisition itself is
//! `fpm_acquire`'s sans-IO state machine, driven by its usual loop on the worker
//! thread; this crate is only the edges around it:
//!
//! * [`store`]: the jobs and their state transitions in a SQLite file (WAL);
//! * [`worker`]: the thread that owns the rig and runs one job at a time, with cancel;
//! * [`live`]: the newest snapshots of the reconstructions and camera frames, for viewers;
//! * [`api`]: the HTTP routes, their checks (token, Host, Origin) and the OpenAPI
//!   document;
//! * [`serve`]: all of it on a tokio runtime until SIGINT/SIGTERM;
//! * [`client`]: a minimal blocking client of the API (tests, benchmarks, the demo).

pub mod api;
pub mod board;
pub mod client;
pub mod error;
pub mod jobs;
pub mod live;
pub mod store;
pub mod worker;

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{bail, Context, Result};
use fpm_acquire::FocusStage;
use fpm_frames::ServiceNames;

/// The port `fpm serve` listens on unless told otherwise.
pub const DEFAULT_PORT: u16 = 8737;

/// Makes the focus stage on the worker thread (iceoryx2 ports stay on the thread that
/// made them, so the stage is made where it is used).
pub type StageFactory = Box<dyn Fn() -> Result<Box<dyn FocusStage>> + Send + Sync>;

/// The rig the service owns.
pub struct Rig {
    /// The LED controller's serial port.
    pub port: String,
    /// The camera whose frames to take.
    pub camera: ServiceNames,
    /// How to make the focus stage.
    pub stage: StageFactory,
    /// What the rig is, in words, for `GET /api/status`.
    pub description: String,
}

/// How the service runs.
pub struct Config {
    /// Where it listens (127.0.0.1 unless a user asks otherwise).
    pub listen: SocketAddr,
    /// Where the job database and the token live.
    pub state_dir: PathBuf,
    /// Allow an address other than loopback (`--public`).
    pub public: bool,
}

/// What a started service tells its front end.
pub struct Started<'a> {
    /// The address it listens on (the port resolved when 0 was asked for).
    pub address: SocketAddr,
    /// The file holding the token that requests changing the rig must carry.
    pub token_file: &'a Path,
    /// The page's address with the token in it, for a person to open (as Jupyter's).
    pub page: String,
}

/// `dir` created if needed and made the owner's alone (0700), as Jupyter keeps its
/// runtime directory: it holds the token, the job history with its paths, and the runs.
/// A directory an older service made readable to all is tightened, and the log says so.
pub fn private_dir(dir: &std::path::Path) -> Result<()> {
    use std::os::unix::fs::{DirBuilderExt, PermissionsExt};
    std::fs::DirBuilder::new()
        .recursive(true)
        .mode(0o700)
        .create(dir)
        .with_context(|| format!("creating {}", dir.display()))?;
    let mode = std::fs::metadata(dir)
        .with_context(|| format!("reading {}", dir.display()))?
        .permissions()
        .mode()
        & 0o777;
    if mode & 0o077 != 0 {
        std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o700))
            .with_context(|| format!("making {} private (chmod 700)", dir.display()))?;
        tracing::info!(
            "made {} readable by its owner alone (it was {mode:o})",
            dir.display()
        );
    }
    Ok(())
}

/// Run the service until SIGINT or SIGTERM: `on_started` once it listens.
pub fn serve(config: Config, rig: Rig, on_started: impl FnOnce(Started<'_>)) -> Result<()> {
    if !config.listen.ip().is_loopback() && !config.public {
        bail!(
            "{}: not a loopback address; the service listens on 127.0.0.1 unless --public is given (then every request needs the token)",
            config.listen
        );
    }
    private_dir(&config.state_dir)?;
    let store = store::Store::open(&config.state_dir.join("jobs.sqlite"))?;
    recover_interrupted(&store);
    let token = api::Token::create(&config.state_dir.join("token"))?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the service's runtime")?;
    runtime.block_on(async move {
        let listener = tokio::net::TcpListener::bind(config.listen)
            .await
            .with_context(|| format!("listening on {}", config.listen))?;
        let address = listener.local_addr()?;
        let (stopping_tx, stopping_rx) = tokio::sync::watch::channel(false);
        let shared = Arc::new(worker::Shared::new(
            store,
            rig.description.clone(),
            rig.camera.clone(),
            config.state_dir.join("runs"),
            fpm_frames::snapshot_service_name(address.port()),
            rig.port.clone(),
        ));
        let worker = worker::Worker::start(shared.clone(), rig)?;
        let state = api::State {
            shared: shared.clone(),
            worker: worker.handle(),
            token: Arc::new(token),
            address,
            public: config.public,
            stopping: stopping_rx,
        };
        on_started(Started {
            address,
            token_file: &state.token.path,
            page: format!("http://{address}/?token={}", state.token.value()),
        });
        let app = api::router(state);
        axum::serve(listener, app)
            .with_graceful_shutdown(async move {
                shutdown_signal().await;
                // Event streams never end by themselves: they end now, so that the
                // requests in flight can finish and the service stop.
                let _ = stopping_tx.send(true);
            })
            .await
            .context("serving")?;
        tracing::info!("stopping: the running job is cancelled, its frames so far written");
        worker.stop();
        Ok(())
    })
}

/// The frames of jobs a killed service left mid-capture, made partial datasets (see
/// `fpm_acquire::journal`); each job's error says what was recovered.
fn recover_interrupted(store: &store::Store) {
    for &id in store.interrupted_at_open() {
        let Ok(Some(job)) = store.get(id) else {
            continue;
        };
        let out = Path::new(&job.out);
        let said = match fpm_acquire::journal::recover(out) {
            Ok(Some(n)) if n > 0 => format!(
                "the service stopped while the job ran; the {n} frames it had taken are a partial dataset in {} (the LEDs without a frame are missing from it); resume it (POST /api/jobs/{}/resume, fpm.Client.resume) to light only those",
                out.display(),
                id
            ),
            Ok(_) => "the service stopped while the job ran, before any frame of its capture could be labelled; queue it again".into(),
            Err(e) => format!(
                "the service stopped while the job ran, and its frames in {} could not be recovered ({e:#}); queue it again",
                out.display()
            ),
        };
        tracing::warn!("job {id}: {said}");
        if let Err(e) = store.set_error(id, &said) {
            tracing::error!("job {id}: {e:#}");
        }
    }
}

/// SIGINT or SIGTERM.
async fn shutdown_signal() {
    use tokio::signal::unix::{signal, SignalKind};
    let (Ok(mut int), Ok(mut term)) = (
        signal(SignalKind::interrupt()),
        signal(SignalKind::terminate()),
    ) else {
        return std::future::pending().await;
    };
    tokio::select! {
        _ = int.recv() => {}
        _ = term.recv() => {}
    }
}
