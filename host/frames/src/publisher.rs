//! The camera side: publish a frame, then signal it.

use iceoryx2::port::notifier::Notifier;
use iceoryx2::prelude::*;

use crate::service::{self, FramePort, ServiceNames, FRAME_READY};
use crate::{ipc, FrameError, FrameHeader};

/// Publishes one camera's frames.
pub struct FramePublisher {
    // Field order is drop order: ports before services before the node.
    port: FramePort,
    notifier: Notifier<ipc::Service>,
    _services: (service::PubSub, service::Event),
    _node: Node<ipc::Service>,
    max_pixels: usize,
}

impl FramePublisher {
    /// Create the publisher for camera `names`, for frames of up to `max_pixels`.
    pub fn create(names: &ServiceNames, max_pixels: usize) -> Result<Self, FrameError> {
        let node = service::node("fpm-camera")?;
        let (pubsub, event) = service::open(&node, names)?;
        let port = service::publisher(&pubsub, max_pixels)?;
        let notifier = event
            .notifier_builder()
            .create()
            .map_err(|e| ipc("creating the frame-ready notifier")(&e))?;
        Ok(Self {
            port,
            notifier,
            _services: (pubsub, event),
            _node: node,
            max_pixels,
        })
    }

    /// Publish `pixels` (row-major, `header.width × header.height`) with `header`;
    /// `pixel_count` is filled in. The one copy is the write into shared memory;
    /// subscribers read it in place. Returns how many subscribers received it.
    pub fn publish(&self, header: FrameHeader, pixels: &[u16]) -> Result<usize, FrameError> {
        let header = self.checked(header, pixels.len())?;
        let mut sample = self
            .port
            .loan_slice_uninit(pixels.len())
            .map_err(|e| ipc("loaning a frame buffer")(&e))?;
        *sample.user_header_mut() = header;
        let sample = sample.write_from_slice(pixels);
        let receivers = sample.send().map_err(|e| ipc("sending a frame")(&e))?;
        signal(&self.notifier)?;
        Ok(receivers)
    }

    /// Publish a `header.width × header.height` frame whose pixels `fill` writes
    /// straight into shared memory (e.g. decoding a camera's packed pixels there): the
    /// one copy between a driver's buffer and the subscribers, and no zeroing first.
    /// `fill` must write every pixel; its error is reported as the frame's.
    pub fn publish_filled<E: std::fmt::Display>(
        &self,
        header: FrameHeader,
        fill: impl FnOnce(&mut [std::mem::MaybeUninit<u16>]) -> Result<(), E>,
    ) -> Result<usize, FrameError> {
        let pixels = header.width as usize * header.height as usize;
        let header = self.checked(header, pixels)?;
        let mut sample = self
            .port
            .loan_slice_uninit(pixels)
            .map_err(|e| ipc("loaning a frame buffer")(&e))?;
        *sample.user_header_mut() = header;
        fill(sample.payload_mut()).map_err(|e| FrameError::Invalid {
            frame_number: header.frame_number,
            field: "pixels",
            problem: e.to_string(),
        })?;
        // SAFETY: `fill` returned Ok, promising every pixel written.
        let sample = unsafe { sample.assume_init() };
        let receivers = sample.send().map_err(|e| ipc("sending a frame")(&e))?;
        signal(&self.notifier)?;
        Ok(receivers)
    }

    /// Borrow a buffer in shared memory for a `width × height` frame, for a driver
    /// that writes (or DMAs) pixels straight into it: no copy at all. The buffer is
    /// zeroed; fill [`FrameLoan::pixels_mut`], then [`FrameLoan::send`].
    pub fn loan(&self, header: FrameHeader) -> Result<FrameLoan<'_>, FrameError> {
        let pixels = header.width as usize * header.height as usize;
        let header = self.checked(header, pixels)?;
        let mut sample = self
            .port
            .loan_slice(pixels)
            .map_err(|e| ipc("loaning a frame buffer")(&e))?;
        *sample.user_header_mut() = header;
        Ok(FrameLoan {
            sample,
            notifier: &self.notifier,
        })
    }

    /// The largest frame this publisher takes, pixels.
    pub fn max_pixels(&self) -> usize {
        self.max_pixels
    }

    /// `header` carrying `pixels` pixels, checked against the contract and this
    /// publisher's maximum before anything is loaned.
    fn checked(&self, header: FrameHeader, pixels: usize) -> Result<FrameHeader, FrameError> {
        let header = FrameHeader {
            pixel_count: pixels as u64,
            ..header
        };
        crate::subscriber::validate(&header, pixels)?;
        if pixels > self.max_pixels {
            return Err(FrameError::TooLarge {
                pixels,
                max: self.max_pixels,
            });
        }
        Ok(header)
    }
}

/// Tell the subscribers a frame is there.
fn signal(notifier: &Notifier<ipc::Service>) -> Result<(), FrameError> {
    notifier
        .notify_with_custom_event_id(EventId::new(FRAME_READY))
        .map_err(|e| ipc("signalling a frame")(&e))?;
    Ok(())
}

/// A frame buffer in shared memory, being filled.
pub struct FrameLoan<'a> {
    sample: iceoryx2::sample_mut::SampleMut<ipc::Service, [u16], FrameHeader>,
    notifier: &'a Notifier<ipc::Service>,
}

impl FrameLoan<'_> {
    /// The pixels to fill, row-major.
    pub fn pixels_mut(&mut self) -> &mut [u16] {
        self.sample.payload_mut()
    }

    /// The header, e.g. to stamp the time just before sending.
    pub fn header_mut(&mut self) -> &mut FrameHeader {
        self.sample.user_header_mut()
    }

    /// Hand the frame to the subscribers and signal it. Returns how many received it.
    pub fn send(self) -> Result<usize, FrameError> {
        let receivers = self.sample.send().map_err(|e| ipc("sending a frame")(&e))?;
        signal(self.notifier)?;
        Ok(receivers)
    }
}
