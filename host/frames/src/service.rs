//! Every iceoryx2 service the frame road uses, built in one place.

use std::sync::atomic::{AtomicBool, Ordering};

use iceoryx2::node::NodeState;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::{event, publish_subscribe};

use crate::{ipc, FrameError, FrameHeader};

/// The event id of "a frame was published".
pub const FRAME_READY: usize = 1;

/// Subscribers a frame service admits: the acquisition service and one monitor.
const MAX_SUBSCRIBERS: usize = 2;
/// Frames buffered per subscriber beyond the one it holds.
const SUBSCRIBER_BUFFER: usize = 2;
/// Frames a subscriber may hold at once.
const SUBSCRIBER_BORROWED: usize = 1;
/// Frames the publisher may have loaned at once.
const PUBLISHER_LOANED: usize = 1;

/// Samples in each publisher's shared-memory segment (iceoryx2's formula:
/// subscribers · (buffer + borrowed) + history + loaned).
pub const SAMPLES_PER_PUBLISHER: usize =
    MAX_SUBSCRIBERS * (SUBSCRIBER_BUFFER + SUBSCRIBER_BORROWED) + PUBLISHER_LOANED;

/// The services of one camera.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ServiceNames {
    /// Publish-subscribe of frames.
    pub frames: String,
    /// Event: a frame was published.
    pub ready: String,
    /// Publish-subscribe, history 1: the settings the camera applied, JSON.
    pub settings: String,
}

impl ServiceNames {
    /// `fpm/camera/<id>/frames` and `fpm/camera/<id>/frame-ready`. `id` names the
    /// camera (tests use a unique one per run so they never meet).
    pub fn for_camera(id: &str) -> Self {
        Self {
            frames: format!("fpm/camera/{id}/frames"),
            ready: format!("fpm/camera/{id}/frame-ready"),
            settings: format!("fpm/camera/{id}/settings"),
        }
    }
}

pub(crate) type PubSub = publish_subscribe::PortFactory<ipc::Service, [u16], FrameHeader>;
pub(crate) type Event = event::PortFactory<ipc::Service>;
pub(crate) type FramePort = Publisher<ipc::Service, [u16], FrameHeader>;

/// Whether the application chose iceoryx2's log level ([`set_ipc_log_level`]).
static LOG_LEVEL_CHOSEN: AtomicBool = AtomicBool::new(false);

/// Set iceoryx2's own log level for this process (e.g. `LogLevel::Warn` with `-v`);
/// `IOX2_LOG_LEVEL` still overrides. Without a call, only iceoryx2's errors are
/// printed: it warns on every start that it runs without a config file, which we
/// never need.
pub fn set_ipc_log_level(level: LogLevel) {
    LOG_LEVEL_CHOSEN.store(true, Ordering::SeqCst);
    set_log_level_from_env_or(level);
}

/// Before any iceoryx2 call: quiet unless the application chose otherwise.
fn quiet_by_default() {
    if !LOG_LEVEL_CHOSEN.load(Ordering::SeqCst) {
        set_log_level_from_env_or(LogLevel::Error);
    }
}

/// An iceoryx2 node of this process, with signal handling left to the application and
/// iceoryx2's log quiet by default.
pub fn node(name: &str) -> Result<Node<ipc::Service>, FrameError> {
    quiet_by_default();
    let name: NodeName = name.try_into().map_err(|e| ipc("node name")(&e))?;
    NodeBuilder::new()
        .name(&name)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(|e| ipc("creating the node")(&e))
}

/// Open (or create) the frame and event services.
pub(crate) fn open(
    node: &Node<ipc::Service>,
    names: &ServiceNames,
) -> Result<(PubSub, Event), FrameError> {
    let frames: ServiceName = names
        .frames
        .as_str()
        .try_into()
        .map_err(|e| ipc("frame service name")(&e))?;
    let ready: ServiceName = names
        .ready
        .as_str()
        .try_into()
        .map_err(|e| ipc("event service name")(&e))?;
    let pubsub = node
        .service_builder(&frames)
        .publish_subscribe::<[u16]>()
        .user_header::<FrameHeader>()
        .max_publishers(1)
        .max_subscribers(MAX_SUBSCRIBERS)
        .subscriber_max_buffer_size(SUBSCRIBER_BUFFER)
        .subscriber_max_borrowed_samples(SUBSCRIBER_BORROWED)
        .history_size(0)
        .enable_safe_overflow(true)
        .open_or_create()
        .map_err(|e| ipc("opening the frame service")(&e))?;
    let event = node
        .service_builder(&ready)
        .event()
        .open_or_create()
        .map_err(|e| ipc("opening the frame-ready event")(&e))?;
    Ok((pubsub, event))
}

/// A publisher port with a fixed maximum frame size (no segment growth: the memory is
/// [`SAMPLES_PER_PUBLISHER`] × the maximum frame, reserved once).
pub(crate) fn publisher(service: &PubSub, max_pixels: usize) -> Result<FramePort, FrameError> {
    service
        .publisher_builder()
        .initial_max_slice_len(max_pixels)
        .allocation_strategy(AllocationStrategy::Static)
        .max_loaned_samples(PUBLISHER_LOANED)
        .create()
        .map_err(|e| ipc("creating the frame publisher")(&e))
}

/// How many dead nodes (processes that crashed or were killed) left resources behind,
/// without touching them: what `fpm doctor` reports.
pub fn stale_nodes() -> Result<usize, FrameError> {
    quiet_by_default();
    let mut dead = 0;
    Node::<ipc::Service>::list(Config::global_config(), |state| {
        if let NodeState::<ipc::Service>::Dead(_) = state {
            dead += 1;
        }
        CallbackProgression::Continue
    })
    .map_err(|e| ipc("listing nodes")(&e))?;
    Ok(dead)
}

/// Remove what crashed processes left behind (shared memory, service entries): safe
/// to call any time, a live process's resources are never touched. Returns how many
/// dead nodes were cleaned up.
pub fn cleanup_stale() -> Result<usize, FrameError> {
    quiet_by_default();
    let mut cleaned = 0;
    Node::<ipc::Service>::list(Config::global_config(), |state| {
        if let NodeState::<ipc::Service>::Dead(view) = state {
            if view.try_remove_stale_resources().is_ok() {
                cleaned += 1;
            }
        }
        CallbackProgression::Continue
    })
    .map_err(|e| ipc("listing nodes")(&e))?;
    Ok(cleaned)
}
