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
// exposure pulse), GP16.. WS2812 data. Log lines go to stderr; with --events, one JSON
// line per trigger-out edge goes to file descriptor 3, stamped in emulated µs.
//
// Usage: node harness.mjs --uf2 FILE --bootrom FILE [--camera-latency-us N]
//        [--camera-exposure-us N] [--no-camera] [--events]

import fs from 'node:fs';
import { BasePeripheral, RP2040, USBCDC, GPIOPinState } from 'rp2040js';

const FLASH_START = 0x10000000;
const UF2_MAGIC = [0x0a324655, 0x9e5d5157];
const UF2_END_MAGIC = 0x0ab16f30;
const UF2_FLAG_NOT_MAIN_FLASH = 0x1;
const RP2040_FAMILY = 0xe48bff56;
const TRIGGER_OUT = 14;
const TRIGGER_IN = 15;
const CPU_HZ = 125e6;

function args(argv) {
  const out = { cameraLatencyUs: 20, cameraExposureUs: 2000, camera: true, events: false };
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
    else if (a === '--events') out.events = true;
    else fail(`unknown argument ${a}`);
  }
  if (!out.uf2 || !out.bootrom) fail('--uf2 FILE and --bootrom FILE are required');
  return out;
}

function fail(message) {
  process.stderr.write(`rp2040 harness: ${message}\n`);
  process.exit(2);
}

// UF2: 512-byte blocks, each with 256 (or up to 476) payload bytes for a flash address.
function loadUf2(path, flash) {
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
const blocks = loadUf2(opt.uf2, mcu.flash);
mcu.peripherals[0x14000] = new XipControl(mcu, 'XIP_CTRL');
// boot2 sits at the start of flash; starting there is what the boot ROM does after
// checking it (the ROM's own flash probing is not emulated).
mcu.core.PC = FLASH_START;

const log = (message) => process.stderr.write(`rp2040 harness: ${message}\n`);
log(`${blocks} UF2 blocks loaded from ${opt.uf2}`);

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
};
cdc.onSerialData = (buffer) => {
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
const events = opt.events ? fs.createWriteStream(null, { fd: 3 }) : null;
const triggerIn = mcu.gpio[TRIGGER_IN];
triggerIn.setInputValue(false);
let lastTrigger = false;
mcu.gpio[TRIGGER_OUT].addListener((state) => {
  const high = state === GPIOPinState.High;
  if (high === lastTrigger) return;
  lastTrigger = high;
  const us = mcu.clock.micros;
  if (process.env.FPM_HARNESS_DEBUG) log(`GP${TRIGGER_OUT} ${high ? 'high' : 'low'} at ${us.toFixed(1)} µs`);
  if (events) events.write(`{"pin":${TRIGGER_OUT},"level":${high ? 1 : 0},"us":${us.toFixed(3)}}\n`);
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

// Run: emulated time advances with the instructions executed (and jumps to the next
// alarm while the core sleeps); yield to the event loop often so USB bytes flow.
const cycleNanos = 1e9 / CPU_HZ;
let wallStart = Date.now();
let lastReport = 0;
function run() {
  const clock = mcu.clock;
  for (let i = 0; i < 200000; i++) {
    if (mcu.core.waiting) {
      const skip = clock.nanosToNextAlarm;
      if (skip > 0) clock.tick(skip);
      else clock.tick(cycleNanos);
      i += skip / cycleNanos;
    } else {
      clock.tick(mcu.core.executeInstruction() * cycleNanos);
    }
  }
  const emulatedS = clock.nanos / 1e9;
  if (emulatedS - lastReport >= (process.env.FPM_HARNESS_DEBUG ? 1 : 10)) {
    lastReport = emulatedS;
    log(`${emulatedS.toFixed(0)} s emulated, ${(emulatedS / ((Date.now() - wallStart) / 1e3)).toFixed(2)} emulated s per wall s`);
  }
  setImmediate(run);
}
run();
