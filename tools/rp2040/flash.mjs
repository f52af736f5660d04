// The Pico's QSPI flash chip (a W25Q16JV, 2 MiB) behind the RP2040's SSI, as the boot
// ROM's flash routines and embassy-rp drive it. rp2040js maps the flash contents for
// XIP reads but stubs the SSI: writes to its data register vanish, so a firmware that
// erases or programs flash (or reads the chip's unique id) got nothing. Here the SSI's
// FIFOs and the chip's command set are modelled:
//
// - chip select: forced by the ROM through IO_QSPI's SS override (GPIO_QSPI_SS_CTRL
//   OUTOVER: 2 low, 3 high), or driven by the SSI itself in EEPROM-read mode while it
//   is enabled (embassy-rp's unique-id read);
// - commands: 06/04 write enable/disable, 05/35/15 status, 03/0B read, 02 page
//   program (bits only cleared, wrapping in the 256-byte page), 20/52/D8 erase of
//   4/32/64 KiB, 60/C7 chip erase, 4B unique id, 9F JEDEC id;
// - power cuts: after a given number of erased or programmed bytes the chip stops
//   mid-operation, as a board losing power would.
//
// Everything else (boot2's XIP set-up with the SSI driving chip select itself) sees the
// FIFO behaviour of the stub it replaces: one zero byte received per byte sent.

import { BasePeripheral } from 'rp2040js';

const SSI_CTRLR0 = 0x00;
const SSI_CTRLR1 = 0x04;
const SSI_SSIENR = 0x08;
const SSI_TXFLR = 0x20;
const SSI_RXFLR = 0x24;
const SSI_SR = 0x28;
const SSI_IDR = 0x58;
const SSI_VERSION_ID = 0x5c;
const SSI_DR0 = 0x60;
const SR_TFNF = 0x2;
const SR_TFE = 0x4;
const SR_RFNE = 0x8;
const FIFO_DEPTH = 16;
const TMOD_EEPROM = 3;

const QSPI_SS_CTRL = 0x0c;
const OUTOVER_NORMAL = 0;
const OUTOVER_LOW = 2;

const PAGE = 256;
const ERASE_SIZES = { 0x20: 4096, 0x52: 32768, 0xd8: 65536 };

/** The flash chip: a command state machine over `bytes` (the emulator's flash array). */
export class SpiNorFlash {
  constructor(bytes, { size, uid, onChange, powerCutAfter, onPowerCut }) {
    this.bytes = bytes;
    this.size = size;
    this.uid = uid; // 8 bytes
    this.onChange = onChange;
    this.powerLeft = powerCutAfter ?? Infinity;
    this.onPowerCut = onPowerCut;
    this.writeEnabled = false;
    this.cmd = null;
    this.count = 0;
    this.address = 0;
    this.changed = false;
  }

  begin() {
    this.cmd = null;
    this.count = 0;
    this.address = 0;
  }

  // One byte in, one byte out.
  transfer(b) {
    if (this.cmd === null) {
      this.cmd = b;
      if (b === 0x06) this.writeEnabled = true;
      if (b === 0x04) this.writeEnabled = false;
      return 0xff;
    }
    this.count++;
    const addressing = this.count <= 3;
    if (addressing) this.address = ((this.address << 8) | b) >>> 0;
    switch (this.cmd) {
      case 0x05:
        return this.writeEnabled ? 0x02 : 0x00; // never busy: operations are instant
      case 0x35:
        return 0x02; // QE set: boot2 leaves the status registers alone
      case 0x15:
        return 0x00;
      case 0x03:
        return addressing ? 0xff : this.bytes[this.address++ % this.size];
      case 0x0b:
        return this.count <= 4 ? 0xff : this.bytes[this.address++ % this.size];
      case 0x02:
        if (!addressing && this.writeEnabled) this.program(b);
        return 0xff;
      case 0x4b:
        return this.count <= 4 ? 0xff : this.uid[(this.count - 5) % 8];
      case 0x9f:
        return [0xef, 0x40, 0x15][this.count - 1] ?? 0xff;
      default:
        return 0xff;
    }
  }

  end() {
    const cmd = this.cmd;
    if (cmd !== null && this.writeEnabled) {
      const eraseSize = ERASE_SIZES[cmd];
      if (eraseSize && this.count >= 3) {
        const start = (this.address % this.size) & ~(eraseSize - 1);
        this.erase(start, eraseSize);
      } else if (cmd === 0x60 || cmd === 0xc7) {
        this.erase(0, this.size);
      }
    }
    if ([0x02, 0x20, 0x52, 0xd8, 0x60, 0xc7, 0x01, 0x31].includes(cmd)) this.writeEnabled = false;
    this.cmd = null;
    if (this.changed) {
      this.changed = false;
      this.onChange?.();
    }
  }

  program(b) {
    const page = this.address & ~(PAGE - 1);
    const at = (page + ((this.address - page) % PAGE)) % this.size;
    this.address++;
    this.spend();
    this.bytes[at] &= b;
    this.changed = true;
  }

  erase(start, length) {
    for (let i = start; i < start + length; i++) {
      this.spend();
      this.bytes[i] = 0xff;
    }
    this.changed = true;
  }

  spend() {
    if (this.powerLeft <= 0) {
      this.onPowerCut?.();
      throw new Error('power cut');
    }
    this.powerLeft--;
  }
}

/** The SSI with real FIFO levels, feeding a selected flash chip. */
export class FlashSsi extends BasePeripheral {
  constructor(mcu, flash) {
    super(mcu, 'SSI');
    this.flash = flash;
    this.regs = new Map();
    this.rx = [];
    this.eepromLeft = 0;
    this.outover = OUTOVER_NORMAL;
    this.selected = false;
  }

  get tmod() {
    return ((this.regs.get(SSI_CTRLR0) ?? 0) >> 8) & 3;
  }

  get enabled() {
    return (this.regs.get(SSI_SSIENR) ?? 0) & 1;
  }

  // Chip select follows the override, or the SSI in EEPROM mode while enabled.
  updateSelect() {
    const selected =
      this.outover === OUTOVER_LOW ||
      (this.outover === OUTOVER_NORMAL && this.tmod === TMOD_EEPROM && this.enabled === 1);
    if (selected === this.selected) return;
    this.selected = selected;
    if (selected) this.flash.begin();
    else this.flash.end();
  }

  setOutover(value) {
    this.outover = value;
    this.updateSelect();
  }

  readUint32(offset) {
    switch (offset) {
      case SSI_TXFLR:
        return 0; // sent at once
      case SSI_RXFLR:
        return Math.min(FIFO_DEPTH, this.rx.length + this.eepromLeft);
      case SSI_SR:
        return SR_TFNF | SR_TFE | (this.rx.length > 0 || this.eepromLeft > 0 ? SR_RFNE : 0);
      case SSI_IDR:
        return 0x51535049;
      case SSI_VERSION_ID:
        return 0x3430312a;
      case SSI_DR0:
        if (this.rx.length > 0) return this.rx.shift();
        if (this.eepromLeft > 0) {
          this.eepromLeft--;
          return this.selected ? this.flash.transfer(0) : 0;
        }
        return 0;
      default:
        return this.regs.get(offset) ?? 0;
    }
  }

  writeUint32(offset, value) {
    switch (offset) {
      case SSI_DR0: {
        const out = this.selected ? this.flash.transfer(value & 0xff) : 0;
        if (this.tmod === TMOD_EEPROM) {
          // Command bytes go out; the frames to receive are clocked in afterwards.
          this.eepromLeft = ((this.regs.get(SSI_CTRLR1) ?? 0) & 0xffff) + 1;
        } else if (this.tmod !== 1 && this.rx.length < FIFO_DEPTH) {
          this.rx.push(out);
        }
        return;
      }
      case SSI_SSIENR:
        this.regs.set(offset, value & 1);
        if (!(value & 1)) {
          // Disabling the SSI flushes its FIFOs.
          this.rx = [];
          this.eepromLeft = 0;
        }
        this.updateSelect();
        return;
      default:
        this.regs.set(offset, value >>> 0);
        if (offset === SSI_CTRLR0) this.updateSelect();
    }
  }
}

/** IO_QSPI: register storage, with the chip-select override passed to the SSI. */
export class QspiIo extends BasePeripheral {
  constructor(mcu, ssi) {
    super(mcu, 'IO_QSPI');
    this.ssi = ssi;
    this.regs = new Map();
  }

  readUint32(offset) {
    return this.regs.get(offset) ?? 0;
  }

  writeUint32(offset, value) {
    this.regs.set(offset, value >>> 0);
    if (offset === QSPI_SS_CTRL) this.ssi.setOutover((value >>> 8) & 3);
  }
}
