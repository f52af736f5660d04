// The real fpm LED controller firmware in an emulated RP2040 (rp2040js).
//
// Loads the UF2 image users drag onto their Pico into the emulated flash, boots it with
// the RP2040's B1 boot ROM, and bridges the firmware's USB CDC-ACM port to this
// process's stdin (host → device) and stdout (device → host), byte for byte.
// `fpm emulator --firmware FILE.uf2` runs this and puts a pseudo-terminal in front, so
// the unchanged host client talks to it like to a board.
//
// Pins, as on the board (firmware/rp2040/src/board.rs): GP14 camera trigger out, GP15
// camera trigger in (an emulated camera answers every active trigger edge with an
// exposure pulse), GP16–GP19 WS2812 data, lanes 0–3 (decoded). Log lines go to stderr, and so do the
// pin events, one JSON line each after `event `, stamped in emulated µs.
//
// The flash chip is modelled behind the SSI (flash.mjs): the firmware can program it,
// and with --flash-image the whole 2 MiB chip is kept in a file between runs, as on a
// board (loading a UF2 then rewrites only the sectors it covers, as the boot ROM's UF2
// loader does). --uid gives the chip's unique id (the board's serial number);
// --power-cut-after N stops the chip, saves the image and exits (code 3) after N erased
// or programmed bytes.
//
// Usage: node harness.mjs --uf2 FILE --bootrom FILE [--camera-latency-us N]
//        [--camera-exposure-us N] [--no-camera] [--flash-image FILE] [--uid HEX16]
//        [--power-cut-after N]

import fs from 'node:fs';
import { BasePeripheral, RP2040, USBCDC, GPIOPinState, getDescriptorPacket, createSetupPacket } from 'rp2040js';
import { FlashSsi, QspiIo, SpiNorFlash } from './flash.mjs';

const FLASH_START = 0x10000000;
const UF2_MAGIC = [0x0a324655, 0x9e5d5157];
const UF2_END_MAGIC = 0x0ab16f30;
const UF2_FLAG_NOT_MAIN_FLASH = 0x1;
const RP2040_FAMILY = 0xe48bff56;
const TRIGGER_OUT = 14;
const TRIGGER_IN = 15;
const CPU_HZ = 125e6;
// The Pico's W25Q16JV.
const FLASH_BYTES = 2 * 1024 * 1024;
const SECTOR = 4096;

function args(argv) {
  const out = { cameraLatencyUs: 20, cameraExposureUs: 2000, camera: true, uid: 'e6605481db2b8e2a' };
  for (let i = 0; i < argv.length; i++) {
    const a = argv[i];
    const next = () => {
      if (i + 1 >= argv.length) fail(`${a} needs a value`);
      return argv[++i];
    };
    if (a === '--uf2') out.uf2 = next();
    else if (a === '--bootrom') out.bootrom = next();
    else if (a === '--camera-latency-us') out.cameraLatencyUs = Number(next());
    else if (a === '--camera-exposure-us') out.cameraExposureUs = Number(next());
    else if (a === '--no-camera') out.camera = false;
    else if (a === '--flash-image') out.flashImage = next();
    else if (a === '--uid') out.uid = next();
    else if (a === '--power-cut-after') out.powerCutAfter = Number(next());
    else if (a === '--real-time') out.realTime = true;
    else fail(`unknown argument ${a}`);
  }
  if (!out.uf2 || !out.bootrom) fail('--uf2 FILE and --bootrom FILE are required');
  if (!/^[0-9a-fA-F]{16}$/.test(out.uid)) fail(`--uid ${out.uid}: 16 hex digits expected`);
  if (out.powerCutAfter !== undefined && !(out.powerCutAfter >= 0)) fail('--power-cut-after needs a byte count');
  return out;
}

function fail(message) {
  process.stderr.write(`rp2040 harness: ${message}\n`);
  process.exit(2);
}

// UF2: 512-byte blocks, each with 256 (or up to 476) payload bytes for a flash address.
// Each 4 KiB sector a block lands in is erased first, as the boot ROM's UF2 loader
// does; sectors the image does not cover keep what they held.
function loadUf2(path, flash) {
  const erased = new Set();
  const data = fs.readFileSync(path);
  if (data.length === 0 || data.length % 512 !== 0) {
    fail(`${path}: ${data.length} bytes is not a whole number of 512-byte UF2 blocks`);
  }
  let blocks = 0;
  for (let offset = 0; offset < data.length; offset += 512) {
    const word = (k) => data.readUInt32LE(offset + 4 * k);
    if (word(0) !== UF2_MAGIC[0] || word(1) !== UF2_MAGIC[1] || data.readUInt32LE(offset + 508) !== UF2_END_MAGIC) {
      fail(`${path}: block ${offset / 512} has no UF2 magic`);
    }
    const flags = word(2);
    const address = word(3);
    const size = word(4);
    if (flags & UF2_FLAG_NOT_MAIN_FLASH) continue;
    if ((flags & 0x2000) && word(7) !== RP2040_FAMILY) {
      fail(`${path}: block ${offset / 512} is for family 0x${word(7).toString(16)}, not the RP2040`);
    }
    if (size > 476 || address < FLASH_START || address + size > FLASH_START + flash.length) {
      fail(`${path}: block ${offset / 512} writes ${size} bytes at 0x${address.toString(16)}, outside the flash`);
    }
    for (let s = Math.floor((address - FLASH_START) / SECTOR); s * SECTOR < address - FLASH_START + size; s++) {
      if (!erased.has(s)) {
        flash.fill(0xff, s * SECTOR, (s + 1) * SECTOR);
        erased.add(s);
      }
    }
    flash.set(data.subarray(offset + 32, offset + 32 + size), address - FLASH_START);
    blocks++;
  }
  return blocks;
}

// The XIP stream control block: embassy-rp waits for STREAM_CTR to read 0 before
// touching flash from RAM; rp2040js maps nothing there.
class XipControl extends BasePeripheral {
  readUint32() {
    return 0;
  }
}

const opt = args(process.argv.slice(2));
const mcu = new RP2040();
// rp2040js logs on stdout by default, which is the serial stream here: errors only, to
// stderr.
const quiet = (level) => (component, message) => {
  if (level === 'error') process.stderr.write(`rp2040 harness: [${component}] ${message}\n`);
};
mcu.logger = { debug: quiet('debug'), info: quiet('info'), warn: quiet('warn'), error: quiet('error') };
const bootrom = fs.readFileSync(opt.bootrom);
if (bootrom.length !== 16 * 1024) fail(`${opt.bootrom}: a B1 boot ROM is 16384 bytes, not ${bootrom.length}`);
mcu.loadBootrom(new Uint32Array(bootrom.buffer, bootrom.byteOffset, bootrom.length / 4));
if (opt.flashImage && fs.existsSync(opt.flashImage)) {
  const image = fs.readFileSync(opt.flashImage);
  if (image.length !== FLASH_BYTES) fail(`${opt.flashImage}: a flash image of ${image.length} bytes, expected ${FLASH_BYTES} (the Pico's 2 MiB chip)`);
  mcu.flash.set(image);
}
const blocks = loadUf2(opt.uf2, mcu.flash);
mcu.peripherals[0x14000] = new XipControl(mcu, 'XIP_CTRL');
function saveFlash() {
  if (!opt.flashImage) return;
  const tmp = `${opt.flashImage}.tmp`;
  fs.writeFileSync(tmp, mcu.flash.subarray(0, FLASH_BYTES));
  fs.renameSync(tmp, opt.flashImage);
}
const chip = new SpiNorFlash(mcu.flash, {
  size: FLASH_BYTES,
  uid: Buffer.from(opt.uid, 'hex'),
  onChange: () => {
    saveFlash();
    emit({ type: 'flash', us: Number(mcu.clock.micros.toFixed(3)) });
  },
  powerCutAfter: opt.powerCutAfter,
  onPowerCut: () => {
    saveFlash();
    emit({ type: 'power-cut', us: Number(mcu.clock.micros.toFixed(3)) });
    log('power cut during a flash write (--power-cut-after)');
    process.exit(3);
  },
});
const ssi = new FlashSsi(mcu, chip);
mcu.peripherals[0x18000] = ssi;
mcu.peripherals[0x40018] = new QspiIo(mcu, ssi);
// boot2 sits at the start of flash; starting there is what the boot ROM does after
// checking it (the ROM's own flash probing is not emulated).
mcu.core.PC = FLASH_START;

const log = (message) => process.stderr.write(`rp2040 harness: ${message}\n`);
log(`${blocks} UF2 blocks loaded from ${opt.uf2}`);

// The restart in BOOTSEL (`fpm/device/bootsel`): the firmware calls the boot ROM's
// reset_usb_boot, which leaves the ROM's reboot magic (0xb007c0d3) in the watchdog's
// scratch register 4, the ROM address to restart at in scratch 7 (its USB boot), and
// fires the watchdog. A board resets there and comes back as the RP2040's boot device;
// this chip cannot (the ROM's own boot path is not emulated), so the harness reports
// the hand-over to the ROM, with the registers as the ROM left them, and stops as a
// board leaves its serial port.
const WATCHDOG_REBOOT_MAGIC = 0xb007c0d3;
const watchdog = mcu.peripherals[0x40058];
let rebooting = false;
watchdog.onWatchdogTrigger = () => {
  const scratch = Array.from(watchdog.scratchData, (v) => v >>> 0);
  if (rebooting) return;
  if (scratch[4] !== WATCHDOG_REBOOT_MAGIC) {
    log(`watchdog reset at ${mcu.clock.micros.toFixed(0)} µs (not emulated; the firmware goes on)`);
    return;
  }
  rebooting = true;
  emit({
    type: 'bootsel',
    us: Number(mcu.clock.micros.toFixed(3)),
    rom_entry: scratch[7],
    scratch,
  });
  log(`the firmware handed over to the boot ROM's reboot (watchdog scratch 4 = 0x${scratch[4].toString(16)}, restart at 0x${scratch[7].toString(16)} in the ROM): a board restarts in BOOTSEL here; stopping`);
  saveFlash();
  process.exit(0);
};

// USB CDC-ACM ↔ stdin/stdout. Like a real host, we leave the firmware's OUT endpoint
// armed until there are bytes to send. rp2040js clears a buffer's AVAILABLE bit the
// moment the firmware arms it, which embassy-rp reads as "a packet arrived"; its own
// CDC model therefore answers every armed read at once, with zero bytes when it has
// none, and that flood kept the firmware's main loop permanently busy (it starved the
// trigger-in task: found by the conformance suite).
const EP0_OUT_BUFFER_CONTROL = 0x84;
const BUFFER_AVAILABLE = 1 << 10;
const cdc = new USBCDC(mcu.usbCtrl);
let connected = false;
const toDevice = [];
let armedRead = 0;
function setOutAvailable(endpoint, available) {
  const reg = EP0_OUT_BUFFER_CONTROL + endpoint * 8;
  const view = mcu.usbDPRAMView;
  const value = view.getUint32(reg, true);
  view.setUint32(reg, available ? value | BUFFER_AVAILABLE : value & ~BUFFER_AVAILABLE, true);
}
function serveRead() {
  const size = armedRead;
  armedRead = 0;
  const buffer = Uint8Array.from(toDevice.splice(0, Math.min(size, toDevice.length)));
  if (process.env.FPM_HARNESS_DEBUG) log(`OUT ${buffer.length} byte(s) at ${mcu.clock.micros.toFixed(1)} µs, ${toDevice.length} waiting`);
  // Received, in one step as the firmware sees it: no longer available, full, with
  // its length.
  setOutAvailable(cdc.outEndpoint, false);
  if (buffer.includes(0)) requestEndUs = mcu.clock.micros;
  mcu.usbCtrl.finishRead(cdc.outEndpoint, buffer);
}
mcu.usbCtrl.onEndpointRead = (endpoint, size) => {
  if (endpoint !== cdc.outEndpoint) return;
  armedRead = size;
  if (connected && toDevice.length > 0) {
    serveRead();
  } else {
    setOutAvailable(endpoint, true);
  }
};
function flushToDevice() {
  if (connected && armedRead > 0 && toDevice.length > 0) serveRead();
}
cdc.onDeviceConnected = () => {
  connected = true;
  log(`USB CDC-ACM enumerated at ${(mcu.clock.micros / 1e3).toFixed(1)} ms (emulated)`);
  flushToDevice();
  readIdentity();
};

// The device's USB identity, read as a host reads it after enumeration: the device
// descriptor (VID:PID) and its strings, reported as `event {"type":"usb",...}`.
const USB_DESCRIPTOR_DEVICE = 1;
const USB_DESCRIPTOR_STRING = 3;
const LANGUAGE_EN_US = 0x0409;
let controlIn = null;
const cdcEndpointWrite = mcu.usbCtrl.onEndpointWrite;
mcu.usbCtrl.onEndpointWrite = (endpoint, buffer) => {
  if (endpoint === 0 && controlIn && buffer.length > 0) {
    const take = controlIn;
    controlIn = null;
    take(buffer);
    return;
  }
  cdcEndpointWrite(endpoint, buffer);
};
function controlRead(setup) {
  return new Promise((resolve, reject) => {
    const timer = setTimeout(() => reject(new Error('no answer on endpoint 0')), 5000);
    controlIn = (buffer) => {
      clearTimeout(timer);
      resolve(Uint8Array.from(buffer));
    };
    mcu.usbCtrl.sendSetupPacket(setup);
  });
}
function stringPacket(index) {
  return createSetupPacket({
    dataDirection: 1,
    type: 0,
    recipient: 0,
    bRequest: 6,
    wValue: (USB_DESCRIPTOR_STRING << 8) | index,
    wIndex: LANGUAGE_EN_US,
    wLength: 255,
  });
}
async function readString(index) {
  if (!index) return null;
  const d = await controlRead(stringPacket(index));
  let text = '';
  for (let i = 2; i + 1 < Math.min(d[0], d.length); i += 2) text += String.fromCharCode(d[i] | (d[i + 1] << 8));
  return text;
}
async function readIdentity() {
  try {
    const device = await controlRead(getDescriptorPacket(USB_DESCRIPTOR_DEVICE, 18));
    const word = (k) => device[k] | (device[k + 1] << 8);
    emit({
      type: 'usb',
      vid: word(8),
      pid: word(10),
      manufacturer: await readString(device[14]),
      product: await readString(device[15]),
      serial: await readString(device[16]),
    });
  } catch (e) {
    log(`could not read the USB identity: ${e.message}`);
  }
}
// Request round trips in emulated time: from the USB packet that ends a request frame
// (its zero delimiter) reaching the firmware to the first bytes it sends back, reported
// as `event {"type":"round-trip","us":...}`.
let requestEndUs = null;
cdc.onSerialData = (buffer) => {
  if (requestEndUs !== null) {
    emit({ type: 'round-trip', us: Number((mcu.clock.micros - requestEndUs).toFixed(3)) });
    requestEndUs = null;
  }
  process.stdout.write(Buffer.from(buffer));
};
process.stdin.on('data', (chunk) => {
  for (const b of chunk) toDevice.push(b);
  flushToDevice();
});
process.stdin.on('end', () => {
  log('host side closed; stopping');
  process.exit(0);
});

// Trigger lines and the emulated camera (active-high trigger, active-high exposure).
const triggerIn = mcu.gpio[TRIGGER_IN];
triggerIn.setInputValue(false);
let lastTrigger = false;
mcu.gpio[TRIGGER_OUT].addListener((state) => {
  const high = state === GPIOPinState.High;
  if (high === lastTrigger) return;
  lastTrigger = high;
  const us = mcu.clock.micros;
  if (process.env.FPM_HARNESS_DEBUG) log(`GP${TRIGGER_OUT} ${high ? 'high' : 'low'} at ${us.toFixed(1)} µs`);
  emit({ type: 'trigger', level: high ? 1 : 0, us: Number(us.toFixed(3)) });
  if (high && opt.camera) {
    const start = mcu.clock.createAlarm(() => {
      triggerIn.setInputValue(true);
      if (process.env.FPM_HARNESS_DEBUG) log(`GP${TRIGGER_IN} high at ${mcu.clock.micros.toFixed(1)} µs`);
      const end = mcu.clock.createAlarm(() => {
        triggerIn.setInputValue(false);
        if (process.env.FPM_HARNESS_DEBUG) log(`GP${TRIGGER_IN} low at ${mcu.clock.micros.toFixed(1)} µs`);
      });
      end.schedule(opt.cameraExposureUs * 1e3);
    });
    start.schedule(opt.cameraLatencyUs * 1e3);
  }
});

// The WS2812 chain, decoded at the pins (GP16–GP19, lanes 0–3: one PIO state machine
// each). rp2040js runs a state machine's next instruction at once, counting the
// instruction's delay cycles but not waiting them out, on its own wall-clock timer. Here each state machine is stepped cycle by
// cycle in emulated time instead: one PIO cycle every clk_sys / CLKDIV system cycles
// (the firmware's own divider), an instruction only once the delay cycles of the one
// before have passed (rp2040js's `cycles` counter), so pulse widths at the pin are the
// program's. Edges are stamped with the PIO cycle they happen in.
//
// Decoding follows the WS2812B datasheet: a high pulse of 0.25–0.55 µs is a 0 (T0H
// 0.4 µs ± 150 ns), of 0.65–0.95 µs a 1 (T1H 0.8 µs ± 150 ns), anything else is a bad
// pulse; 24 bits make a word, G then R then B. Each lane is decoded on its own; the
// lanes are shifted together, so a frame ends when every lane has been low for
// LATCH_US (280 µs), and is reported on stderr as one `event {"type":"latched",...}`
// with, per lane driven (the pins of the enabled state machines' side-set, in order):
// the words and the timing measured at that pin — first rise to last fall, the
// shortest and longest T0H, T1H and bit period, the longest low inside the frame, and
// the gap since that lane's previous frame.
const LANE_PINS = [16, 17, 18, 19];
const LATCH_US = 280;
const T0H_NS = [250, 550];
const T1H_NS = [650, 950];
const pio0 = mcu.pio[0];
pio0.run = () => {}; // stepped below, not on its own timer
// Per machine: the system cycle of its next PIO cycle, and that PIO cycle's number.
const smNext = [0, 0, 0, 0];
const smTick = [0, 0, 0, 0];
let pinTimeUs = 0;
// Called after every CPU instruction: does nothing until a PIO cycle is due.
let pioDueAt = 0;
// While idle, how often to look for new data in the FIFOs (system cycles, 0.5 µs).
const IDLE_RECHECK_CYCLES = 64;
// While the CPU sleeps beside a running PIO, the clock advances in slices this long.
const PIO_SLICE_CYCLES = 2000;
function clockDivider(m) {
  return (m.clockDivInt || 65536) + m.clockDivFrac / 256;
}
function stepPio() {
  if (pio0.stopped) return;
  const now = mcu.clock.nanos / cycleNanos;
  if (now < pioDueAt) return;
  if (pioIdle()) {
    // Stalled on an empty FIFO (no frame open): nothing to step until the CPU or DMA
    // writes again.
    for (let k = 0; k < 4; k++) {
      smNext[k] = now;
      pio0.machines[k].cycles = smTick[k];
    }
    pioDueAt = now + IDLE_RECHECK_CYCLES;
    return;
  }
  for (let k = 0; k < 4; k++) {
    const m = pio0.machines[k];
    if (!m.enabled) {
      smNext[k] = now;
      continue;
    }
    const div = clockDivider(m);
    while (smNext[k] <= now) {
      if (m.cycles <= smTick[k]) {
        pinTimeUs = (smNext[k] * cycleNanos) / 1e3;
        m.step();
        // A stall takes this cycle; the instruction runs when it clears.
        if (m.waiting) m.cycles = smTick[k] + 1;
        pio0.checkChangedPins();
      }
      smTick[k]++;
      smNext[k] += div;
    }
  }
  // The earliest next PIO cycle (runs after every few CPU instructions: no allocation).
  pioDueAt = Infinity;
  for (let k = 0; k < 4; k++) {
    if (pio0.machines[k].enabled && smNext[k] < pioDueAt) pioDueAt = smNext[k];
  }
  if (frameOpen && latchedOnEveryLane()) {
    closeFrame();
    pioDueAt = now;
  }
  // An open frame must be closed on time even if no machine runs.
  if (frameOpen) pioDueAt = Math.min(pioDueAt, now + IDLE_RECHECK_CYCLES);
}
// Every running state machine stalled on an empty TX FIFO: nothing changes at the pins
// until the CPU (or DMA) writes again, so sleep can be skipped in one go.
const FDEBUG_TXSTALL = 1 << 24;
function pioIdle() {
  // A frame being shifted out may find the FIFO empty between DMA bursts, and a DMA
  // channel waits for the PIO's DREQ, which only a stepped PIO raises: not idle.
  if (frameOpen || mcu.dma.channels.some((c) => c.active)) return false;
  return pio0.machines.every(
    (m) => !m.enabled || (m.txFIFO.empty && (pio0.txStall & (FDEBUG_TXSTALL << m.index)) !== 0),
  );
}
// One data line's decoder.
class LaneDecoder {
  constructor(pin) {
    this.pin = pin;
    this.high = false;
    this.riseUs = 0;
    this.fallUs = -Infinity;
    this.lastFrameEndUs = null;
    this.clear();
  }
  clear() {
    this.bits = 0;
    this.word = 0;
    this.words = [];
    this.bad = 0;
    this.startUs = null;
    this.timing = newTiming();
  }
  edge(high, at) {
    if (high === this.high) return;
    this.high = high;
    if (high) {
      if (this.startUs === null) {
        this.startUs = at;
        this.timing.gapUs = this.lastFrameEndUs === null ? null : at - this.lastFrameEndUs;
        frameOpen = true;
      } else {
        widen(this.timing.period, (at - this.riseUs) * 1e3);
        this.timing.lowMax = Math.max(this.timing.lowMax, (at - this.fallUs) * 1e3);
      }
      this.riseUs = at;
      return;
    }
    this.fallUs = at;
    const width = (at - this.riseUs) * 1e3;
    let bit;
    if (width >= T0H_NS[0] && width <= T0H_NS[1]) {
      bit = 0;
      widen(this.timing.t0h, width);
    } else if (width >= T1H_NS[0] && width <= T1H_NS[1]) {
      bit = 1;
      widen(this.timing.t1h, width);
    } else {
      this.bad++;
      bit = width > (T0H_NS[1] + T1H_NS[0]) / 2 ? 1 : 0;
      widen(bit ? this.timing.t1h : this.timing.t0h, width);
    }
    this.word = ((this.word << 1) | bit) >>> 0;
    this.bits++;
    if (this.bits === 24) {
      this.words.push(this.word);
      this.word = 0;
      this.bits = 0;
    }
  }
  // This lane's part of a latched frame (no words if it was not shifted).
  report() {
    const shifted = this.startUs !== null;
    if (this.bits !== 0) this.bad++;
    const out = {
      pin: this.pin,
      words: this.words,
      bad: this.bad,
      shift_us: shifted ? Number((this.fallUs - this.startUs).toFixed(3)) : 0,
      t0h_ns: ns(this.timing.t0h),
      t1h_ns: ns(this.timing.t1h),
      period_ns: ns(this.timing.period),
      low_max_ns: Math.round(this.timing.lowMax),
      gap_us: shifted && this.timing.gapUs !== null ? Number(this.timing.gapUs.toFixed(3)) : null,
    };
    if (shifted) this.lastFrameEndUs = this.fallUs;
    this.clear();
    return out;
  }
}
const decoders = new Map(LANE_PINS.map((pin) => [pin, new LaneDecoder(pin)]));
let frameOpen = false;
function newTiming() {
  return { t0h: [Infinity, -Infinity], t1h: [Infinity, -Infinity], period: [Infinity, -Infinity], lowMax: 0, gapUs: null };
}
function widen(range, x) {
  range[0] = Math.min(range[0], x);
  range[1] = Math.max(range[1], x);
}
const ns = (range) => (Number.isFinite(range[0]) ? [Math.round(range[0]), Math.round(range[1])] : null);
function emit(event) {
  process.stderr.write(`event ${JSON.stringify(event)}\n`);
}
// Every lane low for the latch time since its last fall.
function latchedOnEveryLane() {
  const now = mcu.clock.micros;
  for (const d of decoders.values()) {
    if (d.high || now - d.fallUs < LATCH_US) return false;
  }
  return true;
}
// The pins the enabled state machines drive (their side-set base), in lane order.
function drivenPins() {
  const pins = pio0.machines.filter((m) => m.enabled).map((m) => m.sidesetBase);
  return [...new Set(pins)].filter((pin) => decoders.has(pin)).sort((a, b) => a - b);
}
function closeFrame() {
  const pins = drivenPins();
  for (const [pin, d] of decoders) {
    // A pin no state machine drives that still toggled: report it too, it is wrong.
    if (d.startUs !== null && !pins.includes(pin)) pins.push(pin);
  }
  emit({
    type: 'latched',
    us: Number(mcu.clock.micros.toFixed(3)),
    lanes: pins.map((pin) => decoders.get(pin).report()),
  });
  frameOpen = false;
}
for (const [pin, d] of decoders) {
  mcu.gpio[pin].addListener((state) => d.edge(state === GPIOPinState.High, pinTimeUs));
}

// Run: emulated time advances with the instructions executed (and jumps to the next
// alarm while the core sleeps); yield to the event loop often so USB bytes flow.
const cycleNanos = 1e9 / CPU_HZ;
const MAX_SLEEP_NS = 1e6;
let wallStart = Date.now();
let lastReport = 0;
// --real-time: emulated time may not run ahead of the wall clock since the first turn
// (a sleep is cut where the wall clock is, and the loop waits a millisecond for it);
// behind it, the emulator runs flat out as without the flag.
let paceFrom = null;
function run() {
  const clock = mcu.clock;
  if (opt.realTime && paceFrom === null) paceFrom = { wallMs: performance.now(), nanos: clock.nanos };
  const wallNanos = () => paceFrom.nanos + (performance.now() - paceFrom.wallMs) * 1e6;
  for (let i = 0; i < 200000; i++) {
    if (opt.realTime && mcu.core.waiting && clock.nanos >= wallNanos()) {
      setTimeout(run, 1);
      return;
    }
    if (mcu.core.waiting) {
      // Asleep until the next alarm; the PIO keeps running meanwhile. At most
      // MAX_SLEEP_NS at a time: with no alarm armed (the firmware waiting for USB)
      // rp2040js reports the timer's wrap-around, and jumping there would put the
      // device clock years ahead and cost the µs timestamps their precision.
      let skip = Math.min(Math.max(clock.nanosToNextAlarm, cycleNanos), MAX_SLEEP_NS);
      if (opt.realTime) skip = Math.max(Math.min(skip, wallNanos() - clock.nanos), cycleNanos);
      const cycles = skip / cycleNanos;
      if (!pio0.stopped && cycles > PIO_SLICE_CYCLES && !pioIdle()) {
        // Step through the sleep in slices, so the PIO's pin changes land in time; at
        // most 2 ms of it per turn, so a long sleep beside a busy PIO cannot hog the loop.
        const slice = PIO_SLICE_CYCLES * cycleNanos;
        let left = Math.min(skip, 2e6);
        while (left > 0 && mcu.core.waiting) {
          const dt = Math.min(slice, left);
          clock.tick(dt);
          stepPio();
          left -= dt;
        }
      } else {
        clock.tick(skip);
        stepPio();
      }
      i += cycles;
    } else {
      const cycles = mcu.core.executeInstruction();
      clock.tick(cycles * cycleNanos);
      stepPio();
    }
  }
  const emulatedS = clock.nanos / 1e9;
  if (emulatedS - lastReport >= (process.env.FPM_HARNESS_DEBUG ? 1 : 10)) {
    lastReport = emulatedS;
    log(`${emulatedS.toFixed(0)} s emulated, ${(emulatedS / ((Date.now() - wallStart) / 1e3)).toFixed(2)} emulated s per wall s`);
  }
  setImmediate(run);
}
if (process.env.FPM_HARNESS_DEBUG) {
  setInterval(() => log(`watch: ${mcu.clock.micros.toFixed(0)} µs, waiting ${mcu.core.waiting}, PC 0x${(mcu.core.PC >>> 0).toString(16)}, pio idle ${pioIdle()}, next alarm ${mcu.clock.nanosToNextAlarm} ns`), 2000);
}
run();
