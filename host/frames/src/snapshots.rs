//! Live images of a reconstruction for viewers on this machine: the acquisition
//! service publishes each snapshot (amplitude and phase, float32) once into shared
//! memory on `fpm/serve/<port>/snapshots`, and every local viewer reads it in place,
//! however large. The service keeps the newest one (a history of one), so a viewer
//! that opens mid-run sees the current image at once. Over HTTP the same snapshots are
//! `GET /api/jobs/{id}/snapshot/…`.

use std::time::Duration;

use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;
use iceoryx2::service::port_factory::publish_subscribe;

use crate::service::node;
use crate::{ipc, FrameError};

/// Sent with every snapshot. Offsets (bytes, little-endian on the machines we run on):
///
/// | offset | type | field |
/// |---|---|---|
/// | 0 | i64 | `job` |
/// | 8 | u64 | `seq` |
/// | 16 | u64 | `frames` |
/// | 24 | u64 | `of` |
/// | 32 | f64 | `pixel_um` |
/// | 40 | u32 | `width` |
/// | 44 | u32 | `height` |
/// | 48 | u32 | `finished` (0 or 1) |
/// | 52 | u32 | `flags` (0) |
///
/// The payload is `2 · width · height` float32: the amplitude's rows, then the phase's
/// (radians, −π…π).
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("fpm::SnapshotHeader/1")]
#[repr(C)]
pub struct SnapshotHeader {
    /// The service's job.
    pub job: i64,
    /// Counts up per snapshot of the service.
    pub seq: u64,
    /// Frames in it.
    pub frames: u64,
    /// LEDs in the job's capture.
    pub of: u64,
    /// Its pixel in the sample plane, µm.
    pub pixel_um: f64,
    /// Pixels per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// 1: the finished reconstruction; 0: the stream's state.
    pub finished: u32,
    /// Reserved, 0.
    pub flags: u32,
}

impl SnapshotHeader {
    /// The iceoryx2 type name a subscriber in another language must declare.
    pub const TYPE_NAME: &'static str = "fpm::SnapshotHeader/1";
}

/// The snapshot service of the acquisition service listening on `port`.
pub fn snapshot_service_name(port: u16) -> String {
    format!("fpm/serve/{port}/snapshots")
}

/// Viewers a snapshot service admits.
const MAX_VIEWERS: usize = 8;

type SnapshotService = publish_subscribe::PortFactory<ipc::Service, [f32], SnapshotHeader>;

fn open(node: &Node<ipc::Service>, name: &str) -> Result<SnapshotService, FrameError> {
    let name: ServiceName = name
        .try_into()
        .map_err(|e| ipc("snapshot service name")(&e))?;
    node.service_builder(&name)
        .publish_subscribe::<[f32]>()
        .user_header::<SnapshotHeader>()
        .max_publishers(1)
        .max_subscribers(MAX_VIEWERS)
        .history_size(1)
        .subscriber_max_buffer_size(2)
        .enable_safe_overflow(true)
        .open_or_create()
        .map_err(|e| ipc("opening the snapshot service")(&e))
}

/// The acquisition service's side. Like every iceoryx2 port, it stays on the thread
/// that made it.
pub struct SnapshotPublisher {
    port: Publisher<ipc::Service, [f32], SnapshotHeader>,
    _service: SnapshotService,
    _node: Node<ipc::Service>,
}

impl SnapshotPublisher {
    /// Publish on service `name` ([`snapshot_service_name`]).
    pub fn create(name: &str) -> Result<Self, FrameError> {
        let node = node("fpm-serve-snapshots")?;
        let service = open(&node, name)?;
        let port = service
            .publisher_builder()
            .initial_max_slice_len(2 * 256 * 256)
            // Snapshots grow with the field of view: the segment grows with them.
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(|e| ipc("creating the snapshot publisher")(&e))?;
        Ok(Self {
            port,
            _service: service,
            _node: node,
        })
    }

    /// Publish one snapshot: `amplitude` and `phase`, `header.width × header.height`
    /// each, row-major, written once into shared memory.
    pub fn publish(
        &self,
        header: SnapshotHeader,
        amplitude: impl ExactSizeIterator<Item = f32>,
        phase: impl ExactSizeIterator<Item = f32>,
    ) -> Result<usize, FrameError> {
        let area = header.width as usize * header.height as usize;
        if amplitude.len() != area || phase.len() != area {
            return Err(FrameError::Invalid {
                frame_number: header.seq,
                field: "width/height",
                problem: format!(
                    "{}x{} but {} amplitude and {} phase values",
                    header.width,
                    header.height,
                    amplitude.len(),
                    phase.len()
                ),
            });
        }
        let mut sample = self
            .port
            .loan_slice_uninit(2 * area)
            .map_err(|e| ipc("loaning a snapshot buffer")(&e))?;
        *sample.user_header_mut() = header;
        for (slot, value) in sample.payload_mut().iter_mut().zip(amplitude.chain(phase)) {
            slot.write(value);
        }
        // SAFETY: the loop wrote all 2 · area values (both iterators hold `area`).
        let sample = unsafe { sample.assume_init() };
        sample.send().map_err(|e| ipc("sending a snapshot")(&e))
    }

    /// Hand the newest snapshot to viewers that connected since.
    pub fn serve(&self) {
        let _ = self.port.update_connections();
    }
}

/// A snapshot received, still in shared memory (released when dropped).
pub struct SnapshotView {
    sample: Sample<ipc::Service, [f32], SnapshotHeader>,
}

impl SnapshotView {
    /// Its header.
    pub fn header(&self) -> &SnapshotHeader {
        self.sample.user_header()
    }

    /// The amplitude, row-major.
    pub fn amplitude(&self) -> &[f32] {
        let area = self.sample.payload().len() / 2;
        &self.sample.payload()[..area]
    }

    /// The phase, radians, row-major.
    pub fn phase(&self) -> &[f32] {
        let area = self.sample.payload().len() / 2;
        &self.sample.payload()[area..]
    }
}

/// A local viewer's side.
pub struct SnapshotSubscriber {
    port: Subscriber<ipc::Service, [f32], SnapshotHeader>,
    _service: SnapshotService,
    _node: Node<ipc::Service>,
}

impl SnapshotSubscriber {
    /// Subscribe to service `name` (the newest snapshot, if any, comes first).
    pub fn create(name: &str) -> Result<Self, FrameError> {
        let node = node("fpm-snapshot-viewer")?;
        let service = open(&node, name)?;
        let port = service
            .subscriber_builder()
            .create()
            .map_err(|e| ipc("creating the snapshot subscriber")(&e))?;
        Ok(Self {
            port,
            _service: service,
            _node: node,
        })
    }

    /// The next snapshot, polling up to `timeout`. One whose payload does not hold
    /// `2 · width · height` values is an error naming the field.
    pub fn next(&self, timeout: Duration) -> Result<Option<SnapshotView>, FrameError> {
        let deadline = std::time::Instant::now() + timeout;
        loop {
            if let Some(sample) = self
                .port
                .receive()
                .map_err(|e| ipc("receiving a snapshot")(&e))?
            {
                let h = *sample.user_header();
                let area = h.width as usize * h.height as usize;
                if sample.payload().len() != 2 * area {
                    return Err(FrameError::Invalid {
                        frame_number: h.seq,
                        field: "width/height",
                        problem: format!(
                            "{}x{} but the payload holds {} values",
                            h.width,
                            h.height,
                            sample.payload().len()
                        ),
                    });
                }
                return Ok(Some(SnapshotView { sample }));
            }
            if std::time::Instant::now() >= deadline {
                return Ok(None);
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::mem::{offset_of, size_of};

    #[test]
    fn the_layout_is_the_documented_one() {
        assert_eq!(size_of::<SnapshotHeader>(), 56);
        assert_eq!(offset_of!(SnapshotHeader, job), 0);
        assert_eq!(offset_of!(SnapshotHeader, seq), 8);
        assert_eq!(offset_of!(SnapshotHeader, frames), 16);
        assert_eq!(offset_of!(SnapshotHeader, of), 24);
        assert_eq!(offset_of!(SnapshotHeader, pixel_um), 32);
        assert_eq!(offset_of!(SnapshotHeader, width), 40);
        assert_eq!(offset_of!(SnapshotHeader, height), 44);
        assert_eq!(offset_of!(SnapshotHeader, finished), 48);
        assert_eq!(offset_of!(SnapshotHeader, flags), 52);
    }

    #[test]
    fn a_viewer_that_opens_late_gets_the_newest_snapshot_in_place() {
        let name = format!("fpm/test/{}/snapshots", std::process::id());
        let publisher = SnapshotPublisher::create(&name).unwrap();
        let header = |seq| SnapshotHeader {
            job: 7,
            seq,
            frames: 10 * seq,
            of: 441,
            pixel_um: 0.15,
            width: 3,
            height: 2,
            finished: 0,
            flags: 0,
        };
        for seq in 1..=2u64 {
            let amplitude = (0..6).map(|k| (k as f32) * seq as f32);
            let phase = (0..6).map(|k| -(k as f32));
            publisher.publish(header(seq), amplitude, phase).unwrap();
        }
        let viewer = SnapshotSubscriber::create(&name).unwrap();
        publisher.serve();
        let got = viewer
            .next(Duration::from_secs(2))
            .unwrap()
            .expect("the newest");
        assert_eq!(*got.header(), header(2));
        assert_eq!(got.amplitude(), &[0.0, 2.0, 4.0, 6.0, 8.0, 10.0]);
        assert_eq!(got.phase(), &[0.0, -1.0, -2.0, -3.0, -4.0, -5.0]);
        // A snapshot that does not fit its size is refused before anything is sent.
        let five = (0..5).map(|k| k as f32);
        let six = (0..6).map(|k| k as f32);
        let wrong = publisher.publish(header(3), five, six);
        assert!(matches!(
            wrong,
            Err(FrameError::Invalid {
                field: "width/height",
                ..
            })
        ));
    }
}
