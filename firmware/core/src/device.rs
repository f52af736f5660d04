//! The controller: request dispatch and the handlers behind each endpoint.

use fpm_protocol::limits::{MAX_ENCODED_FRAME_LEN, MAX_FRAME_LEN, MAX_LEDS_PER_LIST};
use fpm_protocol::*;
use postcard_rpc::header::{VarHeader, VarKey, VarSeq};
use postcard_rpc::standard_icd::{PingEndpoint, ERROR_KEY};
use postcard_rpc::{Endpoint, Key, Topic};
use serde::{de::DeserializeOwned, Serialize};

use crate::board::{BoardConfig, FIRMWARE_VERSION};
use crate::budget::Output;
use crate::chain::{chain_index, led_at};
use crate::hw::{FrameSink, LedStrip, TriggerOut};
use crate::led_sets::LedSets;
use crate::leds::LedState;
use crate::link::{encode, Feed, FrameReceiver};
use crate::patterns;
use crate::sequence::{Action, Done, Engine, Stored};
use crate::storage::CalibrationStore;
use embedded_storage::nor_flash::NorFlash;

/// Most engine actions carried out in one poll before yielding back to the shell.
const MAX_ACTIONS_PER_POLL: usize = 64;

/// The LED controller: feed it bytes, edges and time; it drives the strip and the
/// trigger line, keeps the board's calibration in flash `F`, and answers through a
/// [`FrameSink`].
pub struct Device<S: LedStrip, T: TriggerOut, F: NorFlash> {
    board: BoardConfig,
    serial: u64,
    strip: S,
    trigger: T,
    calibration: CalibrationStore<F>,
    leds: LedState,
    budget: BudgetConfig,
    engine: Engine,
    sets: LedSets,
    rx: FrameReceiver,
    stats: LinkStats,
    topic_seq: u32,
    tx_buf: [u8; MAX_FRAME_LEN],
    enc_buf: [u8; MAX_ENCODED_FRAME_LEN],
    /// A sequence step written to a strip that `latches_later`: its LEDs lit, and the
    /// model's latch time, until the shell reports the real one.
    awaiting_latch: Option<(u16, u64)>,
    /// The host asked for the boot ROM's USB mode ([`Device::bootsel_requested`]).
    bootsel: bool,
}

/// How long after the model's latch time a sequence waits for the shell's report
/// before it goes on with the model (a shell that never reports must not hang it).
const LATCH_REPORT_GRACE_US: u64 = 100_000;

impl<S: LedStrip, T: TriggerOut, F: NorFlash> Device<S, T, F> {
    /// A controller for `board`, all LEDs off, trigger line idle low, full brightness,
    /// budget at the board's maximum and refusing anything above it, its calibration
    /// kept in `calibration`.
    pub fn new(
        board: BoardConfig,
        serial: u64,
        strip: S,
        mut trigger: T,
        calibration: CalibrationStore<F>,
    ) -> Result<Self, &'static str> {
        board.validate()?;
        trigger.set_level(false);
        Ok(Self {
            leds: LedState::new(board.geometry.led_count() as usize, 255),
            budget: BudgetConfig {
                limit_ma: board.max_current_ma,
                policy: BudgetPolicy::Refuse,
            },
            board,
            serial,
            strip,
            trigger,
            calibration,
            engine: Engine::new(),
            sets: LedSets::new(),
            rx: FrameReceiver::new(),
            stats: LinkStats::default(),
            topic_seq: 0,
            awaiting_latch: None,
            bootsel: false,
            tx_buf: [0; MAX_FRAME_LEN],
            enc_buf: [0; MAX_ENCODED_FRAME_LEN],
        })
    }

    /// Whether the host asked to restart in the boot ROM's USB mode (BOOTSEL): the
    /// reply has been sent and every LED written off. The shell lets the reply and the
    /// strip's latch go out, then restarts there (`reset_to_usb_boot` on an RP2040);
    /// the controller answers nothing more meanwhile.
    pub fn bootsel_requested(&self) -> bool {
        self.bootsel
    }

    /// The LED strip driver (the emulator inspects it).
    pub fn strip_mut(&mut self) -> &mut S {
        &mut self.strip
    }

    /// The LED strip.
    pub fn strip(&self) -> &S {
        &self.strip
    }

    /// The calibration store (the emulator saves its flash image from it).
    pub fn calibration_store(&self) -> &CalibrationStore<F> {
        &self.calibration
    }

    /// The trigger line driver.
    pub fn trigger(&self) -> &T {
        &self.trigger
    }

    /// The board this controller drives.
    pub fn board(&self) -> &BoardConfig {
        &self.board
    }

    /// Current drawn by what is lit now, mA.
    pub fn current_ma(&self) -> u32 {
        self.leds.current_ma(self.board.channel_current_ua)
    }

    /// The current budget in force.
    pub fn budget(&self) -> BudgetConfig {
        self.budget
    }

    /// Link counters.
    pub fn link_stats(&self) -> LinkStats {
        self.stats
    }

    /// Feed bytes from the link at time `now` (µs). Complete requests are answered
    /// through `out`. Returns when [`Self::poll`] must run next.
    pub fn receive(&mut self, bytes: &[u8], now: u64, out: &mut impl FrameSink) -> Option<u64> {
        let mut frame = [0u8; MAX_FRAME_LEN];
        for &b in bytes {
            let len = match self.rx.feed(b) {
                Feed::Pending => continue,
                Feed::Dropped => {
                    self.stats.frames_dropped = self.stats.frames_dropped.wrapping_add(1);
                    continue;
                }
                Feed::Frame(f) => {
                    let n = f.len().min(MAX_FRAME_LEN);
                    frame[..n].copy_from_slice(&f[..n]);
                    n
                }
            };
            self.dispatch(&frame[..len], now, out);
        }
        self.poll(now, out)
    }

    /// A trigger-in edge from the camera at `at` (µs). Returns when to poll next.
    pub fn trigger_edge(
        &mut self,
        edge: Edge,
        at: u64,
        now: u64,
        out: &mut impl FrameSink,
    ) -> Option<u64> {
        self.engine.edge(edge, at);
        self.poll(now, out)
    }

    /// Advance the capture sequence to `now`. Returns the next time anything is due
    /// (`None`: nothing until a request or an edge arrives).
    pub fn poll(&mut self, now: u64, out: &mut impl FrameSink) -> Option<u64> {
        if let Some((leds_on, model)) = self.awaiting_latch {
            if now >= model.saturating_add(LATCH_REPORT_GRACE_US) {
                self.awaiting_latch = None;
                self.engine.lit(now, leds_on);
            }
        }
        for _ in 0..MAX_ACTIONS_PER_POLL {
            match self.engine.next(now) {
                Action::Light { step } => {
                    let lit = self.light_step(step, now);
                    match lit {
                        // Data queued for a later shift: wait for the shell's report.
                        Ok(lit) if self.strip.latches_later() && lit.latched_us > now => {
                            self.awaiting_latch = Some((lit.leds_on, lit.latched_us));
                        }
                        Ok(lit) => self.engine.lit(lit.latched_us, lit.leds_on),
                        Err(e) => {
                            if let Some(end) = self.engine.stop(SequenceOutcome::Failed(e), now) {
                                self.finish(end, now, out);
                            }
                        }
                    }
                }
                Action::Trigger(active) => self.set_trigger(active),
                Action::StepDone(Done::Step(event)) => self.publish::<StepTopic>(&event, out),
                Action::StepDone(Done::Set(event)) => self.publish::<SetStepTopic>(&event, out),
                Action::End(end) => self.finish(end, now, out),
                Action::WaitUntil(t) => {
                    let grace = self
                        .awaiting_latch
                        .map(|(_, model)| model.saturating_add(LATCH_REPORT_GRACE_US));
                    return match (t, grace) {
                        (Some(a), Some(b)) => Some(a.min(b)),
                        (a, b) => a.or(b),
                    };
                }
            }
        }
        Some(now)
    }

    /// The strip (one that `latches_later`) has shifted out and latched everything
    /// written to it, at `at` (µs): a sequence step waiting for its LEDs settles from
    /// there. Returns when to poll next.
    pub fn strip_latched(&mut self, at: u64, now: u64, out: &mut impl FrameSink) -> Option<u64> {
        if let Some((leds_on, _)) = self.awaiting_latch.take() {
            self.engine.lit(at, leds_on);
        }
        self.poll(now, out)
    }

    // ---------------------------------------------------------------- dispatch

    fn dispatch(&mut self, frame: &[u8], now: u64, out: &mut impl FrameSink) {
        if self.bootsel {
            // Restarting in BOOTSEL: what comes after is the next firmware's to answer.
            return;
        }
        let Some((hdr, body)) = VarHeader::take_from_slice(frame) else {
            self.stats.frames_dropped = self.stats.frames_dropped.wrapping_add(1);
            return;
        };
        self.stats.frames_ok = self.stats.frames_ok.wrapping_add(1);

        macro_rules! route {
            ($($ep:ty => $handler:ident,)*) => {
                $(
                    if hdr.key == VarKey::Key8(<$ep as Endpoint>::REQ_KEY) {
                        return self.serve::<$ep, _>(&hdr, body, now, out, Self::$handler);
                    }
                )*
            };
        }
        route! {
            PingEndpoint => ping,
            VersionEndpoint => version,
            InfoEndpoint => info,
            StatusEndpoint => status,
            SetLedEndpoint => set_led,
            SetLedsEndpoint => set_leds,
            ClearEndpoint => clear,
            PatternEndpoint => pattern,
            BrightnessEndpoint => brightness,
            GammaEndpoint => gamma,
            BudgetEndpoint => set_budget,
            SequenceDefineEndpoint => seq_define,
            SequenceStepsEndpoint => seq_steps,
            SequenceStartEndpoint => seq_start,
            SequenceAbortEndpoint => seq_abort,
            SequenceStatusEndpoint => seq_status,
            GeometryEndpoint => geometry,
            GeometrySetEndpoint => set_geometry,
            LedSetDefineEndpoint => define_set,
            SequenceSetStepsEndpoint => seq_set_steps,
            BootselEndpoint => bootsel,
        }
        self.stats.unknown_keys = self.stats.unknown_keys.wrapping_add(1);
        self.send(ERROR_KEY, hdr.seq_no, &WireError::UnknownKey, out);
    }

    /// Decode a request strictly (no trailing bytes), run its handler, send the reply.
    fn serve<E, O>(
        &mut self,
        hdr: &VarHeader,
        body: &[u8],
        now: u64,
        out: &mut O,
        handler: fn(&mut Self, E::Request, u64, &mut O) -> E::Response,
    ) where
        E: Endpoint,
        E::Request: DeserializeOwned,
        E::Response: Serialize,
        O: FrameSink,
    {
        match postcard::take_from_bytes::<E::Request>(body) {
            Ok((req, [])) => {
                let resp = handler(self, req, now, out);
                self.send(E::RESP_KEY, hdr.seq_no, &resp, out);
            }
            _ => {
                self.stats.decode_errors = self.stats.decode_errors.wrapping_add(1);
                self.send(ERROR_KEY, hdr.seq_no, &WireError::DeserFailed, out);
            }
        }
    }

    fn publish<P: Topic>(&mut self, msg: &P::Message, out: &mut impl FrameSink)
    where
        P::Message: Serialize,
    {
        let seq = self.topic_seq;
        self.topic_seq = self.topic_seq.wrapping_add(1);
        self.send(P::TOPIC_KEY, VarSeq::Seq4(seq), msg, out);
    }

    fn send<M: Serialize + ?Sized>(
        &mut self,
        key: Key,
        seq_no: VarSeq,
        msg: &M,
        out: &mut impl FrameSink,
    ) {
        let hdr = VarHeader {
            key: VarKey::Key8(key),
            seq_no,
        };
        let used = match encode_message(&hdr, msg, &mut self.tx_buf) {
            Some(n) => n,
            // Cannot happen with this protocol's sizes; answer with a small error anyway.
            None => match encode_message(
                &VarHeader {
                    key: VarKey::Key8(ERROR_KEY),
                    seq_no,
                },
                &WireError::SerFailed,
                &mut self.tx_buf,
            ) {
                Some(n) => n,
                None => return,
            },
        };
        if let Some(wire) = encode(&self.tx_buf[..used], &mut self.enc_buf) {
            out.send(wire);
        }
    }

    // ---------------------------------------------------------------- handlers

    fn ping(&mut self, x: u32, _: u64, _: &mut impl FrameSink) -> u32 {
        x
    }

    fn version(&mut self, _: (), _: u64, _: &mut impl FrameSink) -> ProtocolVersion {
        PROTOCOL_VERSION
    }

    fn info(&mut self, _: (), _: u64, _: &mut impl FrameSink) -> DeviceInfo {
        let mut board = heapless::String::new();
        for ch in self.board.name.chars() {
            if board.push(ch).is_err() {
                break;
            }
        }
        DeviceInfo {
            protocol: PROTOCOL_VERSION,
            firmware: FIRMWARE_VERSION,
            board,
            serial: self.serial,
            geometry: self.board.geometry,
            channels: self.board.channels,
            triggers: self.board.triggers,
            limits: self.board.limits(),
        }
    }

    fn geometry(&mut self, _: (), _: u64, _: &mut impl FrameSink) -> StoredCalibration {
        self.calibration.load()
    }

    fn set_geometry(
        &mut self,
        update: CalibrationUpdate,
        _: u64,
        _: &mut impl FrameSink,
    ) -> StoreResult {
        // Programming flash stalls the whole chip for milliseconds: never mid-sequence.
        if self.engine.is_running() {
            return Err(StorageError::Busy);
        }
        self.calibration.save(update.as_ref())
    }

    fn status(&mut self, _: (), now: u64, _: &mut impl FrameSink) -> DeviceStatus {
        DeviceStatus {
            now_us: now,
            leds_on: self.leds.leds_on(),
            current_ma: self.leds.current_ma(self.board.channel_current_ua),
            brightness: self.leds.brightness(),
            budget: self.budget,
            sequence: self.engine.status(),
            link: self.stats,
        }
    }

    fn set_led(&mut self, req: SetLed, now: u64, _: &mut impl FrameSink) -> LitResult {
        self.not_running()?;
        let index = chain_index(&self.board.geometry, req.led).ok_or(bad_led(req.led))?;
        if let Some(px) = self.leds.stage(false).get_mut(index as usize) {
            *px = req.color;
        }
        self.commit(self.leds.brightness(), self.budget, now)
    }

    fn set_leds(&mut self, req: SetLeds, now: u64, _: &mut impl FrameSink) -> LitResult {
        self.not_running()?;
        if req.leds.len() > MAX_LEDS_PER_LIST {
            return Err(DeviceError::TooMany {
                requested: req.leds.len() as u32,
                max: MAX_LEDS_PER_LIST as u32,
            });
        }
        let g = self.board.geometry;
        for &led in &req.leds {
            chain_index(&g, led).ok_or(bad_led(led))?;
        }
        let staged = self.leds.stage(req.keep_others);
        for &led in &req.leds {
            if let Some(px) = chain_index(&g, led).and_then(|i| staged.get_mut(i as usize)) {
                *px = req.color;
            }
        }
        self.commit(self.leds.brightness(), self.budget, now)
    }

    fn clear(&mut self, _: (), now: u64, _: &mut impl FrameSink) -> LitResult {
        self.not_running()?;
        self.leds.stage(false);
        self.commit(self.leds.brightness(), self.budget, now)
    }

    fn pattern(&mut self, req: PatternRequest, now: u64, _: &mut impl FrameSink) -> LitResult {
        self.not_running()?;
        render(
            &self.board,
            &mut self.leds,
            Illumination::Pattern(req.pattern),
            req.color,
        )?;
        self.commit(self.leds.brightness(), self.budget, now)
    }

    fn brightness(&mut self, level: u8, now: u64, _: &mut impl FrameSink) -> LitResult {
        self.not_running()?;
        self.leds.stage(true);
        self.commit(level, self.budget, now)
    }

    /// Gamma correction on or off (`None`: only ask). What is lit is shown again
    /// through the new setting, within the budget as for any change.
    fn gamma(&mut self, on: Option<bool>, now: u64, _: &mut impl FrameSink) -> GammaResult {
        let Some(on) = on else {
            return Ok(self.leds.output().gamma);
        };
        self.not_running()?;
        self.leds.stage(true);
        let output = Output {
            gamma: on,
            ..self.leds.output()
        };
        self.commit_output(output, self.budget, now)?;
        Ok(on)
    }

    /// A new budget takes effect at once: what is lit is dimmed to fit if needed.
    fn set_budget(&mut self, req: BudgetConfig, now: u64, _: &mut impl FrameSink) -> BudgetResult {
        self.not_running()?;
        if req.limit_ma == 0 {
            return Err(DeviceError::BadParam(Param::Budget));
        }
        if req.limit_ma > self.board.max_current_ma {
            return Err(DeviceError::TooMany {
                requested: req.limit_ma,
                max: self.board.max_current_ma,
            });
        }
        self.leds.stage(true);
        let fit = BudgetConfig {
            limit_ma: req.limit_ma,
            policy: BudgetPolicy::Scale,
        };
        self.commit(self.leds.brightness(), fit, now)?;
        self.budget = req;
        Ok(req)
    }

    fn seq_define(&mut self, req: SequenceDefine, _: u64, _: &mut impl FrameSink) -> StatusResult {
        let status = self.engine.define(&req)?;
        self.set_trigger(false);
        Ok(status)
    }

    fn seq_steps(&mut self, req: StepChunk, _: u64, _: &mut impl FrameSink) -> StepsResult {
        let mut steps: heapless::Vec<Stored, { limits::MAX_STEPS_PER_CHUNK }> =
            heapless::Vec::new();
        for &s in &req.steps {
            // As many as the chunk holds: room for each.
            let _ = steps.push(Stored::Step(s));
        }
        self.load_steps(req.id, req.offset, &steps)
    }

    fn seq_set_steps(&mut self, req: SetStepChunk, _: u64, _: &mut impl FrameSink) -> StepsResult {
        let mut steps: heapless::Vec<Stored, { limits::MAX_STEPS_PER_CHUNK }> =
            heapless::Vec::new();
        for &s in &req.steps {
            let _ = steps.push(Stored::Set(s));
        }
        self.load_steps(req.id, req.offset, &steps)
    }

    fn load_steps(&mut self, id: u32, offset: u16, steps: &[Stored]) -> StepsResult {
        let (board, leds, budget, sets) = (&self.board, &mut self.leds, self.budget, &self.sets);
        self.engine.load(id, offset, steps, |i, step| {
            check_step(board, sets, leds, budget, i, step)
        })
    }

    fn define_set(&mut self, req: LedSetDefine, _: u64, _: &mut impl FrameSink) -> LedSetsResult {
        // A running sequence may be lighting these sets.
        self.not_running()?;
        self.sets.define(&req, &self.board.geometry)
    }

    fn seq_start(&mut self, id: u32, now: u64, out: &mut impl FrameSink) -> StartResult {
        if self.engine.is_running() {
            return Err(DeviceError::Busy);
        }
        // Brightness or budget may have changed since the upload: check again.
        for (i, step) in self.engine.steps().iter().enumerate() {
            check_step(
                &self.board,
                &self.sets,
                &mut self.leds,
                self.budget,
                i as u16,
                step,
            )?;
        }
        self.engine.start(id, now)?;
        self.awaiting_latch = None;
        let status = self.engine.status();
        let started = SequenceStarted {
            id,
            steps: status.total,
            started_us: now,
            min_duration_us: self.engine.min_duration_us(),
        };
        self.poll(now, out);
        Ok(started)
    }

    fn seq_abort(&mut self, _: (), now: u64, out: &mut impl FrameSink) -> StatusResult {
        let end = self
            .engine
            .stop(SequenceOutcome::Aborted, now)
            .ok_or(DeviceError::NotRunning)?;
        self.finish(end, now, out);
        Ok(self.engine.status())
    }

    /// Every LED off, then the restart in BOOTSEL is left to the shell. Not while a
    /// sequence runs (the host aborts it first): a board does not go dark mid-capture
    /// on a stray request.
    fn bootsel(&mut self, _: (), now: u64, _: &mut impl FrameSink) -> BootselResult {
        self.not_running()?;
        self.leds.stage(false);
        self.commit(self.leds.brightness(), self.budget, now)?;
        self.bootsel = true;
        Ok(())
    }

    fn seq_status(&mut self, _: (), _: u64, _: &mut impl FrameSink) -> SequenceStatus {
        self.engine.status()
    }

    // ---------------------------------------------------------------- helpers

    fn not_running(&self) -> Result<(), DeviceError> {
        if self.engine.is_running() {
            Err(DeviceError::Busy)
        } else {
            Ok(())
        }
    }

    fn commit(&mut self, brightness: u8, budget: BudgetConfig, now: u64) -> LitResult {
        let output = self.leds.output().at(brightness);
        self.commit_output(output, budget, now)
    }

    fn commit_output(&mut self, output: Output, budget: BudgetConfig, now: u64) -> LitResult {
        self.leds
            .commit(&self.board, output, budget, &mut self.strip, now)
    }

    fn light_step(&mut self, step: u16, now: u64) -> LitResult {
        let s = self
            .engine
            .steps()
            .get(step as usize)
            .copied()
            .ok_or(DeviceError::Incomplete {
                loaded: step,
                total: step,
            })?;
        render_stored(&self.board, &self.sets, &mut self.leds, &s)?;
        let refuse = BudgetConfig {
            policy: BudgetPolicy::Refuse,
            ..self.budget
        };
        self.commit(self.leds.brightness(), refuse, now)
            .map_err(|e| match e {
                DeviceError::OverBudget {
                    required_ma,
                    limit_ma,
                    ..
                } => DeviceError::OverBudget {
                    required_ma,
                    limit_ma,
                    step: Some(step),
                },
                other => other,
            })
    }

    /// Polarity of the trigger output under the defined sequence (active-high when
    /// none is defined). An emulated camera is configured from it, as a user would
    /// configure a real one.
    pub fn trigger_polarity(&self) -> Polarity {
        self.engine
            .timing()
            .and_then(|t| t.trigger_out)
            .map(|t| t.polarity)
            .unwrap_or(Polarity::ActiveHigh)
    }

    fn set_trigger(&mut self, active: bool) {
        let high = match self.trigger_polarity() {
            Polarity::ActiveHigh => active,
            Polarity::ActiveLow => !active,
        };
        self.trigger.set_level(high);
    }

    fn finish(&mut self, end: SequenceEnd, now: u64, out: &mut impl FrameSink) {
        self.set_trigger(false);
        if self.engine.timing().is_some_and(|t| t.clear_at_end) {
            self.leds.stage(false);
            // Turning LEDs off always fits any budget.
            let _ = self.commit(self.leds.brightness(), self.budget, now);
        }
        self.publish::<SequenceEndTopic>(&end, out);
    }
}

fn bad_led(led: LedIndex) -> DeviceError {
    DeviceError::BadLed {
        row: led.row,
        col: led.col,
    }
}

/// Write header and postcard body into `buf`; returns the bytes used.
fn encode_message<M: Serialize + ?Sized>(
    hdr: &VarHeader,
    msg: &M,
    buf: &mut [u8],
) -> Option<usize> {
    let (h, rest) = hdr.write_to_slice(buf)?;
    let hlen = h.len();
    let body = postcard::to_slice(msg, rest).ok()?.len();
    Some(hlen + body)
}

/// Stage what `illumination` lights in `color`, everything else off.
fn render(
    board: &BoardConfig,
    leds: &mut LedState,
    illumination: Illumination,
    color: Rgb,
) -> Result<(), DeviceError> {
    let g = &board.geometry;
    if let Illumination::Pattern(p) = &illumination {
        patterns::validate(p)?;
    }
    if let Illumination::Led(led) = illumination {
        chain_index(g, led).ok_or(bad_led(led))?;
    }
    let staged = leds.stage(false);
    match illumination {
        Illumination::Dark => {}
        Illumination::Led(led) => {
            if let Some(px) = chain_index(g, led).and_then(|i| staged.get_mut(i as usize)) {
                *px = color;
            }
        }
        Illumination::Pattern(p) => {
            for (i, px) in staged.iter_mut().enumerate() {
                if led_at(g, i as u16).is_some_and(|led| patterns::contains(g, &p, led)) {
                    *px = color;
                }
            }
        }
    }
    Ok(())
}

/// Stage what a loaded step lights, everything else off: its illumination, or its
/// set of the table (which must be defined).
fn render_stored(
    board: &BoardConfig,
    sets: &LedSets,
    leds: &mut LedState,
    step: &Stored,
) -> Result<(), DeviceError> {
    match step {
        Stored::Step(s) => render(board, leds, s.illumination, s.color),
        Stored::Set(s) => {
            let members = sets.get(s.set).ok_or(sets.missing(s.set))?;
            let g = &board.geometry;
            let staged = leds.stage(false);
            for &led in members {
                if let Some(px) = chain_index(g, led).and_then(|i| staged.get_mut(i as usize)) {
                    *px = s.color;
                }
            }
            Ok(())
        }
    }
}

/// A sequence step must name LEDs on the board (a set, one defined) and fit the budget
/// at the current brightness (sequences never scale, so every frame sees the same
/// light per LED).
fn check_step(
    board: &BoardConfig,
    sets: &LedSets,
    leds: &mut LedState,
    budget: BudgetConfig,
    index: u16,
    step: &Stored,
) -> Result<(), DeviceError> {
    render_stored(board, sets, leds, step)?;
    let need = leds.staged_current_ua(leds.output(), board.channel_current_ua);
    if need > budget.limit_ma as u64 * 1000 {
        return Err(DeviceError::OverBudget {
            required_ma: crate::budget::ua_to_ma(need),
            limit_ma: budget.limit_ma,
            step: Some(index),
        });
    }
    Ok(())
}
