//! How a running acquisition is watched ([`Watcher`]) and steered from outside its
//! loop ([`Control`]): the same for every mode and every driver.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use crate::acquisition::{Progress, Snapshot};
use crate::capture::ShotView;

/// Whoever watches an acquisition: its progress after every event, and, if it wants
/// them, the live snapshots of the reconstruction and each labelled frame as it
/// arrives. A closure over `&Progress` is a watcher of progress alone.
pub trait Watcher {
    /// How far the acquisition is (after every event).
    fn progress(&mut self, progress: &Progress);
    /// Whether it shows snapshots: only then are they taken (a stream's blend, or a
    /// copy of the finished object, is not made for nobody).
    fn wants_snapshots(&self) -> bool {
        false
    }
    /// A snapshot of the reconstruction ([`crate::acquisition::Plan::snapshot_every`], and the finished one).
    fn snapshot(&mut self, _snapshot: Snapshot) {}
    /// A labelled frame as it arrives, lent: copy what you keep (on the capture's
    /// thread, between two frames: keep it short).
    fn frame(&mut self, _shot: &ShotView<'_>) {}
}

impl<F: FnMut(&Progress)> Watcher for F {
    fn progress(&mut self, progress: &Progress) {
        self(progress)
    }
}

/// How a running acquisition is steered from outside its loop (another thread, a
/// signal handler): cancel, pause, resume. The loop reads the flags between events; a
/// capture sequence running is aborted at once by a cancel or a pause.
#[derive(Debug, Clone, Default)]
pub struct Control {
    cancel: Arc<AtomicBool>,
    pause: Arc<AtomicBool>,
    /// When [`Control::cancel`] was first called (a flag set elsewhere has none).
    cancelled_at: Arc<std::sync::OnceLock<std::time::Instant>>,
}

impl Control {
    /// Nothing asked yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Cancelled when `flag` is set (by a signal handler, say).
    pub fn cancelled_by(flag: Arc<AtomicBool>) -> Self {
        Self {
            cancel: flag,
            ..Self::default()
        }
    }

    /// Stop: no new sequence starts, what was captured is written, the run fails
    /// saying it was cancelled.
    pub fn cancel(&self) {
        self.cancelled_at.get_or_init(std::time::Instant::now);
        self.cancel.store(true, Ordering::SeqCst);
    }

    /// When [`Control::cancel`] was first called.
    pub fn cancelled_at(&self) -> Option<std::time::Instant> {
        self.cancelled_at.get().copied()
    }

    /// Hold between LEDs (and before any stage move) until [`Control::resume`].
    pub fn pause(&self) {
        self.pause.store(true, Ordering::SeqCst);
    }

    /// Go on after a pause.
    pub fn resume(&self) {
        self.pause.store(false, Ordering::SeqCst);
    }

    /// Whether a cancel was asked for.
    pub fn is_cancelled(&self) -> bool {
        self.cancel.load(Ordering::SeqCst)
    }

    /// Whether a pause is asked for now.
    pub fn is_paused(&self) -> bool {
        self.pause.load(Ordering::SeqCst)
    }
}
