//! The thread that owns the rig: it takes queued jobs one at a time, runs each with
//! `fpm_acquire::pipeline::acquire` (the acquisition's state machine and its loop),
//! and publishes progress as it goes. Cancelling sets the job's flag: the running
//! sequence is aborted on the controller, what was captured is written, and the job
//! ends `cancelled`. Pausing holds the rig between LEDs until resumed; a job that
//! ended part-way (interrupted, cancelled, failed) is completed by a `resume` job,
//! which lights only the LEDs its frames lack.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Result};
use fpm_acquire::controller::ControllerError;
use fpm_acquire::pipeline::Control;
use fpm_acquire::{Controller, Progress};
use fpm_frames::ServiceNames;
use serde::Serialize;
use tokio::sync::broadcast;
use utoipa::ToSchema;

use crate::board::Board;
use crate::jobs::{AcquireRequest, JobRequest, ScanRequest};
use crate::live::Live;
use crate::store::{JobState, Store};
use crate::Rig;

/// What the event stream carries: a job's state, its progress, each frame it
/// labelled, and the live images that are new.
#[derive(Debug, Clone, Serialize, ToSchema)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum Event {
    /// A job moved to `state`.
    State {
        job: i64,
        state: JobState,
        error: Option<String>,
    },
    /// How far the running job is; `eta_s` is the capture's time left (while it
    /// captures): the LEDs still to label at the step period the controller measures
    /// (`JobWatcher::eta_s`).
    Progress {
        job: i64,
        #[schema(value_type = Object)]
        progress: Progress,
        eta_s: Option<f64>,
    },
    /// A frame was labelled with its LED, (row, col).
    Frame { job: i64, led: [u8; 2] },
    /// A new snapshot of the job's reconstruction: `GET /api/jobs/{job}/snapshot/…`.
    Snapshot {
        job: i64,
        seq: u64,
        frames: usize,
        of: usize,
        finished: bool,
        width: usize,
        height: usize,
        pixel_um: f64,
    },
    /// A new camera frame for viewers (a few a second at most): `GET /api/camera/frame`.
    CameraFrame { job: i64, seq: u64, led: [u8; 2] },
    /// How far a job that does not acquire is (a reconstruction's frame updates), a
    /// few times a second.
    Work {
        job: i64,
        what: &'static str,
        done: usize,
        total: usize,
    },
}

/// An event as the stream sends it: with `at_s`, when the service published it (Unix
/// seconds), so a client can tell how late it got it.
#[derive(Debug, Clone, Serialize)]
pub struct Stamped {
    #[serde(flatten)]
    pub event: Event,
    pub at_s: f64,
}

/// How long a job waits for its LED controller to be there before failing.
pub const CONTROLLER_WAIT: Duration = Duration::from_secs(15);

/// The running job.
struct Running {
    id: i64,
    /// What kind of job (a reconstruction cannot be stopped part-way).
    kind: String,
    control: Control,
    progress: Option<Progress>,
    eta_s: Option<f64>,
}

/// What the API and the worker share.
pub struct Shared {
    /// The job database.
    pub store: Store,
    /// Events for every subscriber (a slow one misses some and is told so).
    pub events: broadcast::Sender<Stamped>,
    /// The rig, in words.
    pub rig: String,
    /// The rig's camera (a request's plan is checked against it when it comes in).
    pub camera: ServiceNames,
    /// Where jobs sent without an output directory write, each in one of its own.
    pub runs: std::path::PathBuf,
    /// The live images.
    pub live: Live,
    /// The iceoryx2 service the snapshots are published on for local viewers.
    pub snapshot_service: String,
    running: Mutex<Option<Running>>,
    /// The LED controller as last found ([`crate::board`]).
    board: Mutex<Board>,
    /// Held while a job has the controller open, so that the service's own look at
    /// it never opens the port beside a job.
    rig_in_use: Mutex<()>,
}

impl Shared {
    /// Nothing running yet.
    pub fn new(
        store: Store,
        rig: String,
        camera: ServiceNames,
        runs: std::path::PathBuf,
        snapshot_service: String,
        port: String,
    ) -> Self {
        Self {
            board: Mutex::new(Board::Unchecked { port }),
            rig_in_use: Mutex::new(()),
            snapshot_service,
            store,
            events: broadcast::channel(4096).0,
            rig,
            camera,
            runs,
            live: Live::default(),
            running: Mutex::new(None),
        }
    }

    /// The LED controller as last found.
    pub fn board(&self) -> Board {
        self.board.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    fn set_board(&self, board: Board) {
        let mut now = self.board.lock().unwrap_or_else(|e| e.into_inner());
        if *now != board {
            tracing::info!(
                "the LED controller: {}",
                serde_json::to_string(&board).unwrap_or_default()
            );
            *now = board;
        }
    }

    /// Look at the controller on `port` again, unless a job has it open (then what
    /// that job found stands); returns what is known. A board found on another
    /// protocol version stays so until it answers again: a look that could not reach
    /// it (unplugged, or the port still held by the last look's closing reader) says
    /// nothing about its firmware.
    pub fn check_board(&self, port: &str) -> Board {
        if let Ok(_idle) = self.rig_in_use.try_lock() {
            let found = Board::check(port);
            let unknown = matches!(found, Board::Unreachable { .. })
                && matches!(self.board(), Board::Mismatch { .. });
            if unknown {
                tracing::debug!("the LED controller could not be looked at again: {found:?}");
            } else {
                self.set_board(found);
            }
        }
        self.board()
    }

    fn running(&self) -> std::sync::MutexGuard<'_, Option<Running>> {
        self.running.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The running job's id, progress and ETA.
    pub fn current(&self) -> Option<(i64, Option<Progress>, Option<f64>)> {
        self.running().as_ref().map(|r| (r.id, r.progress, r.eta_s))
    }

    fn publish(&self, event: Event) {
        // No subscriber is not an error.
        let at_s = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0.0, |d| d.as_secs_f64());
        let _ = self.events.send(Stamped { event, at_s });
    }

    fn set_state(
        &self,
        id: i64,
        state: JobState,
        error: Option<String>,
        summary: Option<serde_json::Value>,
    ) {
        if let Err(e) = self
            .store
            .set_state(id, state, error.as_deref(), summary.as_ref())
        {
            tracing::error!("job {id}: could not record its state {state:?}: {e:#}");
        }
        self.publish(Event::State {
            job: id,
            state,
            error,
        });
    }
}

/// Why a cancel was refused.
#[derive(Debug, thiserror::Error)]
pub enum CancelError {
    /// No such job.
    #[error("no job {0}")]
    Unknown(i64),
    /// It has ended.
    #[error("job {0} has already ended ({1:?})")]
    Ended(i64, JobState),
    /// It is a reconstruction running now: it ends by itself.
    #[error("job {0} is reconstructing and cannot be stopped part-way; it ends by itself")]
    Unstoppable(i64),
    /// The database could not say.
    #[error("{0:#}")]
    Store(anyhow::Error),
}

/// Why a pause or a resume was refused.
#[derive(Debug, thiserror::Error)]
pub enum SteerError {
    /// No such job.
    #[error("no job {0}")]
    Unknown(i64),
    /// It is not in a state the request applies to.
    #[error("{0}")]
    Conflict(String),
    /// The database could not say.
    #[error("{0:#}")]
    Store(anyhow::Error),
}

/// What a `resume` job completes.
pub enum Resumable {
    /// An acquisition: the LEDs its frames lack are lit.
    Acquisition(AcquireRequest),
    /// A scan: the fields it lacks are acquired, then all are stitched.
    Scan(ScanRequest),
}

/// The request a job carries out, if a resume can complete it: its own, or for a
/// `resume` job the request of the job it completes (followed back through resumes of
/// resumes).
pub fn resumable_request(store: &Store, id: i64) -> Result<Resumable, SteerError> {
    let mut at = id;
    for _ in 0..1000 {
        let job = store
            .get(at)
            .map_err(SteerError::Store)?
            .ok_or(SteerError::Unknown(at))?;
        let request: JobRequest = serde_json::from_value(job.request)
            .map_err(|e| SteerError::Store(anyhow!("job {at}'s stored request: {e}")))?;
        match request {
            JobRequest::Acquire(a) => return Ok(Resumable::Acquisition(a)),
            JobRequest::Sequence(s) => return Ok(Resumable::Acquisition(s.as_acquisition())),
            JobRequest::Scan(s) => return Ok(Resumable::Scan(s)),
            JobRequest::Calibrate(_) | JobRequest::Reconstruct(_) | JobRequest::Dpc(_) => {
                return Err(SteerError::Conflict(format!(
                    "job {at} does not acquire: queue it again rather than resume it"
                )))
            }
            JobRequest::Resume(r) => at = r.job,
        }
    }
    Err(SteerError::Conflict(format!(
        "job {id}: its resumes do not lead back to an acquisition"
    )))
}

/// The API's way to the worker.
#[derive(Clone)]
pub struct Handle {
    shared: Arc<Shared>,
    queue: mpsc::Sender<i64>,
}

impl Handle {
    /// Queue `request` (placed under the runs directory when it names no output); its
    /// job id.
    pub fn submit(&self, request: &JobRequest) -> Result<i64> {
        let json = serde_json::to_value(request)?;
        let out = request
            .out()
            .ok_or_else(|| anyhow!("the request has no output directory"))?
            .display()
            .to_string();
        let id = self.shared.store.insert(request.kind(), &json, &out)?;
        self.shared.publish(Event::State {
            job: id,
            state: JobState::Queued,
            error: None,
        });
        self.queue
            .send(id)
            .map_err(|_| anyhow!("the service's worker has stopped"))?;
        Ok(id)
    }

    /// Cancel job `id`: a queued job never starts; a running one stops at once.
    pub fn cancel(&self, id: i64) -> Result<(), CancelError> {
        if let Some(r) = self.shared.running().as_ref().filter(|r| r.id == id) {
            if r.kind == "reconstruct" {
                return Err(CancelError::Unstoppable(id));
            }
            r.control.cancel();
            return Ok(());
        }
        let job = self
            .shared
            .store
            .get(id)
            .map_err(CancelError::Store)?
            .ok_or(CancelError::Unknown(id))?;
        match job.state {
            JobState::Queued => {
                self.shared.set_state(
                    id,
                    JobState::Cancelled,
                    Some("cancelled before it started".into()),
                    None,
                );
                Ok(())
            }
            // Between the queue and the rig: the worker reads the flag it is about to set.
            JobState::Running => Ok(()),
            state => Err(CancelError::Ended(id, state)),
        }
    }

    /// Pause the running job `id` between LEDs.
    pub fn pause(&self, id: i64) -> Result<(), SteerError> {
        self.steer(id, "paused", Control::pause)
    }

    /// Resume the running job `id` after a pause.
    pub fn resume_running(&self, id: i64) -> Result<(), SteerError> {
        self.steer(id, "resumed", Control::resume)
    }

    fn steer(&self, id: i64, what: &str, how: fn(&Control)) -> Result<(), SteerError> {
        if let Some(r) = self.shared.running().as_ref().filter(|r| r.id == id) {
            if r.kind == "reconstruct" {
                return Err(SteerError::Conflict(format!(
                    "job {id} reconstructs: only an acquisition is {what}"
                )));
            }
            how(&r.control);
            return Ok(());
        }
        let job = self
            .shared
            .store
            .get(id)
            .map_err(SteerError::Store)?
            .ok_or(SteerError::Unknown(id))?;
        Err(SteerError::Conflict(format!(
            "job {id} is {:?}, not running: only a running job is {what}",
            job.state
        )))
    }

    /// Whether the running job `id` is paused (or asked to be).
    pub fn is_paused(&self, id: i64) -> bool {
        self.shared
            .running()
            .as_ref()
            .is_some_and(|r| r.id == id && r.control.is_paused())
    }
}

/// The worker thread.
pub struct Worker {
    handle: Handle,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Worker {
    /// Start it on `rig`; the jobs a previous service left queued are queued again.
    pub fn start(shared: Arc<Shared>, rig: Rig) -> Result<Self> {
        let (queue, rx) = mpsc::channel();
        for id in shared.store.queued()? {
            let _ = queue.send(id);
        }
        let stop = Arc::new(AtomicBool::new(false));
        let (s, flag) = (shared.clone(), stop.clone());
        let thread = std::thread::Builder::new()
            .name("fpm-serve-rig".into())
            .spawn(move || run(&s, &rig, &rx, &flag))?;
        Ok(Self {
            handle: Handle { shared, queue },
            stop,
            thread: Some(thread),
        })
    }

    /// The API's handle.
    pub fn handle(&self) -> Handle {
        self.handle.clone()
    }

    /// Cancel the running job and wait for the worker to end.
    pub fn stop(mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(r) = self.handle.shared.running().as_ref() {
            r.control.cancel();
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn run(shared: &Shared, rig: &Rig, queue: &mpsc::Receiver<i64>, stop: &AtomicBool) {
    // Snapshots for local viewers in shared memory (an extra: HTTP has them too).
    let publisher = fpm_frames::SnapshotPublisher::create(&shared.snapshot_service)
        .map_err(|e| {
            tracing::warn!(
                "snapshots are not published on iceoryx2 ({e}); viewers fetch them over HTTP"
            )
        })
        .ok();
    // The board is looked at once before the first job, for the page and
    // /api/status; each job's own opening of it keeps that up to date.
    shared.check_board(&rig.port);
    while !stop.load(Ordering::SeqCst) {
        if let Some(p) = &publisher {
            p.serve();
        }
        let Ok(id) = queue.recv_timeout(Duration::from_millis(100)) else {
            continue;
        };
        run_job(shared, rig, id, stop, publisher.as_ref());
    }
}

/// Job `id`'s LED controller on `port`. One that is not there yet (a board being
/// plugged back in, a driver restarting) is waited for a while: the service reconnects
/// when it returns. What the opening finds is what the service knows of the board.
fn open_controller(shared: &Shared, port: &str, id: i64, control: &Control) -> Result<Controller> {
    let deadline = Instant::now() + CONTROLLER_WAIT;
    let mut said = false;
    loop {
        match Controller::open(port, Duration::from_secs(2)) {
            Ok(dev) => {
                shared.set_board(Board::of(&dev));
                return Ok(dev);
            }
            // Waiting does not change a board's firmware.
            Err(e @ ControllerError::VersionMismatch { .. }) => {
                let board = Board::from_error(port, &e);
                let said = board.refusal().unwrap_or_default().to_owned();
                shared.set_board(board);
                bail!("{said}");
            }
            Err(e) if Instant::now() < deadline && !control.is_cancelled() => {
                if !std::mem::replace(&mut said, true) {
                    tracing::warn!("job {id}: waiting for the LED controller on {port} ({e:#})");
                }
                std::thread::sleep(Duration::from_millis(250));
            }
            Err(e) => bail!(
                "the LED controller on {port}: {e:#} (waited {} s for it: is it plugged in?)",
                CONTROLLER_WAIT.as_secs()
            ),
        }
    }
}

/// Run job `id` if it is still queued.
fn run_job(
    shared: &Shared,
    rig: &Rig,
    id: i64,
    stop: &AtomicBool,
    publisher: Option<&fpm_frames::SnapshotPublisher>,
) {
    let job = match shared.store.get(id) {
        Ok(Some(job)) if job.state == JobState::Queued => job,
        Ok(_) => return,
        Err(e) => {
            tracing::error!("job {id}: {e:#}");
            return;
        }
    };
    let control = Control::new();
    if stop.load(Ordering::SeqCst) {
        control.cancel();
    }
    // A job on the rig has the controller to itself (a reconstruction does not use it).
    let _rig = (job.kind != "reconstruct")
        .then(|| shared.rig_in_use.lock().unwrap_or_else(|e| e.into_inner()));
    *shared.running() = Some(Running {
        id,
        kind: job.kind.clone(),
        control: control.clone(),
        progress: None,
        eta_s: None,
    });
    shared.set_state(id, JobState::Running, None, None);
    let request: Result<JobRequest> = serde_json::from_value(job.request).map_err(Into::into);
    let watcher = JobWatcher::new(shared, id, publisher);
    let open = || -> Result<_> {
        let dev = open_controller(shared, &rig.port, id, &control)?;
        Ok((dev, (rig.stage)()?))
    };
    let summary = |s: fpm_acquire::AcquireSummary| serde_json::to_value(s).unwrap_or_default();
    let outcome = request.and_then(|r| match r {
        JobRequest::Acquire(a) => {
            let plan = a.plan(&rig.camera)?;
            let (dev, mut stage) = open()?;
            match a.color_plan()? {
                None => fpm_acquire::pipeline::acquire(
                    &dev,
                    stage.as_mut(),
                    &plan,
                    watcher.stepping(&plan),
                    &control,
                )
                .map(summary),
                Some(colors) => fpm_acquire::color::acquire(
                    &dev,
                    stage.as_mut(),
                    &plan,
                    &colors,
                    |_| JobWatcher::new(shared, id, publisher).stepping(&plan),
                    &control,
                    &format!("fpm serve: job {id}"),
                )
                .and_then(|s| serde_json::to_value(s).map_err(Into::into)),
            }
        }
        JobRequest::Calibrate(c) => {
            let plan = c.plan(&rig.camera)?;
            let (dev, mut stage) = open()?;
            let watcher = watcher.stepping(&plan);
            fpm_acquire::pipeline::acquire(&dev, stage.as_mut(), &plan, watcher, &control)
                .map(summary)
        }
        JobRequest::Sequence(s) => {
            let plan = s.as_acquisition().plan(&rig.camera)?;
            let (dev, mut stage) = open()?;
            let watcher = watcher.stepping(&plan);
            fpm_acquire::pipeline::acquire(&dev, stage.as_mut(), &plan, watcher, &control)
                .map(summary)
        }
        JobRequest::Reconstruct(r) => reconstruct(
            JobWatcher::new(shared, id, publisher),
            &r,
            Path::new(&job.out),
        ),
        JobRequest::Dpc(d) => {
            let (dev, _stage) = open()?;
            let plan = d.plan(&rig.camera, fpm_acquire::pipeline::board_geometry(&dev))?;
            fpm_acquire::dpc::live(&dev, &plan, watcher, &control)
                .and_then(|s| serde_json::to_value(s).map_err(Into::into))
        }
        JobRequest::Resume(r) => match resumable_request(&shared.store, r.job)? {
            Resumable::Acquisition(a) => {
                if a.colors.is_some() {
                    bail!(
                        "job {}: a colour acquisition is not resumable yet; acquire the colours again",
                        r.job
                    );
                }
                let plan = a.plan_in(&rig.camera, Path::new(&job.out))?;
                let (dev, mut stage) = open()?;
                let watcher = watcher.stepping(&plan);
                fpm_acquire::pipeline::resume(&dev, stage.as_mut(), &plan, watcher, &control)
                    .map(summary)
            }
            Resumable::Scan(s) => {
                let plan = s.plan_in(&rig.camera, Path::new(&job.out))?;
                let (dev, mut stage) = open()?;
                scan(watcher.stepping(&plan.field), &dev, stage.as_mut(), &plan, &control)
            }
        },
        JobRequest::Scan(s) => {
            let plan = s.plan(&rig.camera)?;
            let (dev, mut stage) = open()?;
            scan(watcher.stepping(&plan.field), &dev, stage.as_mut(), &plan, &control)
        }
    });
    // What the acquisition wrote, also when it failed part-way.
    let written = || {
        std::fs::read_to_string(std::path::Path::new(&job.out).join("acquisition.json"))
            .ok()
            .and_then(|t| serde_json::from_str(&t).ok())
    };
    match outcome {
        Ok(summary) => shared.set_state(id, JobState::Done, None, Some(summary)),
        Err(e) if control.is_cancelled() => {
            shared.set_state(id, JobState::Cancelled, Some(format!("{e:#}")), written())
        }
        Err(e) => shared.set_state(id, JobState::Failed, Some(format!("{e:#}")), written()),
    }
    *shared.running() = None;
}

/// Run a scan job: each field's acquisition as the job's progress, the fields moved
/// to, reconstructed and stitched as `work` events; the scan's summary (with how the
/// fields were joined) is the job's.
fn scan(
    mut watcher: JobWatcher<'_>,
    dev: &Controller,
    stage: &mut dyn fpm_acquire::FocusStage,
    plan: &fpm_acquire::scan::ScanPlan,
    control: &Control,
) -> Result<serde_json::Value> {
    use fpm_acquire::pipeline::Watcher;
    use fpm_acquire::scan::ScanEvent;
    let Some(stage) = stage.as_scan_stage() else {
        bail!("a scan needs a motorised stage: start the service with --stage gcode:PORT or sangaboard:PORT (or --virtual)");
    };
    let (shared, id) = (watcher.shared, watcher.job);
    let work = |what: &'static str, done: usize, total: usize| {
        shared.publish(Event::Work {
            job: id,
            what,
            done,
            total,
        })
    };
    let mut reconstructed = 0;
    let summary = fpm_acquire::scan::run(
        dev,
        stage,
        plan,
        &mut |e| match e {
            ScanEvent::Moving { index, total, .. } => work("fields", index, total),
            ScanEvent::Skipped { index } => work("fields", index + 1, plan.rows * plan.cols),
            ScanEvent::Acquiring { progress, .. } => watcher.progress(&progress),
            ScanEvent::Reconstructed { .. } => {
                reconstructed += 1;
                work("fields reconstructed", reconstructed, plan.rows * plan.cols)
            }
            ScanEvent::Stitching { done, total } => work("stitching", done, total),
            ScanEvent::Focused { index, .. } => {
                work("fields focused", index + 1, plan.rows * plan.cols)
            }
        },
        control,
    )?;
    serde_json::to_value(summary).map_err(Into::into)
}

/// Run reconstruct job `id` into `out`: progress as `work` events (a few a second),
/// the finished image as the job's snapshot; the report is its summary.
fn reconstruct(
    mut watcher: JobWatcher<'_>,
    request: &crate::jobs::ReconstructRequest,
    out: &Path,
) -> Result<serde_json::Value> {
    let (shared, id) = (watcher.shared, watcher.job);
    let job = request.job()?;
    let last = Mutex::new(None::<Instant>);
    let finished = job.run(&request.dataset, &|event| {
        use fpm_host::reconstruction::JobEvent;
        let (what, done, total) = match event {
            JobEvent::Updates { done, total } => ("frame updates", done, total),
            JobEvent::GammaCandidates { done, total } => ("camera gamma candidates", done, total),
            JobEvent::FromDisk { .. } | JobEvent::WeighingEdgeHeight { .. } => return,
        };
        let mut last = last.lock().unwrap_or_else(|e| e.into_inner());
        if done < total && last.is_some_and(|t| t.elapsed() < Duration::from_millis(200)) {
            return;
        }
        *last = Some(Instant::now());
        shared.publish(Event::Work {
            job: id,
            what,
            done,
            total,
        });
    })?;
    let output = fpm_host::reconstruction::OutputOptions {
        format: match request.format {
            crate::jobs::OutputFormat::Tiff => fpm_host::reconstruction::ImageFormat::Tiff,
            crate::jobs::OutputFormat::OmeZarr => fpm_host::reconstruction::ImageFormat::OmeZarr,
        },
        ..Default::default()
    };
    let reproduce = format!(
        "fpm serve: reconstruct job {id} ({})",
        serde_json::to_string(request).unwrap_or_default()
    );
    let written = fpm_report::reconstruction::write(&finished, out, output, &reproduce)?;
    for w in &written.warnings {
        tracing::warn!("job {id}: {w}");
    }
    let r = &finished.reconstruction;
    let snapshot = fpm_acquire::acquisition::Snapshot {
        frames: r.report.frames,
        of: r.report.frames,
        finished: true,
        object: r.object.clone(),
        pixel_um: r.report.pixel_um,
    };
    fpm_acquire::pipeline::Watcher::snapshot(&mut watcher, snapshot);
    fpm_host::reconstruction::report_json(&r.report)
}

/// The service's view of its running acquisition: progress (with an ETA) into the
/// running job's record and the event stream; snapshots and a few camera frames a
/// second into [`Live`], announced.
struct JobWatcher<'a> {
    shared: &'a Shared,
    job: i64,
    /// The progress last published (the machine reports after every event; an
    /// unchanged one is not sent again).
    last: Option<Progress>,
    /// Frames labelled when the capture began (a resumed run's earlier ones).
    capture_base: Option<usize>,
    /// When the capture's first frame was labelled, and the frames labelled by then.
    first_label: Option<(Instant, usize)>,
    /// The controller's step, s, when the job runs a sequence.
    step_s: Option<f64>,
    /// Where snapshots go for local viewers.
    publisher: Option<&'a fpm_frames::SnapshotPublisher>,
}

impl<'a> JobWatcher<'a> {
    fn new(
        shared: &'a Shared,
        job: i64,
        publisher: Option<&'a fpm_frames::SnapshotPublisher>,
    ) -> Self {
        Self {
            shared,
            job,
            last: None,
            capture_base: None,
            first_label: None,
            step_s: None,
            publisher,
        }
    }

    /// The same, for a run of `plan`, whose controller steps at its pace.
    fn stepping(mut self, plan: &fpm_acquire::Plan) -> Self {
        self.step_s = Some(plan.step_us() as f64 / 1e6);
        self
    }

    /// The capture's time left, s: the LEDs still to label (or the steps the controller
    /// has still to run and one, if more) at the step period the controller's own clock
    /// measures (before two steps are in, the plan's). Frames that lag the steps count
    /// in: beside a busy CPU the virtual camera falls behind the controller, and the
    /// steps left alone said 0 while a quarter of the frames were still to come. When
    /// frames are labelled at a pace well below the steps' (two thirds or less: a
    /// camera that cannot keep up), the LEDs still to label at that pace. Reading the
    /// labelled pace from the capture's start took the wait before labelling commits
    /// for slowness: 48 % too long at a quarter of the capture (docs/results.md).
    fn eta_s(&mut self, p: &Progress) -> Option<f64> {
        use fpm_acquire::Phase;
        if !matches!(p.phase, Phase::Capturing | Phase::Retaking) || p.of == 0 {
            // The next capture (a scan's next field, the retake) starts afresh.
            (self.capture_base, self.first_label) = (None, None);
            return None;
        }
        let base = *self.capture_base.get_or_insert(p.frames);
        if p.frames > base && self.first_label.is_none() {
            self.first_label = Some((Instant::now(), p.frames));
        }
        // Over 16 frames and 2 s at least, so that a burst of labels is not a pace.
        let pace_s = self.first_label.and_then(|(t, f)| {
            let (n, s) = (p.frames.saturating_sub(f), t.elapsed().as_secs_f64());
            (n >= 16 && s >= 2.0).then(|| s / n as f64)
        });
        let period_s = p
            .steps
            .and_then(|s| s.period_us)
            .map(|us| us as f64 / 1e6)
            .or(self.step_s);
        let to_label = p.of.saturating_sub(p.frames);
        let steps_left = p.steps.map_or(0, |s| s.of.saturating_sub(s.done) + 1);
        match (period_s, pace_s) {
            (Some(step), Some(pace)) if pace > 1.5 * step => Some(to_label as f64 * pace),
            (Some(step), _) => Some(to_label.max(steps_left) as f64 * step),
            (None, pace) => pace.map(|pace| to_label as f64 * pace),
        }
    }
}

impl fpm_acquire::pipeline::Watcher for JobWatcher<'_> {
    fn progress(&mut self, p: &Progress) {
        if self.last == Some(*p) {
            return;
        }
        self.last = Some(*p);
        let eta_s = self.eta_s(p);
        if let Some(r) = self.shared.running().as_mut() {
            r.progress = Some(*p);
            r.eta_s = eta_s;
        }
        self.shared.publish(Event::Progress {
            job: self.job,
            progress: *p,
            eta_s,
        });
    }

    fn wants_snapshots(&self) -> bool {
        true
    }

    fn snapshot(&mut self, snapshot: fpm_acquire::acquisition::Snapshot) {
        let s = self.shared.live.put_snapshot(self.job, &snapshot);
        let (height, width) = s.amplitude.dim();
        if let Some(p) = self.publisher {
            let header = fpm_frames::SnapshotHeader {
                job: self.job,
                seq: s.seq,
                frames: s.frames as u64,
                of: s.of as u64,
                pixel_um: s.pixel_um,
                width: width as u32,
                height: height as u32,
                finished: u32::from(s.finished),
                flags: 0,
            };
            let (a, phase) = (s.amplitude.iter().copied(), s.phase.iter().copied());
            if let Err(e) = p.publish(header, a, phase) {
                tracing::warn!("job {}: snapshot not published on iceoryx2: {e}", self.job);
            }
        }
        self.shared.publish(Event::Snapshot {
            job: self.job,
            seq: s.seq,
            frames: s.frames,
            of: s.of,
            finished: s.finished,
            width,
            height,
            pixel_um: s.pixel_um,
        });
    }

    fn frame(&mut self, shot: &fpm_acquire::ShotView<'_>) {
        let led = [shot.led.row, shot.led.col];
        self.shared.publish(Event::Frame { job: self.job, led });
        if let Some(f) = self.shared.live.offer_frame(self.job, shot) {
            self.shared.publish(Event::CameraFrame {
                job: self.job,
                seq: f.seq,
                led,
            });
        }
    }
}
