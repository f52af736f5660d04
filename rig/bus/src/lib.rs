//! # fpm-rig-bus
//!
//! The wiring of the virtual rig: what the emulated controller physically does (which
//! LEDs shine, when the camera trigger fires) and where the virtual focus stage is,
//! published over iceoryx2 for the virtual camera. It stands for the light path, the
//! trigger cable and the stage's motor cable of a real rig, so the camera side learns
//! nothing it could not see on real hardware. Its own crate so that the controller
//! emulator can publish without depending on the simulator.

use std::time::Duration;

use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;

use fpm_frames::{ipc_error as ipc, node, FrameError};

/// Most LEDs a pulse reports (a sequence step lights at most 64).
pub const MAX_LIT: usize = 64;

/// One lit LED.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("fpm::rig::LitLed/1")]
#[repr(C)]
pub struct LitLed {
    /// Grid row.
    pub row: u8,
    /// Grid column.
    pub col: u8,
    /// Red, green, blue (0–255).
    pub rgb: [u8; 3],
    /// Reserved.
    pub reserved: [u8; 3],
}

/// The camera trigger fired (its active edge), with what was lit at that moment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("fpm::rig::TriggerPulse/1")]
#[repr(C)]
pub struct TriggerPulse {
    /// Consecutive from 0 since the controller started.
    pub pulse_number: u64,
    /// When, on the controller's clock, µs.
    pub time_us: u64,
    /// Entries of `lit` in use.
    pub lit_count: u32,
    /// Reserved.
    pub reserved: u32,
    /// The LEDs shining.
    pub lit: [LitLed; MAX_LIT],
}

impl Default for TriggerPulse {
    fn default() -> Self {
        Self {
            pulse_number: 0,
            time_us: 0,
            lit_count: 0,
            reserved: 0,
            lit: [LitLed::default(); MAX_LIT],
        }
    }
}

impl TriggerPulse {
    /// Pulse `pulse_number` at `time_us` (controller clock) with the LEDs `lit`
    /// (row, col, colour), at most [`MAX_LIT`] of them.
    pub fn new(
        pulse_number: u64,
        time_us: u64,
        lit: impl IntoIterator<Item = (u8, u8, [u8; 3])>,
    ) -> Self {
        let mut pulse = Self {
            pulse_number,
            time_us,
            ..Self::default()
        };
        for (slot, (row, col, rgb)) in pulse.lit.iter_mut().zip(lit) {
            *slot = LitLed {
                row,
                col,
                rgb,
                reserved: [0; 3],
            };
            pulse.lit_count += 1;
        }
        pulse
    }

    /// The lit LEDs.
    pub fn lit(&self) -> &[LitLed] {
        &self.lit[..(self.lit_count as usize).min(MAX_LIT)]
    }
}

/// Where the virtual stage really is and which slide is on it.
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("fpm::rig::Stage/2")]
#[repr(C)]
pub struct Stage {
    /// Sample moved toward the LEDs by this much, µm (0 = in focus).
    pub defocus_um: f64,
    /// The slide position the stage was told to put under the optical axis, µm (the
    /// virtual camera adds the stage's hidden error).
    pub x_um: f64,
    pub y_um: f64,
    /// Which slide: [`Stage::SAMPLE`] or [`Stage::CALIBRATION_TARGET`].
    pub slide: u32,
    /// Reserved.
    pub reserved: u32,
}

impl Stage {
    /// The specimen.
    pub const SAMPLE: u32 = 0;
    /// A slide with one small feature, for pdcFPM.
    pub const CALIBRATION_TARGET: u32 = 1;
}

/// Service names of one virtual rig.
fn names(rig: &str) -> (String, String) {
    (
        format!("fpm/rig/{rig}/trigger"),
        format!("fpm/rig/{rig}/stage"),
    )
}

fn service_name(s: &str) -> Result<ServiceName, FrameError> {
    s.try_into().map_err(|e| ipc("rig service name")(&e))
}

/// Trigger pulses a listener may have queued: the camera renders far slower than a
/// sequence can step, and no pulse may be lost while it catches up.
const PULSE_QUEUE: usize = 1024;

type PulseService =
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, TriggerPulse, ()>;
type StageService =
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, Stage, ()>;

fn pulse_service(node: &Node<ipc::Service>, rig: &str) -> Result<PulseService, FrameError> {
    node.service_builder(&service_name(&names(rig).0)?)
        .publish_subscribe::<TriggerPulse>()
        .subscriber_max_buffer_size(PULSE_QUEUE)
        .history_size(0)
        .open_or_create()
        .map_err(|e| ipc("opening the trigger service")(&e))
}

/// The stage keeps its last position (history 1) for a camera that starts later.
fn stage_service(node: &Node<ipc::Service>, rig: &str) -> Result<StageService, FrameError> {
    node.service_builder(&service_name(&names(rig).1)?)
        .publish_subscribe::<Stage>()
        .history_size(1)
        .subscriber_max_buffer_size(8)
        .open_or_create()
        .map_err(|e| ipc("opening the stage service")(&e))
}

/// The controller side: publishes trigger pulses.
pub struct PulsePublisher {
    port: Publisher<ipc::Service, TriggerPulse, ()>,
    _service: PulseService,
    _node: Node<ipc::Service>,
}

impl PulsePublisher {
    /// For rig `rig`.
    pub fn create(rig: &str) -> Result<Self, FrameError> {
        let node = node("fpm-rig-light")?;
        let service = pulse_service(&node, rig)?;
        let port = service
            .publisher_builder()
            .create()
            .map_err(|e| ipc("creating the trigger publisher")(&e))?;
        Ok(Self {
            port,
            _service: service,
            _node: node,
        })
    }

    /// Publish a pulse.
    pub fn publish(&self, pulse: &TriggerPulse) -> Result<(), FrameError> {
        self.port
            .send_copy(*pulse)
            .map_err(|e| ipc("sending a trigger pulse")(&e))?;
        Ok(())
    }
}

/// The camera side: receives trigger pulses and reads the stage.
pub struct RigListener {
    pulses: Subscriber<ipc::Service, TriggerPulse, ()>,
    stage: Subscriber<ipc::Service, Stage, ()>,
    current: Stage,
    _services: (PulseService, StageService),
    _node: Node<ipc::Service>,
}

impl RigListener {
    /// For rig `rig`.
    pub fn create(rig: &str) -> Result<Self, FrameError> {
        let node = node("fpm-virtual-camera")?;
        let pulses = pulse_service(&node, rig)?;
        let stage = stage_service(&node, rig)?;
        let pulse_port = pulses
            .subscriber_builder()
            .buffer_size(PULSE_QUEUE)
            .create()
            .map_err(|e| ipc("subscribing to trigger pulses")(&e))?;
        let stage_port = stage
            .subscriber_builder()
            .create()
            .map_err(|e| ipc("subscribing to the stage")(&e))?;
        Ok(Self {
            pulses: pulse_port,
            stage: stage_port,
            current: Stage::default(),
            _services: (pulses, stage),
            _node: node,
        })
    }

    /// The next pulse, polling every millisecond up to `timeout` (the rig is a
    /// stand-in for a cable; its latency is not what is being measured).
    pub fn next_pulse(&mut self, timeout: Duration) -> Result<Option<TriggerPulse>, FrameError> {
        let deadline = std::time::Instant::now() + timeout;
        loop {
            if let Some(s) = self
                .pulses
                .receive()
                .map_err(|e| ipc("receiving a trigger pulse")(&e))?
            {
                return Ok(Some(*s.payload()));
            }
            if std::time::Instant::now() >= deadline {
                return Ok(None);
            }
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    /// The stage as last set.
    pub fn stage(&mut self) -> Result<Stage, FrameError> {
        while let Some(s) = self
            .stage
            .receive()
            .map_err(|e| ipc("reading the stage")(&e))?
        {
            self.current = *s.payload();
        }
        Ok(self.current)
    }
}

/// The motorised-stage controller (the acquisition service's side).
pub struct StageControl {
    port: Publisher<ipc::Service, Stage, ()>,
    _service: StageService,
    _node: Node<ipc::Service>,
}

impl StageControl {
    /// For rig `rig`.
    pub fn create(rig: &str) -> Result<Self, FrameError> {
        let node = node("fpm-stage")?;
        let service = stage_service(&node, rig)?;
        let port = service
            .publisher_builder()
            .create()
            .map_err(|e| ipc("creating the stage publisher")(&e))?;
        Ok(Self {
            port,
            _service: service,
            _node: node,
        })
    }

    /// Move the stage (takes effect for the next exposure).
    pub fn set(&self, stage: Stage) -> Result<(), FrameError> {
        self.port
            .send_copy(stage)
            .map_err(|e| ipc("moving the stage")(&e))?;
        Ok(())
    }
}

/// SIGINT/SIGTERM/SIGHUP for rig processes (the emulator, the virtual camera): they run
/// until told to stop, then leave iceoryx2 and their links cleanly.
pub mod stop {
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::{Arc, OnceLock};

    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};

    /// Set by the signals (signal-hook's handler only stores to it).
    fn flag() -> &'static Arc<AtomicBool> {
        static STOP: OnceLock<Arc<AtomicBool>> = OnceLock::new();
        STOP.get_or_init(Default::default)
    }

    /// Install the handlers.
    pub fn install() -> std::io::Result<()> {
        for sig in [SIGINT, SIGTERM, SIGHUP] {
            signal_hook::flag::register(sig, Arc::clone(flag()))?;
        }
        Ok(())
    }

    /// Whether a stop signal arrived.
    pub fn requested() -> bool {
        flag().load(Ordering::SeqCst)
    }
}
