//! What a camera says about itself: the settings it applied (JSON), kept on
//! `fpm/camera/<id>/settings` with a history of one, so that an acquisition started
//! later still reads them. Optional: a camera that does not publish them is fine.

use std::time::{Duration, Instant};

use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::publish_subscribe;

use crate::service::{node, ServiceNames};
use crate::{ipc, FrameError};

/// Longest settings document, bytes.
pub const MAX_SETTINGS_BYTES: usize = 16 * 1024;

type SettingsService = publish_subscribe::PortFactory<ipc::Service, [u8], ()>;

fn open(node: &Node<ipc::Service>, names: &ServiceNames) -> Result<SettingsService, FrameError> {
    let name: ServiceName = names
        .settings
        .as_str()
        .try_into()
        .map_err(|e| ipc("settings service name")(&e))?;
    node.service_builder(&name)
        .publish_subscribe::<[u8]>()
        .max_publishers(1)
        .history_size(1)
        .subscriber_max_buffer_size(1)
        .open_or_create()
        .map_err(|e| ipc("opening the camera settings service")(&e))
}

/// The camera side.
pub struct SettingsPublisher {
    port: Publisher<ipc::Service, [u8], ()>,
    _service: SettingsService,
    _node: Node<ipc::Service>,
}

impl SettingsPublisher {
    /// Publish `json` for camera `names`; keep this alive (and call
    /// [`SettingsPublisher::serve`] now and then) for late readers.
    pub fn create(names: &ServiceNames, json: &str) -> Result<Self, FrameError> {
        if json.len() > MAX_SETTINGS_BYTES {
            return Err(FrameError::Invalid {
                frame_number: 0,
                field: "settings",
                problem: format!("{} bytes, more than {MAX_SETTINGS_BYTES}", json.len()),
            });
        }
        let node = node("fpm-camera-settings")?;
        let service = open(&node, names)?;
        let port = service
            .publisher_builder()
            .initial_max_slice_len(MAX_SETTINGS_BYTES)
            .create()
            .map_err(|e| ipc("creating the settings publisher")(&e))?;
        let sample = port
            .loan_slice_uninit(json.len())
            .map_err(|e| ipc("loaning the settings sample")(&e))?;
        sample
            .write_from_slice(json.as_bytes())
            .send()
            .map_err(|e| ipc("sending the settings")(&e))?;
        Ok(Self {
            port,
            _service: service,
            _node: node,
        })
    }

    /// Hand the settings to readers that connected since (iceoryx2 delivers history
    /// when the publisher updates its connections).
    pub fn serve(&self) {
        if let Err(e) = self.port.update_connections() {
            let _ = e; // a reader that went away; the next call retries
        }
    }
}

/// The settings camera `names` published, if it did within `timeout`.
pub fn read_settings(names: &ServiceNames, timeout: Duration) -> Option<String> {
    let node = node("fpm-camera-settings-reader").ok()?;
    let service = open(&node, names).ok()?;
    let port = service.subscriber_builder().create().ok()?;
    let deadline = Instant::now() + timeout;
    loop {
        if let Ok(Some(sample)) = port.receive() {
            return String::from_utf8(sample.payload().to_vec()).ok();
        }
        if Instant::now() >= deadline {
            return None;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}
