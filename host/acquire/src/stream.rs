//! The streaming reconstruction on a thread of its own, so that the rig's work
//! (serial I/O, frame intake, labelling, the journal) never waits on it: the
//! acquisition hands each labelled frame over and goes on. The thread runs at a lower
//! priority than the acquisition's, updates the tiles, takes the live snapshots, and
//! may fall behind and catch up. Its queue is bounded (in bytes of frames): a frame
//! that finds it full is left to the final reconstruction, which then runs over the
//! dataset, as it does after a relabelling.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Instant;

use anyhow::{Context, Result};
use fpm_frames::FrameHeader;
use fpm_physics::reconstruct::TiledStreaming;
use fpm_physics::{Complex32, LedIndex};
use ndarray::Array2;

use crate::capture::ShotView;

/// Frames queued for the stream at most, in bytes of pixels: all of a 441-LED capture
/// of 256² frames, a few frames of a 20 MP sensor.
const QUEUE_BYTES: usize = 256 << 20;

/// How much lower than the acquisition's the stream thread's priority is (its nice
/// value, on Linux).
#[cfg(target_os = "linux")]
const NICER: i32 = 5;

/// A labelled frame, owned: what [`ShotView::lit_frame`] needs.
struct Handed {
    led: LedIndex,
    header: FrameHeader,
    pixels: Array2<u16>,
}

/// What the thread tells the acquisition.
#[derive(Default)]
struct Shared {
    /// The newest snapshot not yet taken, and the frames in it.
    snapshot: Option<(usize, Array2<Complex32>)>,
    /// Why the stream stopped, if it did.
    error: Option<String>,
    /// Each update's time, µs.
    update_us: Vec<f64>,
}

/// The streaming reconstruction's thread and its queue.
pub struct StreamWorker {
    queue: Option<SyncSender<Handed>>,
    shared: Arc<Mutex<Shared>>,
    /// Set when the stream's work is no longer wanted (a cancel): the thread drops
    /// what is queued.
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<TiledStreaming>>,
    tiles: usize,
    left_out: usize,
}

impl StreamWorker {
    /// Start the thread with `stream` (nothing received yet), frames' dark level
    /// `dark_level`, and a snapshot every `snapshot_every` frames (0: none).
    pub fn start(stream: TiledStreaming, dark_level: f32, snapshot_every: usize) -> Result<Self> {
        let layout = stream.layout();
        let frame_bytes = (layout.width * layout.height * 2).max(1);
        Self::with_queue(
            stream,
            dark_level,
            snapshot_every,
            (QUEUE_BYTES / frame_bytes).max(8),
        )
    }

    /// The same with a queue of `capacity` frames.
    fn with_queue(
        stream: TiledStreaming,
        dark_level: f32,
        snapshot_every: usize,
        capacity: usize,
    ) -> Result<Self> {
        let tiles = stream.layout().tiles.len();
        let (queue, frames) = sync_channel(capacity);
        let shared = Arc::new(Mutex::new(Shared::default()));
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (shared, stop) = (shared.clone(), stop.clone());
            std::thread::Builder::new()
                .name("fpm-stream".into())
                .spawn(move || run(stream, frames, &shared, &stop, dark_level, snapshot_every))
                .context("starting the streaming reconstruction's thread")?
        };
        Ok(Self {
            queue: Some(queue),
            shared,
            stop,
            thread: Some(thread),
            tiles,
            left_out: 0,
        })
    }

    /// Hand a labelled frame over, without waiting: when the queue is full (the stream
    /// is far behind), the frame is left to the final reconstruction.
    pub fn offer(&mut self, shot: ShotView<'_>) {
        let Some(queue) = &self.queue else { return };
        let handed = Handed {
            led: shot.led,
            header: *shot.header,
            pixels: shot.pixels.to_owned(),
        };
        match queue.try_send(handed) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) => {
                if self.left_out == 0 {
                    tracing::warn!("the streaming reconstruction is far behind the capture: frames it cannot queue are left to the final reconstruction, over the dataset");
                }
                self.left_out += 1;
            }
            // The stream stopped (its error is kept for the finish).
            Err(TrySendError::Disconnected(_)) => self.queue = None,
        }
    }

    /// Tiles the frame is cut into.
    pub fn tiles(&self) -> usize {
        self.tiles
    }

    /// Frames the full queue turned away.
    pub fn left_out(&self) -> usize {
        self.left_out
    }

    /// The newest snapshot since the last one taken, and the frames streamed into it.
    pub fn take_snapshot(&self) -> Option<(usize, Array2<Complex32>)> {
        lock(&self.shared).snapshot.take()
    }

    /// Each update's time so far, µs.
    pub fn update_us(&self) -> Vec<f64> {
        lock(&self.shared).update_us.clone()
    }

    /// Wait for the thread to take in every queued frame: the stream as it stands (or
    /// why it stopped), and each update's time, µs.
    pub fn finish(mut self) -> (Result<TiledStreaming, String>, Vec<f64>) {
        self.queue = None;
        let joined = match self.thread.take() {
            Some(t) => t
                .join()
                .map_err(|_| "the streaming reconstruction's thread panicked".to_string()),
            None => Err("the streaming reconstruction's thread is gone".to_string()),
        };
        let mut shared = lock(&self.shared);
        let stream = match (joined, shared.error.take()) {
            (Ok(s), None) => Ok(s),
            (_, Some(e)) | (Err(e), None) => Err(e),
        };
        (stream, std::mem::take(&mut shared.update_us))
    }
}

impl Drop for StreamWorker {
    /// Not finished (a cancel, a failed capture): what is queued is dropped.
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        self.queue = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn lock(shared: &Mutex<Shared>) -> MutexGuard<'_, Shared> {
    shared.lock().unwrap_or_else(|e| e.into_inner())
}

/// The thread: each queued frame into the stream, a snapshot every `snapshot_every`.
fn run(
    mut stream: TiledStreaming,
    frames: Receiver<Handed>,
    shared: &Mutex<Shared>,
    stop: &AtomicBool,
    dark_level: f32,
    snapshot_every: usize,
) -> TiledStreaming {
    lower_priority();
    for handed in frames {
        if stop.load(Ordering::SeqCst) {
            break;
        }
        let shot = ShotView {
            led: handed.led,
            header: &handed.header,
            pixels: handed.pixels.view(),
        };
        let t = Instant::now();
        if let Err(e) = stream.push(&shot.lit_frame(dark_level)) {
            tracing::warn!("streaming reconstruction stopped: {e}");
            lock(shared).error = Some(e.to_string());
            break;
        }
        let micros = t.elapsed().as_secs_f64() * 1e6;
        let received = stream.received();
        let snapshot = (snapshot_every > 0 && received.is_multiple_of(snapshot_every))
            .then(|| stream.snapshot())
            .flatten();
        let mut s = lock(shared);
        s.update_us.push(micros);
        if let Some(object) = snapshot {
            s.snapshot = Some((received, object));
        }
    }
    stream
}

/// Below the acquisition's threads (Linux gives each thread its own nice value); where
/// that cannot be set, the stream runs as it is.
fn lower_priority() {
    #[cfg(target_os = "linux")]
    {
        // SAFETY: plain system calls on this thread's own id.
        let done = unsafe {
            let tid = libc::gettid();
            let now = libc::getpriority(libc::PRIO_PROCESS, tid as libc::id_t);
            libc::setpriority(libc::PRIO_PROCESS, tid as libc::id_t, now + NICER)
        };
        if done != 0 {
            tracing::debug!(
                "the stream thread keeps its priority: {}",
                std::io::Error::last_os_error()
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fpm_physics::reconstruct::Settings;
    use fpm_physics::simulate::{acquire_in_focus, Camera, ObjectField, SimFrame};
    use fpm_physics::{LedGeometry, System};

    /// A 7×7 array's frames of a 64² field, from the full wave-optics simulator.
    fn scene() -> (System, LedGeometry, Vec<SimFrame>, Camera) {
        let system = System::paper();
        let geometry = LedGeometry {
            rows: 7,
            cols: 7,
            center: LedIndex::new(3, 3),
            ..LedGeometry::paper()
        };
        let object = ObjectField::test_sample(&system, 64, 16, 2, 1);
        let camera = Camera::realistic();
        let frames = acquire_in_focus(&system, &geometry, &object, &camera, 1);
        (system, geometry, frames, camera)
    }

    fn header(frame: &SimFrame) -> FrameHeader {
        FrameHeader {
            exposure_us: (frame.exposure_ms * 1e3).round() as u32,
            ..FrameHeader::default()
        }
    }

    fn shot<'a>(frame: &'a SimFrame, header: &'a FrameHeader) -> ShotView<'a> {
        ShotView {
            led: frame.led,
            header,
            pixels: frame.counts.view(),
        }
    }

    #[test]
    fn the_thread_streams_every_frame_in_order_as_the_stream_does_inline() {
        let (system, geometry, frames, camera) = scene();
        let dark = camera.dark_level_dn as f32;
        let new = || TiledStreaming::new(system, geometry, Settings::default(), 64, 64, None);
        let mut worker = StreamWorker::start(new(), dark, 10).expect("thread");
        let mut inline = new();
        let headers: Vec<FrameHeader> = frames.iter().map(header).collect();
        let mut snapshots = 0;
        for (f, h) in frames.iter().zip(&headers) {
            worker.offer(shot(f, h));
            inline.push(&shot(f, h).lit_frame(dark)).expect("pushed");
            snapshots += usize::from(worker.take_snapshot().is_some());
        }
        let (threaded, update_us) = worker.finish();
        let mut threaded = threaded.expect("no error");
        assert_eq!(
            (threaded.received(), inline.received(), update_us.len()),
            (frames.len(), frames.len(), frames.len())
        );
        // The same updates in the same order: the same sample, to the bit.
        let (a, b) = (threaded.snapshot(), inline.snapshot());
        assert!(a.is_some(), "every tile seeded");
        assert_eq!(a, b);
        assert!(snapshots <= frames.len() / 10, "{snapshots} snapshots");
    }

    #[test]
    fn a_full_queue_leaves_frames_out_without_waiting_and_a_drop_stops_the_thread() {
        let (system, geometry, frames, camera) = scene();
        let dark = camera.dark_level_dn as f32;
        let stream = TiledStreaming::new(system, geometry, Settings::default(), 64, 64, None);
        let mut worker = StreamWorker::with_queue(stream, dark, 0, 1).expect("thread");
        let headers: Vec<FrameHeader> = frames.iter().map(header).collect();
        for (f, h) in frames.iter().zip(&headers) {
            worker.offer(shot(f, h));
        }
        // 49 frames offered at once into a queue of one: most find it full.
        assert!(
            worker.left_out() > 0 && worker.left_out() < frames.len(),
            "{} left out",
            worker.left_out()
        );
        drop(worker);
    }
}
