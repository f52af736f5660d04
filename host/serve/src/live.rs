//! What viewers see while a job runs: the newest snapshot of each recent job's
//! reconstruction (amplitude and phase, with their pixel size) and the newest camera
//! frame (at most a few a second), kept in memory. Each has a number the event stream
//! announces, so a viewer fetches only what is new.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use fpm_acquire::ShotView;
use ndarray::Array2;

/// How many jobs' last snapshots are kept (older jobs' images are in their output).
pub const KEPT_JOBS: usize = 8;

/// The shortest time between two camera frames kept for viewers: the capture runs at
/// the camera's rate, a person looks at a few frames a second.
pub const FRAME_INTERVAL: Duration = Duration::from_millis(250);

/// A job's reconstruction as it stood.
pub struct Snapshot {
    /// The job.
    pub job: i64,
    /// Its number (rising over the service's life, shared with the camera frames).
    pub seq: u64,
    /// Frames streamed into it.
    pub frames: usize,
    /// LEDs in the capture.
    pub of: usize,
    /// The finished reconstruction (not the stream's state).
    pub finished: bool,
    /// Its pixel in the sample plane, µm.
    pub pixel_um: f64,
    /// |object|.
    pub amplitude: Array2<f32>,
    /// arg(object), radians.
    pub phase: Array2<f32>,
}

/// A camera frame as it arrived, labelled.
pub struct CameraFrame {
    /// The job that took it.
    pub job: i64,
    /// Its number (see [`Snapshot::seq`]).
    pub seq: u64,
    /// The LED that lit it, (row, col).
    pub led: [u8; 2],
    /// Its exposure, µs.
    pub exposure_us: u32,
    /// Counts, `[row, col]`.
    pub pixels: Array2<u16>,
}

/// The live images.
#[derive(Default)]
pub struct Live {
    snapshots: Mutex<VecDeque<Arc<Snapshot>>>,
    frame: Mutex<Option<(Arc<CameraFrame>, Instant)>>,
    seq: AtomicU64,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl Live {
    /// Job `job`'s newest snapshot.
    pub fn snapshot(&self, job: i64) -> Option<Arc<Snapshot>> {
        lock(&self.snapshots).iter().find(|s| s.job == job).cloned()
    }

    /// The newest camera frame kept.
    pub fn frame(&self) -> Option<Arc<CameraFrame>> {
        lock(&self.frame).as_ref().map(|(f, _)| f.clone())
    }

    /// Keep `snapshot` as `job`'s newest (its amplitude and phase computed here, off
    /// any async thread).
    pub fn put_snapshot(
        &self,
        job: i64,
        snapshot: &fpm_acquire::acquisition::Snapshot,
    ) -> Arc<Snapshot> {
        let kept = Arc::new(Snapshot {
            job,
            seq: self.seq.fetch_add(1, Ordering::SeqCst) + 1,
            frames: snapshot.frames,
            of: snapshot.of,
            finished: snapshot.finished,
            pixel_um: snapshot.pixel_um,
            amplitude: snapshot.object.mapv(|c| c.norm()),
            phase: snapshot.object.mapv(|c| c.arg()),
        });
        let mut all = lock(&self.snapshots);
        all.retain(|s| s.job != job);
        all.push_front(kept.clone());
        all.truncate(KEPT_JOBS);
        kept
    }

    /// Keep `shot` as the newest camera frame, unless one was kept less than
    /// [`FRAME_INTERVAL`] ago; what was kept.
    pub fn offer_frame(&self, job: i64, shot: &ShotView<'_>) -> Option<Arc<CameraFrame>> {
        let mut slot = lock(&self.frame);
        if slot
            .as_ref()
            .is_some_and(|(_, at)| at.elapsed() < FRAME_INTERVAL)
        {
            return None;
        }
        let frame = Arc::new(CameraFrame {
            job,
            seq: self.seq.fetch_add(1, Ordering::SeqCst) + 1,
            led: [shot.led.row, shot.led.col],
            exposure_us: shot.header.exposure_us,
            pixels: shot.pixels.to_owned(),
        });
        *slot = Some((frame.clone(), Instant::now()));
        Some(frame)
    }
}
