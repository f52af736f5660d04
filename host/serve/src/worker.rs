//! The thread that owns the rig: it takes queued jobs one at a time, runs each with
//! `fpm_acquire::pipeline::acquire` (the acquisition's state machine and its loop),
//! and publishes progress as it goes. Cancelling sets the job's flag: the running
//! sequence is aborted on the controller, what was captured is written, and the job
//! ends `cancelled`.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::{anyhow, Result};
use fpm_acquire::{Controller, Progress};
use fpm_frames::ServiceNames;
use serde::Serialize;
use tokio::sync::broadcast;
use utoipa::ToSchema;

use crate::jobs::JobRequest;
use crate::store::{JobState, Store};
use crate::Rig;

/// What the event stream carries: a job's state or progress.
#[derive(Debug, Clone, Serialize, ToSchema)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum Event {
    /// A job moved to `state`.
    State {
        job: i64,
        state: JobState,
        error: Option<String>,
    },
    /// How far the running job is.
    Progress {
        job: i64,
        #[schema(value_type = Object)]
        progress: Progress,
    },
}

/// The running job.
struct Running {
    id: i64,
    cancel: Arc<AtomicBool>,
    progress: Option<Progress>,
}

/// What the API and the worker share.
pub struct Shared {
    /// The job database.
    pub store: Store,
    /// Events for every subscriber (a slow one misses some and is told so).
    pub events: broadcast::Sender<Event>,
    /// The rig, in words.
    pub rig: String,
    /// The rig's camera (a request's plan is checked against it when it comes in).
    pub camera: ServiceNames,
    running: Mutex<Option<Running>>,
}

impl Shared {
    /// Nothing running yet.
    pub fn new(store: Store, rig: String, camera: ServiceNames) -> Self {
        Self {
            store,
            events: broadcast::channel(1024).0,
            rig,
            camera,
            running: Mutex::new(None),
        }
    }

    fn running(&self) -> std::sync::MutexGuard<'_, Option<Running>> {
        self.running.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The running job's id and progress.
    pub fn current(&self) -> Option<(i64, Option<Progress>)> {
        self.running().as_ref().map(|r| (r.id, r.progress))
    }

    fn publish(&self, event: Event) {
        // No subscriber is not an error.
        let _ = self.events.send(event);
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
    /// The database could not say.
    #[error("{0:#}")]
    Store(anyhow::Error),
}

/// The API's way to the worker.
#[derive(Clone)]
pub struct Handle {
    shared: Arc<Shared>,
    queue: mpsc::Sender<i64>,
}

impl Handle {
    /// Queue `request`; its job id.
    pub fn submit(&self, request: &JobRequest) -> Result<i64> {
        let json = serde_json::to_value(request)?;
        let out = request.out().display().to_string();
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
            r.cancel.store(true, Ordering::SeqCst);
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
            r.cancel.store(true, Ordering::SeqCst);
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn run(shared: &Shared, rig: &Rig, queue: &mpsc::Receiver<i64>, stop: &AtomicBool) {
    while !stop.load(Ordering::SeqCst) {
        let Ok(id) = queue.recv_timeout(Duration::from_millis(100)) else {
            continue;
        };
        run_job(shared, rig, id, stop);
    }
}

/// Run job `id` if it is still queued.
fn run_job(shared: &Shared, rig: &Rig, id: i64, stop: &AtomicBool) {
    let job = match shared.store.get(id) {
        Ok(Some(job)) if job.state == JobState::Queued => job,
        Ok(_) => return,
        Err(e) => {
            tracing::error!("job {id}: {e:#}");
            return;
        }
    };
    let cancel = Arc::new(AtomicBool::new(stop.load(Ordering::SeqCst)));
    *shared.running() = Some(Running {
        id,
        cancel: cancel.clone(),
        progress: None,
    });
    shared.set_state(id, JobState::Running, None, None);
    let request: Result<JobRequest> = serde_json::from_value(job.request).map_err(Into::into);
    let outcome = request.and_then(|r| match r {
        JobRequest::Acquire(a) => {
            let plan = a.plan(&rig.camera)?;
            let dev = Controller::open(&rig.port, Duration::from_secs(2))
                .map_err(|e| anyhow!("the LED controller on {}: {e:#}", rig.port))?;
            let mut stage = (rig.stage)()?;
            let on_progress = |p: &Progress| {
                if let Some(r) = shared.running().as_mut() {
                    r.progress = Some(*p);
                }
                shared.publish(Event::Progress {
                    job: id,
                    progress: *p,
                });
            };
            fpm_acquire::pipeline::acquire(&dev, stage.as_mut(), &plan, on_progress, &cancel)
                .map(|summary| serde_json::to_value(summary).unwrap_or_default())
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
        Err(e) if cancel.load(Ordering::SeqCst) => {
            shared.set_state(id, JobState::Cancelled, Some(format!("{e:#}")), written())
        }
        Err(e) => shared.set_state(id, JobState::Failed, Some(format!("{e:#}")), written()),
    }
    *shared.running() = None;
}
