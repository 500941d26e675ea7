// Runs the stereotac firmware ELF in an emulated RP2040 (rp2040js 1.4.1, pinned), in
// lock-step with the Rust HIL tests: simulated time only moves when a command asks.
//
// Protocol: one JSON command per line on stdin, one JSON reply per line on stdout.
//   {"op":"run","until_ns":N,"stop_on_in":B}  run to simulated time N (or until bulk IN
//        data arrives when stop_on_in); reply {t_ns, in (hex), edges [t,pin,level,...],
//        rtt (hex), faults}
//   {"op":"send","data":HEX}                  bytes for the bulk OUT endpoint
//   {"op":"reading","on":B}                   the host reads bulk IN (false: it stops
//        reading, so the device's IN transfers stay pending, as on a real bus)
//   {"op":"control","setup":HEX,"data":HEX?}  one control transfer; reply {status
//        ("ok"|"stall"|"timeout"), data}
//   {"op":"quit"}
// The first line written is the boot report: enumeration result or the reason it failed.
//
// rp2040js 1.4.1 needs five corrections, applied here at run time (see README):
//  1. SEV is a no-op: it must set the core's event flag (embassy signals with SEV + WFE).
//  2. VREG_AND_CHIP_RESET is unimplemented: stubbed. XIP_CTRL (0x14000000) too.
//  3. PIO runs on its own timer loop, not simulated time: each enabled state machine is
//     stepped here, in time order with the CPU, honouring its clock divider and delays.
//     A machine stalled on an empty TX FIFO or on a WAIT for a pin is not stepped until
//     a FIFO write or that pin's change releases it.
//  4. A device-mode OUT buffer's AVAILABLE bit is cleared when the firmware arms it:
//     it is kept set until the host delivers data (embassy-rp polls it).
//  5. STALL is never reported to the host side: the host model watches for it.
// The probe inputs are wired as on a bench sensor: GPIO6 (trigger) drives GPIO7 and
// GPIO2 (strip 1) drives GPIO8, with no delay.
// Debugging: HIL_TRACE_USB=1 logs USB traffic, HIL_TRACE_DMA=1 DMA channel triggers, on
// stderr with simulated ns.
// The RP2040 boot ROM is not loaded (its licence forbids use off the chip): a tiny ROM
// of BKPT stubs answers rom_table_lookup and the flash helpers.

import { readFileSync } from 'node:fs';
import { createInterface } from 'node:readline';
import { RP2040 } from 'rp2040js';

const NS_PER_CYCLE = 8; // 125 MHz
const TRACED_PINS = [2, 3, 4, 5, 6, 25];
// The loopback wiring of the firmware's probe inputs (README, "Hardware-in-loop tests"):
// the trigger (GPIO6) to GPIO7, strip 1's data (GPIO2) to GPIO8.
const LOOPBACK = new Map([
  [6, 7],
  [2, 8],
]);

// ---------------------------------------------------------------- ELF loading
function loadElf(mcu, bytes) {
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  if (view.getUint32(0, false) !== 0x7f454c46) throw new Error('not an ELF file');
  const phoff = view.getUint32(0x1c, true);
  const phentsize = view.getUint16(0x2a, true);
  const phnum = view.getUint16(0x2c, true);
  for (let i = 0; i < phnum; i++) {
    const ph = phoff + i * phentsize;
    if (view.getUint32(ph, true) !== 1) continue; // PT_LOAD
    const offset = view.getUint32(ph + 4, true);
    const paddr = view.getUint32(ph + 12, true);
    const filesz = view.getUint32(ph + 16, true);
    if (filesz === 0) continue;
    const data = bytes.subarray(offset, offset + filesz);
    if (paddr >= 0x10000000 && paddr < 0x11000000) {
      mcu.flash.set(data, paddr - 0x10000000);
    } else if (paddr >= 0x20000000 && paddr < 0x20042000) {
      mcu.sram.set(data, paddr - 0x20000000);
    } else {
      throw new Error(`PT_LOAD at 0x${paddr.toString(16)} is outside flash and RAM`);
    }
  }
  // Symbols (for the RTT control block).
  const shoff = view.getUint32(0x20, true);
  const shentsize = view.getUint16(0x2e, true);
  const shnum = view.getUint16(0x30, true);
  const symbols = new Map();
  for (let i = 0; i < shnum; i++) {
    const sh = shoff + i * shentsize;
    if (view.getUint32(sh + 4, true) !== 2) continue; // SHT_SYMTAB
    const off = view.getUint32(sh + 16, true);
    const size = view.getUint32(sh + 20, true);
    const strtab = shoff + view.getUint32(sh + 24, true) * shentsize;
    const stroff = view.getUint32(strtab + 16, true);
    for (let s = off; s + 16 <= off + size; s += 16) {
      let p = stroff + view.getUint32(s, true);
      let name = '';
      while (bytes[p]) name += String.fromCharCode(bytes[p++]);
      if (name) symbols.set(name, view.getUint32(s + 4, true));
    }
  }
  return symbols;
}

// ---------------------------------------------------------------- the chip and its fixes
const elfPath = process.argv[2];
const mcu = new RP2040();
const core = mcu.core;
const clock = mcu.clock;
const faults = [];
mcu.logger = {
  debug() {},
  info(_component, message) {
    // Fix 1: SEV sets the event register.
    if (message === 'SEV') core.eventRegistered = true;
  },
  warn(component, message) {
    if (faults.length < 50) faults.push(`${component}: ${message}`);
    // A CPU running off into the weeds is a test failure, not something to emulate on.
    if (message.includes('not implemented yet')) halted = true;
  },
  error(component, message) {
    if (faults.length < 50) faults.push(`${component}: ${message}`);
  },
};

// Fix 2: stub peripherals rp2040js lacks.
const stub = (name, read) => ({
  name,
  readUint32: (offset) => read(offset),
  writeUint32() {},
  writeUint32Atomic() {},
});
mcu.peripherals[0x40064] = stub('VREG_AND_CHIP_RESET', (o) => (o === 0 ? 0xb1 : 0));
// XIP_CTRL: STAT reports "flush ready, FIFO empty"; STREAM_CTR reads 0 (idle).
mcu.peripherals[0x14000] = stub('XIP_CTRL', (o) => (o === 0x08 ? 0x3 : 0));

// The ROM: magic, a function table nobody reads, and BKPT stubs.
const ROM_LOOKUP = 0x100;
const ROM_STUBS = 0x200;
const romFunctions = ['IF', 'EX', 'RC', 'FC', 'CX', 'UB', 'MS', 'S4', 'MC', 'C4'];
function setRom16(address, value) {
  const word = mcu.bootrom[address >> 2];
  const shift = (address & 2) * 8;
  mcu.bootrom[address >> 2] = ((word & ~(0xffff << shift)) | (value << shift)) >>> 0;
}
setRom16(0x10, 0x754d); // 'M' 'u'
setRom16(0x12, 0x0201); // magic 0x01, version 2
setRom16(0x14, 0x180); // function table (unused: lookups are trapped)
setRom16(0x16, 0x1c0); // data table (unused)
setRom16(0x18, ROM_LOOKUP | 1);
setRom16(ROM_LOOKUP, 0xbef0); // BKPT #0xF0: rom_table_lookup
romFunctions.forEach((_, i) => setRom16(ROM_STUBS + 4 * i, 0xbe00 | i));
let bootloaderRequested = false;
const returnFromStub = (value) => {
  if (value !== undefined) core.registers[0] = value >>> 0;
  core.PC = core.registers[14] & ~1;
};
mcu.onBreak = (code) => {
  if (code === 0xf0) {
    const tag = core.registers[1];
    const name = String.fromCharCode(tag & 0xff, (tag >> 8) & 0xff);
    const index = romFunctions.indexOf(name);
    return returnFromStub(index < 0 ? 0 : (ROM_STUBS + 4 * index) | 1);
  }
  const name = romFunctions[code];
  if (name === 'UB') bootloaderRequested = true; // reset_to_usb_boot
  if (name === 'MS' || name === 'S4') {
    // memset(ptr, c, n)
    const [ptr, c, n] = [core.registers[0], core.registers[1], core.registers[2]];
    for (let i = 0; i < n; i++) mcu.writeUint8(ptr + i, c & 0xff);
    return returnFromStub(ptr);
  }
  if (name === 'MC' || name === 'C4') {
    const [dst, src, n] = [core.registers[0], core.registers[1], core.registers[2]];
    for (let i = 0; i < n; i++) mcu.writeUint8(dst + i, mcu.readUint8(src + i));
    return returnFromStub(dst);
  }
  if (name !== undefined) return returnFromStub(); // flash helpers: nothing to do
  faults.push(`BKPT #${code} at 0x${(core.PC - 2).toString(16)}`);
  halted = true;
};
let halted = false;

// Fix 3: PIO stepped in simulated time.
const machines = [];
// Set when a register write released or enabled a machine: the CPU loop then stops so
// the machine is stepped on time (its edges are stamped when stepped).
let pioWoken = false;
for (const pio of mcu.pio) {
  pio.run = () => {}; // never the timer loop
  for (const sm of pio.machines) {
    const m = { pio, sm, readyNs: 0, idle: false };
    machines.push(m);
  }
  const write = pio.writeUint32.bind(pio);
  pio.writeUint32 = (offset, value) => {
    const cyclesBefore = pio.machines.map((sm) => sm.cycles);
    write(offset, value);
    const now = clock.nanos;
    for (const m of machines) {
      if (m.pio !== pio) continue;
      if (m.idle && !m.sm.waiting) {
        // A FIFO write (or restart) released a stalled pull/out: it completed now,
        // then its delay.
        m.idle = false;
        m.readyNs = now + (1 + m.sm.cycles - cyclesBefore[m.sm.index]) * periodNs(m);
        pioWoken = true;
      } else if (!m.idle) {
        // A machine just enabled must not replay the time it was off.
        m.readyNs = Math.max(m.readyNs, now);
        pioWoken = true;
      }
    }
    pio.checkChangedPins();
  };
}
// rp2040js's WaitType values for a pull and an autopull out on an empty TX FIFO, and
// for a WAIT on a pin.
const WAIT_TX_FIFO = 3;
const WAIT_OUT = 5;
const WAIT_PIN = 1;
function periodNs(m) {
  const div = m.sm.clockDivInt === 0 ? 65536 : m.sm.clockDivInt + m.sm.clockDivFrac / 256;
  return (div * 1e9) / mcu.clkSys;
}
function nextPioNs() {
  let next = Infinity;
  for (const m of machines) {
    if (m.sm.enabled && !m.idle && m.readyNs < next) next = m.readyNs;
  }
  return next;
}
function stepPio(now) {
  for (const m of machines) {
    const sm = m.sm;
    // Catch up: a machine at clk_sys runs several cycles per CPU instruction.
    while (sm.enabled && !m.idle && m.readyNs <= now) {
      const cycles = sm.cycles;
      sm.step();
      m.pio.checkChangedPins();
      if (sm.waiting && (sm.waitType === WAIT_TX_FIFO || sm.waitType === WAIT_OUT)) {
        // Stalled on an empty TX FIFO: only a FIFO write releases it.
        m.idle = true;
        m.waitPin = undefined;
      } else if (
        sm.waiting &&
        sm.waitType === WAIT_PIN &&
        mcu.gpio[sm.waitIndex].inputValue !== sm.waitPolarity
      ) {
        // Waiting for a pin level it does not have yet: only that pin's change releases
        // it (wakePinWaiters). rp2040js enters the wait even when the level is already
        // there; that wait ends on the next step.
        m.idle = true;
        m.waitPin = sm.waitIndex;
      } else {
        m.readyNs += Math.max(1, sm.cycles - cycles) * periodNs(m);
      }
    }
  }
}

// Release the machines waiting on `pin`: its input changed at `now`.
function wakePinWaiters(pin, now) {
  for (const m of machines) {
    // rp2040js may already have ended the wait itself when the input changed.
    if (m.idle && m.waitPin === pin) {
      m.idle = false;
      m.waitPin = undefined;
      m.readyNs = now;
    }
  }
}

// ---------------------------------------------------------------- USB host model
const usb = mcu.usbCtrl;
const AVAILABLE = 1 << 10;
const FULL = 1 << 15;
const STALL = 1 << 11;
const dpram = mcu.usbDPRAMView;
let inEp = -1;
let outEp = -1;
let ctl = null; // the control transfer in progress
let ep0OutArmed = false;
const outQueue = [];
const outArmed = new Map(); // endpoint -> size the firmware armed
let reading = true;
const heldIn = []; // IN buffer controls armed while the host was not reading
let inBytes = [];
let enumerated = null;

// Fix 4 and 5.
const dpramUpdated = usb.DPRAMUpdated.bind(usb);
usb.DPRAMUpdated = (offset, value) => {
  const isBufCtrl = offset >= 0x80 && offset < 0x100;
  if (!reading && inEp > 0 && offset === 0x80 + inEp * 8 && value & AVAILABLE) {
    // A host that does not read leaves the armed IN buffer AVAILABLE (the firmware
    // cannot queue the next one) until it reads again.
    heldIn.push(offset);
    return;
  }
  if (isBufCtrl && offset <= 0x84 && value & STALL && ctl) {
    ctl.status = 'stall';
    ctl.done = true;
  }
  dpramUpdated(offset, value);
  if (isBufCtrl && offset & 4 && value & AVAILABLE) {
    const now = dpram.getUint32(offset, true);
    if (!(now & FULL)) dpram.setUint32(offset, (now | AVAILABLE) >>> 0, true);
  }
};
const finishRead = usb.finishRead.bind(usb);
usb.finishRead = (endpoint, buffer) => {
  const reg = 0x84 + endpoint * 8;
  dpram.setUint32(reg, dpram.getUint32(reg, true) & ~AVAILABLE, true);
  finishRead(endpoint, buffer);
};

function deliverOut() {
  const size = outArmed.get(outEp);
  if (size === undefined || outQueue.length === 0) return;
  const chunk = Uint8Array.from(outQueue.splice(0, Math.min(size, 64)));
  traceUsb('OUT deliver', outEp, hex(chunk));
  outArmed.delete(outEp);
  usb.endpointReadDone(outEp, chunk);
}

const traceUsb = process.env.HIL_TRACE_USB ? (...a) => process.stderr.write(`[usb ${clock.nanos}] ${a.join(' ')}\n`) : () => {};
usb.onUSBEnabled = () => usb.resetDevice();
usb.onResetReceived = () => startEnumeration();
usb.onEndpointWrite = (endpoint, buffer) => {
  traceUsb('IN', endpoint, hex(buffer));
  if (endpoint === 0) {
    if (!ctl || ctl.done) return;
    if (ctl.in) {
      ctl.data.push(...buffer);
      if (buffer.length < 64 || ctl.data.length >= ctl.length) {
        ctl.stage = 'status';
        if (ep0OutArmed) finishControlIn();
      }
    } else {
      ctl.status = 'ok'; // the status stage of an OUT or no-data request
      ctl.done = true;
    }
    return;
  }
  if (endpoint === inEp) {
    inBytes.push(...buffer);
  }
};
usb.onEndpointRead = (endpoint, size) => {
  traceUsb('OUT armed', endpoint, size);
  if (endpoint === 0) {
    ep0OutArmed = true;
    if (ctl && !ctl.done && ctl.in && ctl.stage === 'status') finishControlIn();
    else if (ctl && !ctl.done && !ctl.in && ctl.out.length > 0) {
      ep0OutArmed = false;
      usb.endpointReadDone(0, Uint8Array.from(ctl.out.splice(0, Math.min(size, 64))));
    }
    return;
  }
  outArmed.set(endpoint, size);
  if (endpoint === outEp) deliverOut();
};
function finishControlIn() {
  ep0OutArmed = false;
  usb.endpointReadDone(0, new Uint8Array(0));
  ctl.status = 'ok';
  ctl.done = true;
}
function startControl(setup, out = []) {
  const length = setup[6] | (setup[7] << 8);
  ctl = { in: !!(setup[0] & 0x80), length, data: [], out: [...out], stage: 'data', done: false, status: 'timeout' };
  usb.sendSetupPacket(Uint8Array.from(setup));
  return ctl;
}
const setup = (type, request, value, index, length) => [
  type, request, value & 0xff, value >> 8, index & 0xff, index >> 8, length & 0xff, length >> 8,
];

// Enumeration as a host does it, one request after the other.
let enumSteps = null;
function startEnumeration() {
  enumerated = { ok: false };
  enumSteps = [
    () => startControl(setup(0x00, 5, 1, 0, 0)), // SET_ADDRESS 1
    () => startControl(setup(0x80, 6, 0x0100, 0, 18)), // device descriptor
    () => startControl(setup(0x80, 6, 0x0200, 0, 9)), // configuration, header
    (prev) => startControl(setup(0x80, 6, 0x0200, 0, prev[2] | (prev[3] << 8))), // all of it
    () => startControl(setup(0x80, 6, 0x0300 | enumerated.device[16], 0x0409, 255)), // serial
    () => startControl(setup(0x00, 9, 1, 0, 0)), // SET_CONFIGURATION 1
  ];
  enumerated.step = 0;
  enumSteps[0]();
}
function advanceEnumeration() {
  if (!enumSteps || !ctl || !ctl.done) return;
  const step = enumerated.step;
  if (ctl.status !== 'ok') {
    enumerated.error = `enumeration step ${step} ended with ${ctl.status}`;
    enumSteps = null;
    return;
  }
  const data = ctl.data;
  if (step === 1) enumerated.device = data;
  if (step === 3) enumerated.config = data;
  if (step === 4) {
    let serial = '';
    for (let i = 2; i + 1 < data.length; i += 2) serial += String.fromCharCode(data[i] | (data[i + 1] << 8));
    enumerated.serial = serial;
  }
  enumerated.step = step + 1;
  if (enumerated.step < enumSteps.length) {
    enumSteps[enumerated.step](data);
  } else {
    enumSteps = null;
    ctl = null;
    findBulkEndpoints(enumerated.config);
    enumerated.ok = inEp > 0 && outEp > 0;
    if (!enumerated.ok) enumerated.error = 'no vendor interface with bulk IN and OUT';
  }
}
function findBulkEndpoints(config) {
  let vendor = false;
  for (let i = 0; i + 1 < config.length && config[i] >= 2; i += config[i]) {
    const type = config[i + 1];
    if (type === 4) vendor = config[i + 5] === 0xff;
    if (type === 5 && vendor && (config[i + 3] & 3) === 2) {
      if (config[i + 2] & 0x80) inEp = config[i + 2] & 0xf;
      else outEp = config[i + 2] & 0xf;
    }
  }
}

// ---------------------------------------------------------------- pins and RTT
let edges = [];
for (const pin of TRACED_PINS) {
  let last = -1;
  mcu.gpio[pin].addListener((state) => {
    const level = state === 1 ? 1 : 0;
    if (level !== last) {
      last = level;
      edges.push(clock.nanos, pin, level);
      const wired = LOOPBACK.get(pin);
      if (wired !== undefined) {
        mcu.gpio[wired].setInputValue(level === 1);
        wakePinWaiters(wired, clock.nanos);
      }
    }
  });
}
let rttAddress = 0;
function drainRtt() {
  if (!rttAddress) return [];
  const up = rttAddress + 24;
  const buffer = mcu.readUint32(up + 4);
  const size = mcu.readUint32(up + 8);
  const write = mcu.readUint32(up + 12);
  let read = mcu.readUint32(up + 16);
  const out = [];
  if (!buffer || !size) return out;
  while (read !== write) {
    out.push(mcu.readUint8(buffer + read));
    read = (read + 1) % size;
  }
  mcu.writeUint32(up + 16, read);
  return out;
}

if (process.env.HIL_TRACE_DMA) {
  const w = mcu.dma.writeUint32.bind(mcu.dma);
  mcu.dma.writeUint32 = (offset, value) => {
    if ((offset & 0x3f) === 0x0c && offset < 0x400) process.stderr.write(`[dma ${clock.nanos}] ch${offset >> 6} trig ${value.toString(16)}\n`);
    w(offset, value);
  };
}
// ---------------------------------------------------------------- the run loop
function runUntil(targetNs, stop) {
  while (clock.nanos < targetNs && !halted) {
    if (stop && stop()) break;
    const pioNext = nextPioNs();
    if (core.waiting) {
      const alarm = clock.nextAlarm ? clock.nextAlarm.nanos : Infinity;
      const t = Math.min(alarm, pioNext, targetNs);
      if (t > clock.nanos) clock.tick(t - clock.nanos);
      else clock.tick(0);
    } else {
      // Instructions until the next PIO step is due.
      const until = Math.min(pioNext, targetNs);
      pioWoken = false;
      do {
        const cycles = core.executeInstruction();
        clock.tick(cycles * NS_PER_CYCLE);
      } while (
        !core.waiting &&
        !pioWoken &&
        clock.nanos < until &&
        !halted &&
        !(stop && stop())
      );
    }
    stepPio(clock.nanos);
    advanceEnumeration();
    if (bootloaderRequested) halted = true;
  }
}

const hex = (bytes) => Buffer.from(bytes).toString('hex');
const fromHex = (text) => [...Buffer.from(text || '', 'hex')];

function report(extra = {}) {
  const reply = {
    t_ns: clock.nanos,
    in: hex(inBytes),
    edges,
    rtt: hex(drainRtt()),
    faults: faults.splice(0),
    halted,
    bootloader: bootloaderRequested,
    ...extra,
  };
  inBytes = [];
  edges = [];
  return reply;
}

function handle(command) {
  switch (command.op) {
    case 'run':
      runUntil(command.until_ns, command.stop_on_in ? () => inBytes.length > 0 : null);
      return report();
    case 'send':
      outQueue.push(...fromHex(command.data));
      deliverOut();
      return { ok: true };
    case 'reading':
      reading = !!command.on;
      if (reading) {
        for (const offset of heldIn.splice(0)) usb.DPRAMUpdated(offset, dpram.getUint32(offset, true));
      }
      return { ok: true };
    case 'control': {
      const transfer = startControl(fromHex(command.setup), fromHex(command.data));
      runUntil(clock.nanos + 100e6, () => transfer.done);
      ctl = null;
      return report({ status: transfer.status, data: hex(transfer.data) });
    }
    default:
      return { error: `unknown op ${command.op}` };
  }
}

// ---------------------------------------------------------------- boot
function boot() {
  const symbols = loadElf(mcu, readFileSync(elfPath));
  rttAddress = symbols.get('_SEGGER_RTT') || 0;
  core.VTOR = 0x10000100;
  core.SP = mcu.readUint32(0x10000100);
  core.PC = mcu.readUint32(0x10000104) & ~1;
  runUntil(3e9, () => enumerated && (enumerated.ok || enumerated.error));
  return report({
    ready: !!(enumerated && enumerated.ok),
    error: enumerated ? enumerated.error : 'the firmware never enabled USB',
    serial: enumerated ? enumerated.serial : null,
    device: enumerated && enumerated.device ? hex(enumerated.device) : null,
    in_ep: inEp,
    out_ep: outEp,
  });
}

const write = (object) => process.stdout.write(`${JSON.stringify(object)}\n`);
try {
  write(boot());
} catch (e) {
  write({ ready: false, error: String(e && e.stack ? e.stack : e) });
  process.exit(1);
}
const lines = createInterface({ input: process.stdin });
lines.on('line', (line) => {
  let command;
  try {
    command = JSON.parse(line);
  } catch (e) {
    write({ error: `bad command: ${e}` });
    return;
  }
  if (command.op === 'quit') {
    lines.close();
    return;
  }
  try {
    write(handle(command));
  } catch (e) {
    write({ error: String(e && e.stack ? e.stack : e), t_ns: clock.nanos });
  }
});
