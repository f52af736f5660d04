//! The typed client for the fpm LED controller (the RP2040 firmware or its emulator).
//!
//! [`Controller`] opens a serial port, checks the protocol version, and offers one
//! blocking method per endpoint, each with a timeout. Sequence progress arrives on a
//! [`SequenceEvents`] subscription.

pub mod discover;
mod error;
pub mod scan;
mod sequence;
mod transport;

use std::sync::Arc;
use std::time::Duration;

use fpm_protocol::*;
use postcard_rpc::header::VarSeqKind;
use postcard_rpc::host_client::{
    HostClient, HostClientConfig, HostErr, MultiSubRxError, MultiSubscription,
};
use postcard_rpc::standard_icd::PingEndpoint;
use postcard_rpc::Endpoint;

pub use error::ControllerError;
pub use sequence::{step_timeout, SequenceRun};

/// Result of a controller call.
pub type Result<T, E = ControllerError> = std::result::Result<T, E>;

/// Default time a request may take.
pub const DEFAULT_TIMEOUT: Duration = Duration::from_millis(1000);

/// Step events the client buffers for a subscriber (a 21×21 scan and then some).
const EVENT_DEPTH: usize = 4096;

/// A connection to an LED controller.
pub struct Controller {
    // Field order is drop order: the client closes, then the reader stops and
    // releases the port.
    client: HostClient<WireError>,
    _reader: transport::Reader,
    runtime: Arc<tokio::runtime::Runtime>,
    port: String,
    timeout: Duration,
    info: DeviceInfo,
}

impl Drop for Controller {
    fn drop(&mut self) {
        self.client.close();
    }
}

impl Controller {
    /// Open `port`, check that it speaks a compatible protocol, and read its identity.
    pub fn open(port: &str, timeout: Duration) -> Result<Self> {
        let serial = serialport::new(port, 115_200)
            .timeout(Duration::from_millis(50))
            .open()
            .map_err(|e| ControllerError::Open {
                port: port.into(),
                reason: e.to_string(),
            })?;
        // Bytes left from an earlier session would only confuse the framing.
        let _ = serial.clear(serialport::ClearBuffer::All);
        let mut serial = serial;
        // A lone delimiter ends any partial frame the device may be holding.
        std::io::Write::write_all(&mut serial, &[0]).map_err(|e| ControllerError::Open {
            port: port.into(),
            reason: e.to_string(),
        })?;

        // A current-thread runtime, driven by whichever call is waiting: a multi-thread
        // worker spinning between requests competes with the device process for the
        // CPU and added milliseconds to 5 % of round trips on two cores.
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_time()
            .build()
            .map_err(|e| ControllerError::Open {
                port: port.into(),
                reason: e.to_string(),
            })?;
        let (tx, rx, reader) =
            transport::split(serial, port.into()).map_err(|e| ControllerError::Open {
                port: port.into(),
                reason: e.to_string(),
            })?;
        let config = HostClientConfig {
            seq_kind: VarSeqKind::Seq4,
            err_uri_path: ERROR_PATH,
            outgoing_depth: 64,
            subscriber_timeout_if_full: Duration::from_millis(100),
        };
        let client = HostClient::new_with_wire_and_config(
            tx,
            rx,
            transport::Spawner(runtime.handle().clone()),
            &config,
        );

        let mut me = Self {
            client,
            _reader: reader,
            runtime: Arc::new(runtime),
            port: port.into(),
            timeout,
            info: placeholder_info(),
        };
        me.handshake()?;
        Ok(me)
    }

    fn handshake(&mut self) -> Result<()> {
        let device = match self.request::<VersionEndpoint>(&()) {
            Ok(v) => v,
            Err(ControllerError::Wire { error, .. }) => {
                return Err(ControllerError::NotFpm {
                    port: self.port.clone(),
                    reply: error.to_string(),
                })
            }
            Err(e) => return Err(e),
        };
        if !PROTOCOL_VERSION.accepts(&device) {
            let advice = if device.is_older_than(&PROTOCOL_VERSION) {
                "flash newer firmware onto the controller: fpm device flash fpm-led-controller.uf2 (a board older than protocol 1.3 is put in BOOTSEL by hand first: docs/hardware.md)"
            } else {
                "update the fpm host software"
            };
            return Err(ControllerError::VersionMismatch {
                port: self.port.clone(),
                host: PROTOCOL_VERSION,
                device,
                advice,
            });
        }
        self.info = self.request::<InfoEndpoint>(&())?;
        Ok(())
    }

    /// The port this controller was opened on.
    pub fn port(&self) -> &str {
        &self.port
    }

    /// The identity read at connection time.
    pub fn info(&self) -> &DeviceInfo {
        &self.info
    }

    /// Change the per-request timeout.
    pub fn set_timeout(&mut self, timeout: Duration) {
        self.timeout = timeout;
    }

    /// Whether the link has closed.
    pub fn is_closed(&self) -> bool {
        self.client.is_closed()
    }

    /// Send a request and wait for its reply (or the timeout).
    pub fn request<E: Endpoint>(&self, req: &E::Request) -> Result<E::Response>
    where
        E::Request: serde::Serialize + postcard_schema::Schema,
        E::Response: serde::de::DeserializeOwned + postcard_schema::Schema,
    {
        let fut = self.client.send_resp::<E>(req);
        let res = self
            .runtime
            .block_on(async { tokio::time::timeout(self.timeout, fut).await });
        match res {
            Err(_) if self.client.is_closed() => Err(self.disconnected(E::PATH)),
            Err(_) => Err(ControllerError::Timeout {
                port: self.port.clone(),
                request: E::PATH,
                timeout: self.timeout,
            }),
            Ok(Ok(r)) => Ok(r),
            Ok(Err(HostErr::Wire(error))) => Err(ControllerError::Wire {
                port: self.port.clone(),
                request: E::PATH,
                error,
            }),
            Ok(Err(HostErr::Closed)) => Err(self.disconnected(E::PATH)),
            Ok(Err(HostErr::BadResponse | HostErr::Postcard(_))) => {
                Err(ControllerError::BadReply {
                    port: self.port.clone(),
                    request: E::PATH,
                })
            }
        }
    }

    /// A request whose reply is `Result<T, DeviceError>`: flatten the device's refusal.
    fn checked<E, T>(&self, req: &E::Request) -> Result<T>
    where
        E: Endpoint<Response = Result<T, DeviceError>>,
        E::Request: serde::Serialize + postcard_schema::Schema,
        E::Response: serde::de::DeserializeOwned + postcard_schema::Schema,
    {
        self.request::<E>(req)?
            .map_err(|error| ControllerError::Device {
                request: E::PATH,
                error,
            })
    }

    fn disconnected(&self, request: &'static str) -> ControllerError {
        ControllerError::Disconnected {
            port: self.port.clone(),
            request,
        }
    }

    /// Fail with [`ControllerError::Unsupported`] if the device predates `since`.
    fn require(&self, since: ProtocolVersion, request: &'static str) -> Result<()> {
        let device = self.info.protocol;
        if device.supports(since) {
            Ok(())
        } else {
            Err(ControllerError::Unsupported {
                port: self.port.clone(),
                request,
                since,
                device,
            })
        }
    }

    /// Gamma correction on or off (`None`: only ask); returns whether it is on
    /// (protocol ≥ 1.1).
    pub fn gamma(&self, on: Option<bool>) -> Result<bool> {
        self.require(PROTOCOL_1_1, GammaEndpoint::PATH)?;
        self.checked::<GammaEndpoint, _>(&on)
    }

    /// Restart the board in the RP2040 boot ROM's USB mode (BOOTSEL: its RPI-RP2 drive
    /// and PICOBOOT), for flashing it in place (protocol ≥ 1.3). A running sequence is
    /// aborted first; the board turns every LED off, answers, and leaves this port,
    /// so the controller is of no further use.
    pub fn reboot_to_bootsel(self) -> Result<()> {
        self.require(PROTOCOL_1_3, BootselEndpoint::PATH)?;
        if self.sequence_status()?.state == SequenceState::Running {
            self.abort_sequence()?;
        }
        self.checked::<BootselEndpoint, _>(&())
    }

    /// The array geometry stored on the board (protocol ≥ 1.1).
    pub fn stored_calibration(&self) -> Result<StoredCalibration> {
        self.require(BoardCalibration::SINCE, GeometryEndpoint::PATH)?;
        self.request::<GeometryEndpoint>(&())
    }

    /// Store `calibration` on the board (`None`: forget it); returns what the board
    /// reads back (protocol ≥ 1.1).
    pub fn store_calibration(
        &self,
        calibration: Option<BoardCalibration>,
    ) -> Result<StoredCalibration> {
        self.require(BoardCalibration::SINCE, GeometrySetEndpoint::PATH)?;
        self.request::<GeometrySetEndpoint>(&calibration)?
            .map_err(ControllerError::Storage)
    }

    /// Echo a number (link check).
    pub fn ping(&self, x: u32) -> Result<u32> {
        self.request::<PingEndpoint>(&x)
    }

    /// Request round-trip times, µs: `warm_up` pings unmeasured, then `count` measured,
    /// each echo checked.
    pub fn ping_round_trips(&self, warm_up: u32, count: u32) -> Result<Vec<f64>> {
        for i in 0..warm_up {
            self.ping(i)?;
        }
        let mut times = Vec::with_capacity(count as usize);
        for i in 0..count {
            let t = std::time::Instant::now();
            let echo = self.ping(i)?;
            if echo != i {
                return Err(ControllerError::BadReply {
                    port: self.port.clone(),
                    request: "ping (wrong echo)",
                });
            }
            times.push(t.elapsed().as_secs_f64() * 1e6);
        }
        Ok(times)
    }

    /// The device's protocol version.
    pub fn version(&self) -> Result<ProtocolVersion> {
        self.request::<VersionEndpoint>(&())
    }

    /// Read the identity again.
    pub fn read_info(&self) -> Result<DeviceInfo> {
        self.request::<InfoEndpoint>(&())
    }

    /// The device's state.
    pub fn status(&self) -> Result<DeviceStatus> {
        self.request::<StatusEndpoint>(&())
    }

    /// Light one LED, everything else off.
    pub fn set_led(&self, led: LedIndex, color: Rgb) -> Result<Lit> {
        self.checked::<SetLedEndpoint, _>(&SetLed { led, color })
    }

    /// Light a list of LEDs (sent in chunks the device accepts; `keep_others` applies
    /// to the first chunk, later ones add).
    pub fn set_leds(&self, leds: &[LedIndex], color: Rgb, keep_others: bool) -> Result<Lit> {
        let max = (self.info.limits.max_leds_per_list as usize).clamp(1, limits::MAX_LEDS_PER_LIST);
        if leds.is_empty() {
            return if keep_others {
                self.status().map(|s| lit_from_status(&s))
            } else {
                self.clear()
            };
        }
        let mut last = None;
        for (i, chunk) in leds.chunks(max).enumerate() {
            let req = SetLeds {
                leds: heapless::Vec::from_slice(chunk)
                    .map_err(|_| ControllerError::Invalid("LED list chunk too long".into()))?,
                color,
                keep_others: keep_others || i > 0,
            };
            last = Some(self.checked::<SetLedsEndpoint, _>(&req)?);
        }
        last.ok_or_else(|| ControllerError::Invalid("empty LED list".into()))
    }

    /// Everything off.
    pub fn clear(&self) -> Result<Lit> {
        self.checked::<ClearEndpoint, _>(&())
    }

    /// Light an on-device pattern.
    pub fn pattern(&self, pattern: Pattern, color: Rgb) -> Result<Lit> {
        self.checked::<PatternEndpoint, _>(&PatternRequest { pattern, color })
    }

    /// Set the global brightness.
    pub fn set_brightness(&self, level: u8) -> Result<Lit> {
        self.checked::<BrightnessEndpoint, _>(&level)
    }

    /// Set the current budget.
    pub fn set_budget(&self, budget: BudgetConfig) -> Result<BudgetConfig> {
        self.checked::<BudgetEndpoint, _>(&budget)
    }

    /// Define and upload a sequence in chunks. Returns the final load state.
    pub fn upload_sequence(
        &self,
        id: u32,
        steps: &[Step],
        timing: SequenceTiming,
    ) -> Result<StepsLoaded> {
        self.upload_chunks(id, steps, timing, |offset, steps| {
            self.checked::<SequenceStepsEndpoint, _>(&StepChunk { id, offset, steps })
        })
    }

    /// Fill the LED set table with `sets`, in order (protocol ≥ 1.2): what
    /// [`Self::upload_set_sequence`]'s steps name by index. Replaces the table.
    pub fn define_led_sets(&self, sets: &[Vec<LedIndex>]) -> Result<LedSetsDefined> {
        self.require(PROTOCOL_1_2, LedSetDefineEndpoint::PATH)?;
        let max_list = (self.info.limits.max_leds_per_list as usize).min(limits::MAX_LEDS_PER_LIST);
        if sets.is_empty() || sets.len() > limits::MAX_LED_SETS {
            return Err(ControllerError::Invalid(format!(
                "a table needs 1 to {} LED sets, this one has {}",
                limits::MAX_LED_SETS,
                sets.len()
            )));
        }
        let mut defined = LedSetsDefined { sets: 0, leds: 0 };
        for (index, set) in sets.iter().enumerate() {
            if set.is_empty() || set.len() > max_list {
                return Err(ControllerError::Invalid(format!(
                    "LED set {index} has {} LEDs: give 1 to {max_list}",
                    set.len()
                )));
            }
            let req = LedSetDefine {
                index: index as u16,
                leds: heapless::Vec::from_slice(set)
                    .map_err(|_| ControllerError::Invalid("LED set too long".into()))?,
            };
            defined = self.checked::<LedSetDefineEndpoint, _>(&req)?;
        }
        Ok(defined)
    }

    /// Define and upload a sequence whose steps each light a set of the table
    /// ([`Self::define_led_sets`]; protocol ≥ 1.2). Its steps are reported as
    /// [`SequenceEvent::SetStep`].
    pub fn upload_set_sequence(
        &self,
        id: u32,
        steps: &[SetStep],
        timing: SequenceTiming,
    ) -> Result<StepsLoaded> {
        self.require(PROTOCOL_1_2, SequenceSetStepsEndpoint::PATH)?;
        self.upload_chunks(id, steps, timing, |offset, steps| {
            self.checked::<SequenceSetStepsEndpoint, _>(&SetStepChunk { id, offset, steps })
        })
    }

    /// Define sequence `id` of `steps` and send them in chunks of what the device
    /// takes, each with `send(offset, chunk)`. Returns the final load state.
    fn upload_chunks<T: Clone>(
        &self,
        id: u32,
        steps: &[T],
        timing: SequenceTiming,
        send: impl Fn(u16, heapless::Vec<T, { limits::MAX_STEPS_PER_CHUNK }>) -> Result<StepsLoaded>,
    ) -> Result<StepsLoaded> {
        let max = self.info.limits.max_sequence_steps as usize;
        if steps.len() > max || steps.is_empty() {
            return Err(ControllerError::Invalid(format!(
                "a sequence needs 1 to {max} steps, this one has {}",
                steps.len()
            )));
        }
        self.checked::<SequenceDefineEndpoint, _>(&SequenceDefine {
            id,
            steps: steps.len() as u16,
            timing,
        })?;
        let per_chunk =
            (self.info.limits.max_steps_per_chunk as usize).clamp(1, limits::MAX_STEPS_PER_CHUNK);
        let mut loaded = StepsLoaded {
            loaded: 0,
            total: steps.len() as u16,
        };
        for (k, chunk) in steps.chunks(per_chunk).enumerate() {
            let chunk = heapless::Vec::from_slice(chunk)
                .map_err(|_| ControllerError::Invalid("step chunk too long".into()))?;
            loaded = send((k * per_chunk) as u16, chunk)?;
        }
        Ok(loaded)
    }

    /// Start the uploaded sequence.
    pub fn start_sequence(&self, id: u32) -> Result<SequenceStarted> {
        self.checked::<SequenceStartEndpoint, _>(&id)
    }

    /// Abort the running sequence.
    pub fn abort_sequence(&self) -> Result<SequenceStatus> {
        self.checked::<SequenceAbortEndpoint, _>(&())
    }

    /// The sequence engine's state.
    pub fn sequence_status(&self) -> Result<SequenceStatus> {
        self.request::<SequenceStatusEndpoint>(&())
    }

    /// Subscribe to step and end events. Subscribe before starting a sequence so no
    /// event is missed.
    pub fn subscribe(&self) -> Result<SequenceEvents> {
        let (steps, set_steps, ends) = self.runtime.block_on(async {
            let steps = self.client.subscribe_multi::<StepTopic>(EVENT_DEPTH).await;
            let set_steps = self
                .client
                .subscribe_multi::<SetStepTopic>(EVENT_DEPTH)
                .await;
            let ends = self.client.subscribe_multi::<SequenceEndTopic>(16).await;
            (steps, set_steps, ends)
        });
        match (steps, set_steps, ends) {
            (Ok(steps), Ok(set_steps), Ok(ends)) => Ok(SequenceEvents {
                steps,
                set_steps,
                ends,
                runtime: self.runtime.clone(),
                closed: ClosedProbe(self.client.clone()),
                port: self.port.clone(),
            }),
            _ => Err(self.disconnected("subscribe")),
        }
    }
}

fn lit_from_status(s: &DeviceStatus) -> Lit {
    Lit {
        leds_on: s.leds_on,
        current_ma: s.current_ma,
        brightness: s.brightness,
        scaled: false,
        latched_us: s.now_us,
    }
}

fn placeholder_info() -> DeviceInfo {
    let b = fpm_firmware::BoardConfig::PICO_21X21;
    DeviceInfo {
        protocol: PROTOCOL_VERSION,
        firmware: fpm_firmware::board::FIRMWARE_VERSION,
        board: heapless::String::new(),
        serial: 0,
        geometry: b.geometry,
        channels: b.channels,
        triggers: b.triggers,
        limits: b.limits(),
    }
}

struct ClosedProbe(HostClient<WireError>);

impl SequenceEvent {
    /// A finished step's (sequence id, index, trigger time µs, end time µs), whichever
    /// topic it came on; None for the end.
    pub fn step_times(&self) -> Option<(u32, u16, u64, u64)> {
        match self {
            SequenceEvent::Step(s) => Some((s.sequence_id, s.step, s.trigger_us, s.end_us)),
            SequenceEvent::SetStep(s) => Some((s.sequence_id, s.step, s.trigger_us, s.end_us)),
            SequenceEvent::End(_) => None,
        }
    }
}

/// One message of the sequence topics.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum SequenceEvent {
    /// A step finished.
    Step(StepEvent),
    /// A step lighting an LED set finished (protocol ≥ 1.2).
    SetStep(SetStepEvent),
    /// The run ended.
    End(SequenceEnd),
}

/// A subscription to sequence progress.
pub struct SequenceEvents {
    steps: MultiSubscription<StepEvent>,
    set_steps: MultiSubscription<SetStepEvent>,
    ends: MultiSubscription<SequenceEnd>,
    runtime: Arc<tokio::runtime::Runtime>,
    closed: ClosedProbe,
    port: String,
}

impl SequenceEvents {
    /// The next event, waiting at most `timeout`. Steps always come before the end
    /// that follows them.
    pub fn next(&mut self, timeout: Duration) -> Result<SequenceEvent> {
        let port = self.port.clone();
        let lost = || ControllerError::Disconnected {
            port: port.clone(),
            request: "the sequence events",
        };
        let closed = &self.closed.0;
        let res = self.runtime.block_on(async {
            tokio::time::timeout(timeout, async {
                tokio::select! {
                    biased;
                    s = self.steps.recv() => s.map(SequenceEvent::Step),
                    s = self.set_steps.recv() => s.map(SequenceEvent::SetStep),
                    e = self.ends.recv() => e.map(SequenceEvent::End),
                    _ = closed.wait_closed() => Err(MultiSubRxError::IoClosed),
                }
            })
            .await
        });
        match res {
            Ok(Ok(ev)) => Ok(ev),
            Ok(Err(MultiSubRxError::Lagged(n))) => Err(ControllerError::Invalid(format!(
                "missed {n} sequence events: the subscriber fell behind"
            ))),
            Ok(Err(_)) => Err(lost()),
            Err(_) if closed.is_closed() => Err(lost()),
            Err(_) => Err(ControllerError::Timeout {
                port: self.port.clone(),
                request: "the next sequence event",
                timeout,
            }),
        }
    }
}
