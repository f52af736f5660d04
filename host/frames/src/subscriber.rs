//! The host side: sleep until a frame is signalled, read it in place.

use std::time::{Duration, Instant};

use iceoryx2::port::listener::Listener;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;

use crate::service::{self, ServiceNames};
use crate::{ipc, FrameError, FrameHeader};

/// A received frame, still in shared memory (released when dropped).
pub struct Frame {
    sample: Sample<ipc::Service, [u16], FrameHeader>,
}

impl Frame {
    /// Its header.
    pub fn header(&self) -> &FrameHeader {
        self.sample.user_header()
    }

    /// Its pixels, row-major, read where the camera wrote them.
    pub fn pixels(&self) -> &[u16] {
        self.sample.payload()
    }
}

/// Receives one camera's frames.
pub struct FrameSubscriber {
    port: Subscriber<ipc::Service, [u16], FrameHeader>,
    listener: Listener<ipc::Service>,
    _services: (service::PubSub, service::Event),
    _node: Node<ipc::Service>,
}

impl FrameSubscriber {
    /// Subscribe to camera `names` (the services are created if the camera is not up
    /// yet, so either side may start first).
    pub fn create(names: &ServiceNames) -> Result<Self, FrameError> {
        let node = service::node("fpm-host-frames")?;
        let (pubsub, event) = service::open(&node, names)?;
        let port = pubsub
            .subscriber_builder()
            .create()
            .map_err(|e| ipc("creating the frame subscriber")(&e))?;
        let listener = event
            .listener_builder()
            .create()
            .map_err(|e| ipc("creating the frame-ready listener")(&e))?;
        Ok(Self {
            port,
            listener,
            _services: (pubsub, event),
            _node: node,
        })
    }

    /// How many cameras publish on this service now (0: none is up).
    pub fn publishers(&self) -> usize {
        use iceoryx2::service::port_factory::PortFactory;
        self._services.0.dynamic_config().number_of_publishers()
    }

    /// Wait up to `timeout` for a camera to publish on this service; whether one does.
    pub fn wait_for_publisher(&self, timeout: Duration) -> bool {
        let deadline = Instant::now() + timeout;
        while self.publishers() == 0 {
            if Instant::now() >= deadline {
                return false;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        true
    }

    /// The next frame, waiting up to `timeout` for one (asleep, not polling). A frame
    /// whose header breaks the contract is an error naming the field.
    pub fn next(&self, timeout: Duration) -> Result<Option<Frame>, FrameError> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(sample) = self
                .port
                .receive()
                .map_err(|e| ipc("receiving a frame")(&e))?
            {
                validate(sample.user_header(), sample.payload().len())?;
                return Ok(Some(Frame { sample }));
            }
            let now = Instant::now();
            if now >= deadline {
                return Ok(None);
            }
            // Wake on the next signal (or the deadline); signals may be coalesced, so
            // always look at the buffer again. Never wait less than MIN_WAIT: a wait
            // under a µs became "forever" (an acquisition hung at the end of a capture,
            // its frame thread's deadline a few hundred ns away).
            self.listener
                .timed_wait(|_| {}, (deadline - now).max(MIN_WAIT))
                .map_err(|e| ipc("waiting for a frame")(&e))?;
        }
    }
}

/// The shortest wait for a frame's signal: iceoryx2 sets the wait as a socket timeout
/// in whole µs, where 0 means forever.
const MIN_WAIT: Duration = Duration::from_millis(1);

/// Check a header against its payload length.
pub(crate) fn validate(h: &FrameHeader, payload_len: usize) -> Result<(), FrameError> {
    let bad = |field: &'static str, problem: String| FrameError::Invalid {
        frame_number: h.frame_number,
        field,
        problem,
    };
    if h.width == 0 || h.height == 0 {
        return Err(bad("width/height", format!("is {}x{}", h.width, h.height)));
    }
    let area = h.width as u64 * h.height as u64;
    if h.pixel_count != area {
        return Err(bad(
            "pixel_count",
            format!("is {} but width × height is {area}", h.pixel_count),
        ));
    }
    if payload_len as u64 != h.pixel_count {
        return Err(bad(
            "pixel_count",
            format!(
                "is {} but the payload holds {payload_len} pixels",
                h.pixel_count
            ),
        ));
    }
    if !(1..=16).contains(&h.bit_depth) {
        return Err(bad(
            "bit_depth",
            format!("is {} (1–16 allowed)", h.bit_depth),
        ));
    }
    Ok(())
}
