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
// exposure pulse), GP16 WS2812 data (decoded). Log lines go to stderr, and so do the
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

// The WS2812 chain, decoded at the pin (GP16, lane 0). rp2040js runs the PIO one
// instruction per step, on its own wall-clock loop; here it is stepped from the CPU
// loop instead, in lockstep with emulated time: one instruction per PIO_STEP_CYCLES
// system cycles, the WS2812 program's average (10 PIO cycles per bit in 3
// instructions, at clk_sys / 15.625). Bits are told apart by how many instructions
// the line stays high (the program's "1": two, its "0": one); a word is 24 bits, G
// then R then B; a frame ends when the line has stayed low for FRAME_GAP_US (the
// latch) and is reported on stderr as `event {"type":"latched",...}`. Instruction
// delays are not modelled by rp2040js, so pulse widths are only approximate in µs.
const WS2812_PIN = 16;
const PIO_STEP_CYCLES = (CPU_HZ / (800e3 * 10)) * (10 / 3);
const FRAME_GAP_US = 100;
const pio0 = mcu.pio[0];
pio0.run = () => {}; // stepped below, not on its own timer
let pioDebt = 0;
function stepPio(cycles) {
  if (pio0.stopped) return;
  pioDebt += cycles;
  // Called on every CPU instruction: look at the PIO only once a step is due.
  if (pioDebt < PIO_STEP_CYCLES) return;
  if (pioIdle()) {
    // Stalled on an empty FIFO (no frame open): nothing to step until the CPU or DMA
    // writes again.
    pioDebt = 0;
    return;
  }
  while (pioDebt >= PIO_STEP_CYCLES) {
    pioDebt -= PIO_STEP_CYCLES;
    pioSteps++;
    pio0.step();
  }
  if (frameOpen && !lineHigh && mcu.clock.micros - fallUs >= FRAME_GAP_US) closeFrame();
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
let pioSteps = 0;
let riseAt = 0;
let fallUs = 0;
let lineHigh = false;
let bits = 0;
let word = 0;
let frame = [];
let frameOpen = false;
let frameStartUs = 0;
let badPulses = 0;
function emit(event) {
  process.stderr.write(`event ${JSON.stringify(event)}\n`);
}
function closeFrame() {
  if (process.env.FPM_HARNESS_DEBUG) {
    const m = pio0.machines[0];
    log(`frame closed at ${mcu.clock.micros.toFixed(1)} µs (first rise ${frameStartUs.toFixed(1)}, last fall ${fallUs.toFixed(1)}, ${frame.length} words): sm0 enabled ${m.enabled} waiting ${m.waiting} waitType ${m.waitType} fifo ${m.txFIFO.itemCount} txStall 0x${(pio0.txStall >>> 0).toString(16)} idle ${pioIdle()}`);
  }
  if (bits !== 0) badPulses++;
  emit({ type: 'latched', us: Number(mcu.clock.micros.toFixed(3)), lane: 0, words: frame, bad: badPulses });
  frame = [];
  bits = 0;
  word = 0;
  badPulses = 0;
  frameOpen = false;
}
mcu.gpio[WS2812_PIN].addListener((state) => {
  const high = state === GPIOPinState.High;
  if (high === lineHigh) return;
  lineHigh = high;
  if (high) {
    riseAt = pioSteps;
    if (!frameOpen) frameStartUs = mcu.clock.micros;
    frameOpen = true;
    return;
  }
  fallUs = mcu.clock.micros;
  const width = pioSteps - riseAt;
  if (width < 1 || width > 2) badPulses++;
  word = ((word << 1) | (width >= 2 ? 1 : 0)) >>> 0;
  bits++;
  if (bits === 24) {
    frame.push(word);
    word = 0;
    bits = 0;
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
      // Asleep until the next alarm; the PIO keeps running meanwhile.
      const skip = Math.max(clock.nanosToNextAlarm, cycleNanos);
      const cycles = skip / cycleNanos;
      if (!pio0.stopped && cycles > PIO_STEP_CYCLES && !pioIdle()) {
        // Step through the sleep in slices, so the PIO's pin changes land in time; at
        // most 2 ms of it per turn, so a long sleep beside a busy PIO cannot hog the loop.
        const slice = PIO_STEP_CYCLES * cycleNanos;
        let left = Math.min(skip, 2e6);
        while (left > 0 && mcu.core.waiting) {
          const dt = Math.min(slice, left);
          clock.tick(dt);
          stepPio(dt / cycleNanos);
          left -= dt;
        }
      } else {
        clock.tick(skip);
        stepPio(cycles);
      }
      i += cycles;
    } else {
      const cycles = mcu.core.executeInstruction();
      clock.tick(cycles * cycleNanos);
      stepPio(cycles);
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
