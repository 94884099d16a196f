#!/usr/bin/python3
"""An independent CANopen peer for interop tests: CiA 402 drives and a force-sensor node.

Written from CiA 301 (NMT, heartbeat, SDO, SYNC, PDO, EMCY) and CiA 402 (device control state
machine, cyclic synchronous position mode), not from cdpr's C++ code. One process plays several
nodes on one SocketCAN interface through python3-can:

    /usr/bin/python3 peer_drive.py --channel vcan0 --drive 1:12000 --drive 2:-3000 \
        --force 9 --gain 2,2,4,1 --offset 0,100,-500,0 --log peer.log --ready peer.ready

Drives (--drive ID[:INITIAL_POSITION]) are CiA 402 servo drives supporting profile position (1),
homing (6) and cyclic synchronous position (8). In CSP, a target received in a synchronous RPDO is
taken at the SYNC that follows it and reached one communication cycle later: the position actual
value sampled at SYNC k is the target taken at SYNC k-1. The statusword is sampled after the
controlword of SYNC k was applied.

The force node (--force ID) is a CiA 401 style analogue input module (0x6401:01..08, INTEGER16).
Channel c measures a simulated tension T_c(t) in N and reports raw = round(gain_c * T_c + offset_c)
with the calibration given by --gain/--offset.

The log (--log, written at exit) has one record per line, fields as key=value:
    nmt cs=0x82 node=0 t=..                  NMT command received
    sdo node=1 dir=download obj=0x6060:00 bytes=08 t=..     every completed SDO transfer
    sdo node=1 dir=upload obj=0x1008:00 bytes=..
    abort node=1 obj=0x2FFF:00 code=0x06020000
    sync n=5 t=..                            SYNC received (n counts from 1)
    rx sync=5 node=1 cw=0x000F target=12000 state=OPERATION_ENABLED   target taken at this SYNC
    tx sync=5 node=1 sw=0x1637 actual=12000  drive TPDO data sampled at this SYNC
    force sync=5 node=9 ch=1 tension=41.25 raw=82   force channel sampled at this SYNC
    state node=1 from=.. to=.. t=..          CiA 402 transitions
    hb_lost node=1 master=127 t=..           the master's heartbeat was lost (0x1016)
    enable node=1 target=.. actual=..        entering OPERATION_ENABLED: the target at that moment
The process exits on SIGTERM/SIGINT, when its parent goes away, or after --max-seconds.
"""

import argparse
import math
import os
import signal
import socket
import struct
import sys
import time

import can

# --- CiA 301 constants ----------------------------------------------------------------------------

COB_NMT = 0x000
COB_SYNC_DEFAULT = 0x080
COB_EMCY = 0x080
COB_SDO_TX = 0x580  # server -> client
COB_SDO_RX = 0x600  # client -> server
COB_HEARTBEAT = 0x700

NMT_START = 0x01
NMT_STOP = 0x02
NMT_PRE_OPERATIONAL = 0x80
NMT_RESET_NODE = 0x81
NMT_RESET_COMMUNICATION = 0x82

# NMT states as sent in heartbeats.
ST_BOOTUP = 0x00
ST_STOPPED = 0x04
ST_OPERATIONAL = 0x05
ST_PRE_OPERATIONAL = 0x7F

# SDO abort codes (CiA 301, 7.2.4.3.17).
ABORT_TOGGLE = 0x05030000
ABORT_TIMEOUT = 0x05040000
ABORT_COMMAND = 0x05040001
ABORT_UNSUPPORTED_ACCESS = 0x06010000
ABORT_WRITE_ONLY = 0x06010001
ABORT_READ_ONLY = 0x06010002
ABORT_NO_OBJECT = 0x06020000
ABORT_NOT_MAPPABLE = 0x06040041
ABORT_PDO_LENGTH = 0x06040042
ABORT_PARAMETER_INCOMPATIBLE = 0x06040043
ABORT_LENGTH_MISMATCH = 0x06070010
ABORT_LENGTH_HIGH = 0x06070012
ABORT_LENGTH_LOW = 0x06070013
ABORT_NO_SUB = 0x06090011
ABORT_VALUE_RANGE = 0x06090030
ABORT_GENERAL = 0x08000000
ABORT_DEVICE_STATE = 0x08000022

PDO_INVALID = 0x80000000
SDO_SERVER_TIMEOUT = 5.0  # s without the next segment request: abort 0x05040000

# --- types ------------------------------------------------------------------------------------------

TYPES = {
    "u8": ("<B", 1),
    "i8": ("<b", 1),
    "u16": ("<H", 2),
    "i16": ("<h", 2),
    "u32": ("<I", 4),
    "i32": ("<i", 4),
    "str": (None, None),  # VISIBLE_STRING, any length
}


def encode(dtype, value):
    fmt, _ = TYPES[dtype]
    if fmt is None:
        return value.encode("ascii")
    return struct.pack(fmt, value)


def decode(dtype, data):
    fmt, _ = TYPES[dtype]
    if fmt is None:
        return data.decode("ascii", errors="replace")
    return struct.unpack(fmt, data)[0]


def in_range(dtype, value):
    fmt, size = TYPES[dtype]
    if fmt is None:
        return True
    bits = 8 * size
    if dtype.startswith("i"):
        return -(1 << (bits - 1)) <= value < (1 << (bits - 1))
    return 0 <= value < (1 << bits)


class SdoAbort(Exception):
    def __init__(self, code):
        super().__init__(hex(code))
        self.code = code


class Variable:
    """One object dictionary entry (index, sub)."""

    def __init__(self, dtype, access, value, mappable=False, on_write=None, on_read=None):
        self.dtype = dtype
        self.access = access  # "ro", "rw", "wo", "const"
        self.default = value
        self.value = value
        self.mappable = mappable
        self.on_write = on_write  # f(new_value) -> None or raises SdoAbort; may store itself
        self.on_read = on_read  # f() -> value

    def size_bits(self):
        _, size = TYPES[self.dtype]
        return 8 * size if size else 0


class ObjectDictionary:
    def __init__(self):
        self.entries = {}
        self.indices = set()

    def add(self, index, sub, dtype, access, value, **kw):
        self.entries[(index, sub)] = Variable(dtype, access, value, **kw)
        self.indices.add(index)

    def lookup(self, index, sub):
        if index not in self.indices:
            raise SdoAbort(ABORT_NO_OBJECT)
        var = self.entries.get((index, sub))
        if var is None:
            raise SdoAbort(ABORT_NO_SUB)
        return var

    def get(self, index, sub=0):
        var = self.entries[(index, sub)]
        return var.on_read() if var.on_read else var.value

    def set(self, index, sub, value):
        self.entries[(index, sub)].value = value

    # SDO access: raw bytes in and out, with the checks of CiA 301.
    def read_bytes(self, index, sub):
        var = self.lookup(index, sub)
        if var.access == "wo":
            raise SdoAbort(ABORT_WRITE_ONLY)
        value = var.on_read() if var.on_read else var.value
        return encode(var.dtype, value)

    def write_bytes(self, index, sub, data):
        var = self.lookup(index, sub)
        if var.access in ("ro", "const"):
            raise SdoAbort(ABORT_READ_ONLY)
        fmt, size = TYPES[var.dtype]
        if size is not None:
            if len(data) > size:
                raise SdoAbort(ABORT_LENGTH_HIGH)
            if len(data) < size:
                raise SdoAbort(ABORT_LENGTH_LOW)
        value = decode(var.dtype, bytes(data))
        if var.on_write:
            var.on_write(value)
        else:
            var.value = value

    def reset_range(self, lo, hi):
        for (index, _), var in self.entries.items():
            if lo <= index <= hi:
                var.value = var.default


# --- one CANopen node -------------------------------------------------------------------------------


class Node:
    """CiA 301 slave: NMT, heartbeat producer/consumer, SDO server, PDOs, SYNC, EMCY."""

    N_PDOS = 4

    def __init__(self, peer, node_id, device_type, name):
        self.peer = peer
        self.id = node_id
        self.name = name
        self.od = ObjectDictionary()
        self.nmt = None  # None before the first boot
        self.next_heartbeat = 0.0
        self.sdo = None  # transfer in progress
        self.sdo_deadline = 0.0
        self.rpdo_latched = {}  # pdo number -> data waiting for the SYNC
        self.tpdo_sync_count = {}  # pdo number -> SYNCs since the last transmission
        self.tpdo_last = {}  # pdo number -> (data, time) of the last transmission
        self.master_seen = None  # time of the last master heartbeat (consumer)
        self._rpdo_cache = None
        self.master_lost = False
        od = self.od
        od.add(0x1000, 0, "u32", "ro", device_type)
        od.add(0x1001, 0, "u8", "ro", 0)
        od.add(0x1005, 0, "u32", "rw", COB_SYNC_DEFAULT, on_write=self._write_sync_cob)
        od.add(0x1008, 0, "str", "const", name)
        od.add(0x1009, 0, "str", "const", "hw-1.0")
        od.add(0x100A, 0, "str", "const", "peer_drive.py 1.0")
        od.add(0x1014, 0, "u32", "rw", COB_EMCY + node_id)
        od.add(0x1016, 0, "u8", "const", 1)
        od.add(0x1016, 1, "u32", "rw", 0, on_write=self._write_consumer)
        od.add(0x1017, 0, "u16", "rw", 0)
        od.add(0x1018, 0, "u8", "const", 4)
        od.add(0x1018, 1, "u32", "ro", 0x00C0FFEE)  # vendor id
        od.add(0x1018, 2, "u32", "ro", 0x402 if device_type & 0xFFFF == 0x0192 else 0x401)
        od.add(0x1018, 3, "u32", "ro", 0x00010002)  # revision
        od.add(0x1018, 4, "u32", "ro", 0x1000 + node_id)  # serial
        # Manufacturer area: a free text label (exercises segmented transfers both ways).
        od.add(0x2000, 0, "str", "rw", "unnamed")
        for n in range(1, self.N_PDOS + 1):
            self._add_pdo(n, rpdo=True)
            self._add_pdo(n, rpdo=False)

    # -- object dictionary helpers --

    def _add_pdo(self, n, rpdo):
        comm = (0x1400 if rpdo else 0x1800) + n - 1
        mapping = (0x1600 if rpdo else 0x1A00) + n - 1
        base = (0x200 if rpdo else 0x180) + 0x100 * (n - 1) + self.id
        od = self.od
        od.add(comm, 0, "u8", "const", 2 if rpdo else 5)
        od.add(comm, 1, "u32", "rw", base | PDO_INVALID, on_write=lambda v: self._write_pdo_cob(comm, v))
        od.add(comm, 2, "u8", "rw", 255, on_write=lambda v: self._write_pdo_type(comm, v))
        if not rpdo:
            od.add(comm, 3, "u16", "rw", 0, on_write=lambda v: self._write_pdo_valid_only(comm, 3, v))
            od.add(comm, 5, "u16", "rw", 0)
        od.add(mapping, 0, "u8", "rw", 0, on_write=lambda v: self._write_map_count(comm, mapping, v))
        for sub in range(1, 9):
            od.add(mapping, sub, "u32", "rw", 0,
                   on_write=lambda v, s=sub: self._write_map_entry(comm, mapping, s, v))

    def set_default_pdo(self, n, rpdo, entries, transmission=255):
        """Pre-defined mapping (restored by a reset of communication)."""
        comm = (0x1400 if rpdo else 0x1800) + n - 1
        mapping = (0x1600 if rpdo else 0x1A00) + n - 1
        od = self.od
        od.entries[(comm, 1)].default &= ~PDO_INVALID
        od.entries[(comm, 2)].default = transmission
        od.entries[(mapping, 0)].default = len(entries)
        for i, e in enumerate(entries, 1):
            od.entries[(mapping, i)].default = e

    def _pdo_valid(self, comm):
        return not (self.od.get(comm, 1) & PDO_INVALID)

    def _write_sync_cob(self, value):
        if value & 0x3FFFF800:
            raise SdoAbort(ABORT_VALUE_RANGE)
        self.od.set(0x1005, 0, value)

    def _write_consumer(self, value):
        # Bits 16..23 node id, 0..15 time in ms (CiA 301, 7.5.2.27).
        self.od.set(0x1016, 1, value)
        self.master_seen = None
        self.master_lost = False

    def _write_pdo_cob(self, comm, value):
        old = self.od.get(comm, 1)
        if value & 0x20000000 or value & 0x1FFFF800:
            raise SdoAbort(ABORT_VALUE_RANGE)  # 29-bit ids not supported
        # A valid PDO's COB-ID may not change; only the valid bit may (CiA 301, 7.5.2.35).
        if not (old & PDO_INVALID) and not (value & PDO_INVALID) and (value & 0x7FF) != (old & 0x7FF):
            raise SdoAbort(ABORT_VALUE_RANGE)
        if not (value & PDO_INVALID):
            rpdo = comm < 0x1800
            mapping = comm + 0x200
            if self.od.get(mapping, 0) > 0 and self._mapped_bits(mapping) == 0:
                raise SdoAbort(ABORT_PARAMETER_INCOMPATIBLE)
            if rpdo:
                self.rpdo_latched.pop(comm - 0x1400 + 1, None)
        self.od.set(comm, 1, value)
        self._rpdo_cache = None

    def _write_pdo_type(self, comm, value):
        if 241 <= value <= 251:
            raise SdoAbort(ABORT_VALUE_RANGE)
        if value in (252, 253):
            raise SdoAbort(ABORT_VALUE_RANGE)  # RTR-only types: not supported
        self.od.set(comm, 2, value)

    def _write_pdo_valid_only(self, comm, sub, value):
        if self._pdo_valid(comm):
            raise SdoAbort(ABORT_DEVICE_STATE)
        self.od.set(comm, sub, value)

    def _mapped_bits(self, mapping):
        total = 0
        for sub in range(1, self.od.get(mapping, 0) + 1):
            total += self.od.get(mapping, sub) & 0xFF
        return total

    def _write_map_count(self, comm, mapping, value):
        # CiA 301, 7.5.2.36: the mapping may change only while the PDO is invalid, and only with
        # sub-index 0 set to 0 first; a new count is checked against the entries.
        if self._pdo_valid(comm):
            raise SdoAbort(ABORT_DEVICE_STATE)
        if value > 8:
            raise SdoAbort(ABORT_VALUE_RANGE)
        total = 0
        for sub in range(1, value + 1):
            entry = self.od.get(mapping, sub)
            self._check_mappable(entry, rpdo=comm < 0x1800)
            total += entry & 0xFF
        if total > 64:
            raise SdoAbort(ABORT_PDO_LENGTH)
        self.od.set(mapping, 0, value)

    def _write_map_entry(self, comm, mapping, sub, value):
        if self._pdo_valid(comm) or self.od.get(mapping, 0) != 0:
            raise SdoAbort(ABORT_PARAMETER_INCOMPATIBLE)
        self._check_mappable(value, rpdo=comm < 0x1800)
        self.od.set(mapping, sub, value)

    def _check_mappable(self, entry, rpdo):
        index, sub, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
        try:
            var = self.od.lookup(index, sub)
        except SdoAbort:
            raise SdoAbort(ABORT_NOT_MAPPABLE)
        if not var.mappable or var.size_bits() != bits:
            raise SdoAbort(ABORT_NOT_MAPPABLE)
        if rpdo and var.access not in ("rw", "wo"):
            raise SdoAbort(ABORT_NOT_MAPPABLE)

    # -- transmission --

    def send(self, cob_id, data):
        self.peer.send(cob_id, bytes(data))

    def emcy(self, code, register=0x01):
        self.od.set(0x1001, 0, register)
        cob = self.od.get(0x1014, 0)
        if not cob & PDO_INVALID:
            self.send(cob & 0x7FF, struct.pack("<HB5x", code, register))

    def heartbeat_state(self):
        return {"preop": ST_PRE_OPERATIONAL, "op": ST_OPERATIONAL, "stopped": ST_STOPPED}[self.nmt]

    # -- NMT --

    def boot(self, reset_application):
        """Power-on or NMT reset: initialise, send the boot-up message, enter PRE-OPERATIONAL."""
        if reset_application:
            self.od.reset_range(0x2000, 0xFFFF)
            self.reset_application()
        self.od.reset_range(0x1000, 0x1FFF)
        self._rpdo_cache = None
        self.sdo = None
        self.rpdo_latched.clear()
        self.tpdo_sync_count.clear()
        self.tpdo_last.clear()
        self.master_seen = None
        self.master_lost = False
        self.od.set(0x1001, 0, 0)
        self.send(COB_HEARTBEAT + self.id, [ST_BOOTUP])
        self.nmt = "preop"
        self.next_heartbeat = time.monotonic()

    def reset_application(self):
        pass

    def on_nmt(self, cs):
        if cs == NMT_START:
            self.set_nmt("op")
        elif cs == NMT_STOP:
            self.set_nmt("stopped")
        elif cs == NMT_PRE_OPERATIONAL:
            self.set_nmt("preop")
        elif cs == NMT_RESET_NODE:
            self.leave_operational()
            self.boot(reset_application=True)
        elif cs == NMT_RESET_COMMUNICATION:
            self.leave_operational()
            self.boot(reset_application=False)

    def set_nmt(self, state):
        if state != "op" and self.nmt == "op":
            self.leave_operational()
        if state != self.nmt:
            self.nmt = state
            # A state change is announced at once (CiA 301 heartbeats report it at the next period;
            # sending now is allowed and makes the master's wait short).
            self.next_heartbeat = time.monotonic()

    def leave_operational(self):
        pass

    # -- heartbeats --

    def poll(self, now, idle):
        """Timers. `idle`: the receive queue is empty, so timeouts may be judged (a peer that runs
        behind must not take frames still queued for missing ones)."""
        period = self.od.get(0x1017, 0)
        if period and self.nmt and now >= self.next_heartbeat:
            self.send(COB_HEARTBEAT + self.id, [self.heartbeat_state()])
            self.next_heartbeat += period / 1000.0
            if self.next_heartbeat <= now:
                self.next_heartbeat = now + period / 1000.0  # late: no burst
        consumer = self.od.get(0x1016, 1)
        timeout_ms = consumer & 0xFFFF
        if idle and timeout_ms and self.master_seen is not None and not self.master_lost:
            if now - self.master_seen > timeout_ms / 1000.0:
                self.master_lost = True
                self.peer.log("hb_lost", node=self.id, master=(consumer >> 16) & 0x7F, t=now)
                self.emcy(0x8130, 0x11)  # life guard / heartbeat error
                self.on_master_lost()
        if idle and self.sdo is not None and now > self.sdo_deadline:
            self.sdo_abort(self.sdo["index"], self.sdo["sub"], ABORT_TIMEOUT)
            self.sdo = None
        self.poll_application(now)

    def poll_application(self, now):
        pass

    def on_master_lost(self):
        pass

    def on_heartbeat(self, node_id, state, now):
        consumer = self.od.get(0x1016, 1)
        if consumer & 0xFFFF and (consumer >> 16) & 0x7F == node_id:
            self.master_seen = now
            self.master_lost = False

    # -- SDO server (CiA 301, 7.2.4) --

    def sdo_send(self, data):
        self.send(COB_SDO_TX + self.id, bytes(data).ljust(8, b"\0"))

    def sdo_abort(self, index, sub, code):
        self.peer.log("abort", node=self.id, obj="0x%04X:%02X" % (index, sub), code="0x%08X" % code)
        self.sdo_send(struct.pack("<BHBI", 0x80, index, sub, code))

    def on_sdo(self, data, now):
        if self.nmt not in ("preop", "op"):
            return  # no SDO in STOPPED
        if len(data) != 8:
            return  # CiA 301: an SDO request has 8 bytes; ignore malformed frames
        cmd = data[0]
        ccs = cmd >> 5
        index, sub = struct.unpack_from("<HB", data, 1)
        try:
            if ccs == 1:
                self.sdo = None
                self._initiate_download(cmd, index, sub, data, now)
            elif ccs == 0:
                self._download_segment(cmd, data, now)
            elif ccs == 2:
                self.sdo = None
                self._initiate_upload(index, sub, now)
            elif ccs == 3:
                self._upload_segment(cmd, now)
            elif ccs == 4:
                self.sdo = None  # abort from the client: drop the transfer, no answer
            else:
                raise SdoAbort(ABORT_COMMAND)  # block transfers are not supported
        except SdoAbort as abort:
            if self.sdo is not None:
                index, sub = self.sdo["index"], self.sdo["sub"]
            self.sdo = None
            self.sdo_abort(index, sub, abort.code)

    def _initiate_download(self, cmd, index, sub, data, now):
        expedited = bool(cmd & 0x02)
        size_indicated = bool(cmd & 0x01)
        var = self.od.lookup(index, sub)
        if var.access in ("ro", "const"):
            raise SdoAbort(ABORT_READ_ONLY)
        if expedited:
            if size_indicated:
                n = 4 - ((cmd >> 2) & 0x03)
            else:
                _, size = TYPES[var.dtype]
                n = size if size else 4
            payload = bytes(data[4:4 + n])
            self.od.write_bytes(index, sub, payload)
            self.peer.log("sdo", node=self.id, dir="download", obj="0x%04X:%02X" % (index, sub),
                          bytes=payload.hex(), t=now)
            self.on_written(index, sub)
            self.sdo_send(struct.pack("<BHB", 0x60, index, sub))
            return
        size = struct.unpack_from("<I", data, 4)[0] if size_indicated else None
        _, fixed = TYPES[var.dtype]
        if size is not None and fixed is not None and size != fixed:
            raise SdoAbort(ABORT_LENGTH_HIGH if size > fixed else ABORT_LENGTH_LOW)
        self.sdo = {"op": "download", "index": index, "sub": sub, "size": size, "buf": bytearray(),
                    "toggle": 0}
        self.sdo_deadline = now + SDO_SERVER_TIMEOUT
        self.sdo_send(struct.pack("<BHB", 0x60, index, sub))

    def _download_segment(self, cmd, data, now):
        t = self.sdo
        if t is None or t["op"] != "download":
            raise SdoAbort(ABORT_COMMAND)
        toggle = (cmd >> 4) & 1
        if toggle != t["toggle"]:
            raise SdoAbort(ABORT_TOGGLE)
        n = 7 - ((cmd >> 1) & 0x07)
        t["buf"] += data[1:1 + n]
        self.sdo_send([0x20 | (toggle << 4)])
        t["toggle"] ^= 1
        self.sdo_deadline = now + SDO_SERVER_TIMEOUT
        if cmd & 0x01:  # last segment
            self.sdo = None
            if t["size"] is not None and t["size"] != len(t["buf"]):
                self.sdo_abort(t["index"], t["sub"], ABORT_LENGTH_MISMATCH)
                return
            try:
                self.od.write_bytes(t["index"], t["sub"], t["buf"])
            except SdoAbort as abort:
                self.sdo_abort(t["index"], t["sub"], abort.code)
                return
            self.peer.log("sdo", node=self.id, dir="download",
                          obj="0x%04X:%02X" % (t["index"], t["sub"]), bytes=bytes(t["buf"]).hex(),
                          t=now)
            self.on_written(t["index"], t["sub"])

    def _initiate_upload(self, index, sub, now):
        payload = self.od.read_bytes(index, sub)
        if len(payload) <= 4 and len(payload) > 0:
            n = 4 - len(payload)
            self.sdo_send(struct.pack("<BHB", 0x43 | (n << 2), index, sub) + payload)
            self.peer.log("sdo", node=self.id, dir="upload", obj="0x%04X:%02X" % (index, sub),
                          bytes=payload.hex(), t=now)
            return
        self.sdo = {"op": "upload", "index": index, "sub": sub, "buf": payload, "pos": 0,
                    "toggle": 0}
        self.sdo_deadline = now + SDO_SERVER_TIMEOUT
        self.sdo_send(struct.pack("<BHBI", 0x41, index, sub, len(payload)))

    def _upload_segment(self, cmd, now):
        t = self.sdo
        if t is None or t["op"] != "upload":
            raise SdoAbort(ABORT_COMMAND)
        toggle = (cmd >> 4) & 1
        if toggle != t["toggle"]:
            raise SdoAbort(ABORT_TOGGLE)
        chunk = t["buf"][t["pos"]:t["pos"] + 7]
        t["pos"] += len(chunk)
        last = t["pos"] >= len(t["buf"])
        self.sdo_send(bytes([(toggle << 4) | ((7 - len(chunk)) << 1) | (1 if last else 0)]) + chunk)
        t["toggle"] ^= 1
        self.sdo_deadline = now + SDO_SERVER_TIMEOUT
        if last:
            self.sdo = None
            self.peer.log("sdo", node=self.id, dir="upload",
                          obj="0x%04X:%02X" % (t["index"], t["sub"]), bytes=t["buf"].hex(), t=now)

    def on_written(self, index, sub):
        pass

    # -- PDOs (CiA 301, 7.2.2) --

    def rpdo_cob_ids(self):
        """COB-ID -> RPDO number for the valid RPDOs (cached; 0x1400.. writes clear the cache)."""
        if self._rpdo_cache is not None:
            return self._rpdo_cache
        out = {}
        for n in range(1, self.N_PDOS + 1):
            cob = self.od.get(0x1400 + n - 1, 1)
            if not cob & PDO_INVALID:
                out[cob & 0x7FF] = n
        self._rpdo_cache = out
        return out

    def on_rpdo(self, n, data):
        if self.nmt != "op":
            return
        mapping = 0x1600 + n - 1
        if len(data) * 8 < self._mapped_bits(mapping):
            self.emcy(0x8210, 0x11)  # PDO not processed due to length error
            return
        if self.od.get(0x1400 + n - 1, 2) <= 240:
            self.rpdo_latched[n] = bytes(data)  # synchronous: taken at the next SYNC
        else:
            self._apply_rpdo(n, data)
            self.on_rpdo_applied(sync=None)

    def _apply_rpdo(self, n, data):
        mapping = 0x1600 + n - 1
        pos = 0
        for sub in range(1, self.od.get(mapping, 0) + 1):
            entry = self.od.get(mapping, sub)
            index, osub, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
            size = bits // 8
            var = self.od.entries[(index, osub)]
            value = decode(var.dtype, data[pos:pos + size])
            pos += size
            if var.on_write:
                var.on_write(value)
            else:
                var.value = value

    def on_rpdo_applied(self, sync):
        pass

    def tpdo_data(self, n):
        mapping = 0x1A00 + n - 1
        out = b""
        for sub in range(1, self.od.get(mapping, 0) + 1):
            entry = self.od.get(mapping, sub)
            index, osub = entry >> 16, (entry >> 8) & 0xFF
            var = self.od.entries[(index, osub)]
            out += encode(var.dtype, var.on_read() if var.on_read else var.value)
        return out

    def on_sync(self, count, now):
        if self.nmt != "op":
            return
        # Outputs first (RPDOs received since the last SYNC), then the application step, then the
        # inputs are sampled into the synchronous TPDOs.
        latched, self.rpdo_latched = self.rpdo_latched, {}
        for n in sorted(latched):
            if self._pdo_valid(0x1400 + n - 1):
                self._apply_rpdo(n, latched[n])
        self.on_rpdo_applied(sync=count)
        self.sync_step(count, now)
        for n in range(1, self.N_PDOS + 1):
            comm = 0x1800 + n - 1
            if not self._pdo_valid(comm):
                continue
            ttype = self.od.get(comm, 2)
            if ttype == 0 or ttype > 240:
                continue
            k = self.tpdo_sync_count.get(n, 0) + 1
            if k >= ttype:
                k = 0
                self.send_tpdo(n, count, now)
            self.tpdo_sync_count[n] = k

    def sync_step(self, count, now):
        pass

    def send_tpdo(self, n, sync, now):
        data = self.tpdo_data(n)
        self.send(self.od.get(0x1800 + n - 1, 1) & 0x7FF, data)
        self.tpdo_last[n] = (data, now)
        self.on_tpdo_sent(n, sync, data)

    def on_tpdo_sent(self, n, sync, data):
        pass

    def poll_event_tpdos(self, now):
        """Event-driven TPDOs (254/255): on change (after the inhibit time) or on the event timer."""
        if self.nmt != "op":
            return
        for n in range(1, self.N_PDOS + 1):
            comm = 0x1800 + n - 1
            if not self._pdo_valid(comm) or self.od.get(comm, 2) < 254:
                continue
            data = self.tpdo_data(n)
            last = self.tpdo_last.get(n)
            inhibit = self.od.get(comm, 3) / 10000.0
            timer = self.od.get(comm, 5) / 1000.0
            if last is None:
                due = True
            else:
                due = (data != last[0] and now - last[1] >= inhibit) or (timer and now - last[1] >= timer)
            if due:
                self.send_tpdo(n, None, now)


# --- CiA 402 drive ------------------------------------------------------------------------------------

# States (CiA 402, 6.2.1) and their statusword bits (mask 0x6F / 0x4F).
NRTSO, SOD, RTSO, SO, OE, QSA, FRA, FAULT = (
    "NOT_READY_TO_SWITCH_ON", "SWITCH_ON_DISABLED", "READY_TO_SWITCH_ON", "SWITCHED_ON",
    "OPERATION_ENABLED", "QUICK_STOP_ACTIVE", "FAULT_REACTION_ACTIVE", "FAULT")
STATE_BITS = {NRTSO: 0x0000, SOD: 0x0040, RTSO: 0x0021, SO: 0x0023, OE: 0x0027, QSA: 0x0007,
              FRA: 0x000F, FAULT: 0x0008}
MODE_PP, MODE_HM, MODE_CSP = 1, 6, 8
SUPPORTED_MODES = (MODE_PP, MODE_HM, MODE_CSP)


class Drive(Node):
    def __init__(self, peer, node_id, initial_position):
        super().__init__(peer, node_id, 0x00020192, "peer 402 drive %d" % node_id)
        self.initial_position = initial_position
        self.position = initial_position  # where the motor is
        self.commanded = initial_position  # where it is going in this cycle
        self.state = NRTSO
        self.last_cw = 0
        self.mode_request_at = None
        self.stop_until = None
        od = self.od
        od.add(0x603F, 0, "u16", "ro", 0, mappable=True)
        od.add(0x6007, 0, "i16", "rw", 1, on_write=self._write_range(0x6007, 0, 3))
        od.add(0x6040, 0, "u16", "rw", 0, mappable=True, on_write=self._write_controlword)
        od.add(0x6041, 0, "u16", "ro", 0, mappable=True, on_read=self.statusword)
        od.add(0x605A, 0, "i16", "rw", 2, on_write=self._write_range(0x605A, 0, 8))
        od.add(0x6060, 0, "i8", "rw", 0, mappable=True, on_write=self._write_mode)
        od.add(0x6061, 0, "i8", "ro", 0, mappable=True)
        od.add(0x6064, 0, "i32", "ro", initial_position, mappable=True,
               on_read=lambda: self.position)
        od.add(0x6065, 0, "u32", "rw", 10000)  # following error window
        od.add(0x606C, 0, "i32", "ro", 0, mappable=True)
        od.add(0x607A, 0, "i32", "rw", initial_position, mappable=True)
        od.add(0x6081, 0, "u32", "rw", 10000, mappable=True)
        od.add(0x6083, 0, "u32", "rw", 100000, mappable=True)
        od.add(0x6084, 0, "u32", "rw", 100000, mappable=True)
        od.add(0x6098, 0, "i8", "rw", 37, on_write=self._write_homing_method)
        od.add(0x60C2, 0, "u8", "const", 2)
        od.add(0x60C2, 1, "u8", "rw", 1)  # interpolation time period value
        od.add(0x60C2, 2, "i8", "rw", -3, on_write=self._write_range(0x60C2, 2, -128, 63))
        od.add(0x6502, 0, "u32", "ro", (1 << 0) | (1 << 5) | (1 << 7), mappable=True)
        # Pre-defined PDOs: RPDO1 controlword, TPDO1 statusword (CiA 402 defaults).
        self.set_default_pdo(1, True, [0x60400010])
        self.set_default_pdo(1, False, [0x60410010])

    def _write_range(self, index, sub, lo, hi=None):
        if hi is None:
            lo, hi = 0, lo

        def write(value):
            if not lo <= value <= hi:
                raise SdoAbort(ABORT_VALUE_RANGE)
            self.od.set(index, sub, value)
        return write

    def _write_homing_method(self, value):
        if value not in (35, 37):
            raise SdoAbort(ABORT_VALUE_RANGE)  # only "current position is home" is supported
        self.od.set(0x6098, 0, value)

    def _write_mode(self, value):
        if value not in SUPPORTED_MODES:
            raise SdoAbort(ABORT_VALUE_RANGE)
        self.od.set(0x6060, 0, value)
        # The mode display follows after a short internal delay (the master must poll 0x6061).
        self.mode_request_at = time.monotonic() + 0.03

    def _write_controlword(self, value):
        self.od.set(0x6040, 0, value)

    def reset_application(self):
        self.position = self.commanded = self.initial_position
        self.state = NRTSO
        self.last_cw = 0
        self.mode_request_at = None

    def boot(self, reset_application):
        super().boot(reset_application)
        if self.state == NRTSO:
            self.set_state(SOD)  # T1: self test done

    def leave_operational(self):
        # Leaving OPERATIONAL ends the PDO communication: a running drive stops (quick stop).
        if self.state == OE:
            self.set_state(QSA)
            self.stop_until = time.monotonic()

    def on_master_lost(self):
        option = self.od.get(0x6007, 0)
        if self.state != OE or option == 0:
            return
        if option == 1:
            self.fault(0x8130)
        elif option == 2:
            self.set_state(SOD)
        elif option == 3:
            self.set_state(QSA)
            self.stop_until = time.monotonic() + 0.04

    def fault(self, code):
        self.od.set(0x603F, 0, code)
        self.set_state(FRA)
        self.emcy(code, 0x81)
        self.set_state(FAULT)

    def set_state(self, state):
        if state == self.state:
            return
        self.peer.log("state", node=self.id, frm=self.state, to=state, t=time.monotonic())
        if state == OE:
            self.peer.log("enable", node=self.id, target=self.od.get(0x607A, 0),
                          actual=self.position)
            self.commanded = self.position
        self.state = state

    def statusword(self):
        sw = STATE_BITS[self.state] | (1 << 9)  # remote
        if self.state in (RTSO, SO, OE, QSA):
            sw |= 1 << 4  # voltage enabled
        if self.position == self.od.get(0x607A, 0) or self.state != OE:
            sw |= 1 << 10  # target reached
        if self.state == OE and self.od.get(0x6061, 0) == MODE_CSP:
            sw |= 1 << 12  # CSP: drive follows the command value
        return sw

    def apply_controlword(self, cw):
        """Device control (CiA 402, 6.2.1.3): the transition the controlword asks for."""
        rising_reset = (cw & 0x80) and not (self.last_cw & 0x80)
        self.last_cw = cw
        s = self.state
        if s == FAULT:
            if rising_reset:
                self.od.set(0x603F, 0, 0)
                self.od.set(0x1001, 0, 0)
                self.set_state(SOD)  # T15
            return
        if s in (NRTSO, FRA):
            return
        enable_voltage = bool(cw & 0x02)
        quick_stop_off = bool(cw & 0x04)  # bit 2 is active low
        switch_on = bool(cw & 0x01)
        enable_op = bool(cw & 0x08)
        if not enable_voltage:
            if s in (RTSO, SO, OE, QSA):
                self.set_state(SOD)  # T7, T9, T10, T12
            return
        if not quick_stop_off:
            if s in (RTSO, SO):
                self.set_state(SOD)  # T7, T10
            elif s == OE:
                self.set_state(QSA)  # T11
                option = self.od.get(0x605A, 0)
                self.stop_until = time.monotonic() + (0.0 if option == 0 else 0.04)
            return
        # bits 1 and 2 set from here on
        if not switch_on:  # shutdown: x110
            if s in (SOD, SO, OE):
                self.set_state(RTSO)  # T2, T6, T8
            return
        if not enable_op:  # switch on: 0111
            if s == RTSO:
                self.set_state(SO)  # T3
            elif s == OE:
                self.set_state(SO)  # T5
            return
        # enable operation: 1111
        if s == SO:
            self.set_state(OE)  # T4
        elif s == RTSO:
            self.set_state(SO)  # T3 (T4 follows at the next command)
        elif s == QSA and self.od.get(0x605A, 0) >= 5:
            self.set_state(OE)  # T16

    def on_rpdo_applied(self, sync):
        self.apply_controlword(self.od.get(0x6040, 0))
        if sync is not None:
            self.peer.log("rx", sync=sync, node=self.id, cw="0x%04X" % self.od.get(0x6040, 0),
                          target=self.od.get(0x607A, 0), state=self.state)

    def poll_application(self, now):
        if self.mode_request_at is not None and now >= self.mode_request_at:
            self.od.set(0x6061, 0, self.od.get(0x6060, 0))
            self.mode_request_at = None
        if self.state == QSA and self.stop_until is not None and now >= self.stop_until:
            self.stop_until = None
            if self.od.get(0x605A, 0) < 5:
                self.set_state(SOD)  # stopped: quick-stop options 0..4 end in SWITCH ON DISABLED
        self.poll_event_tpdos(now)

    def sync_step(self, count, now):
        # The motor reached what was commanded in the last cycle; take the new target.
        self.position = self.commanded
        mode = self.od.get(0x6061, 0)
        if self.state == OE and mode == MODE_CSP:
            self.commanded = self.od.get(0x607A, 0)
        else:
            self.commanded = self.position

    def on_tpdo_sent(self, n, sync, data):
        if sync is not None:
            self.peer.log("tx", sync=sync, node=self.id, pdo=n, data=data.hex(),
                          sw="0x%04X" % self.statusword(), actual=self.position)


# --- force-sensor node (CiA 401 analogue inputs) ------------------------------------------------------


class ForceNode(Node):
    CHANNELS = 8

    def __init__(self, peer, node_id, gains, offsets):
        super().__init__(peer, node_id, 0x00040191, "peer force node %d" % node_id)
        self.gains = gains
        self.offsets = offsets
        self.t0 = time.monotonic()
        od = self.od
        od.add(0x6401, 0, "u8", "const", self.CHANNELS)
        for ch in range(1, self.CHANNELS + 1):
            od.add(0x6401, ch, "i16", "ro", 0, mappable=True)
        self.set_default_pdo(1, False, [0x64010110, 0x64010210, 0x64010310, 0x64010410])
        self.sample(0.0)

    def tension(self, ch, t):
        """The simulated cable tension of channel ch (1-based) at time t, in N."""
        return 30.0 + 8.0 * ch + 12.0 * math.sin(2.0 * math.pi * t / 1.7 + ch) + 3.0 * t

    def sample(self, t):
        self.tensions = {}
        for ch in range(1, self.CHANNELS + 1):
            k = ch - 1
            gain = self.gains[k] if k < len(self.gains) else 1.0
            offset = self.offsets[k] if k < len(self.offsets) else 0.0
            tension = self.tension(ch, t)
            raw = max(-32768, min(32767, int(round(gain * tension + offset))))
            self.tensions[ch] = (tension, raw)
            self.od.set(0x6401, ch, raw)

    def sync_step(self, count, now):
        self.sample(now - self.t0)

    def poll_application(self, now):
        self.poll_event_tpdos(now)

    def on_tpdo_sent(self, n, sync, data):
        mapping = 0x1A00 + n - 1
        for sub in range(1, self.od.get(mapping, 0) + 1):
            entry = self.od.get(mapping, sub)
            if entry >> 16 == 0x6401:
                ch = (entry >> 8) & 0xFF
                tension, raw = self.tensions[ch]
                self.peer.log("force", sync=sync if sync is not None else -1, node=self.id,
                              pdo=n, ch=ch, tension="%.6f" % tension, raw=raw)


# --- the process ------------------------------------------------------------------------------------


class Peer:
    def __init__(self, args):
        self.bus = can.Bus(interface=args.interface, channel=args.channel,
                           receive_own_messages=False)
        sock = getattr(self.bus, "socket", None)
        # A large receive buffer: a slow reader (user-mode-linux) must not lose bursts.
        for opt in (33, socket.SO_RCVBUF):  # SO_RCVBUFFORCE (root), else SO_RCVBUF
            try:
                if sock is not None:
                    sock.setsockopt(socket.SOL_SOCKET, opt, 8 * 1024 * 1024)
                break
            except OSError:
                continue
        self.lines = []
        self.sent = 0
        self.send_errors = 0
        self.nodes = []
        for spec in args.drive:
            node_id, _, pos = spec.partition(":")
            self.nodes.append(Drive(self, int(node_id, 0), int(pos or "0", 0)))
        gains = [float(x) for x in args.gain.split(",")] if args.gain else []
        offsets = [float(x) for x in args.offset.split(",")] if args.offset else []
        for spec in args.force:
            self.nodes.append(ForceNode(self, int(spec, 0), gains, offsets))
        self.sync_count = 0

    def log(self, kind, **fields):
        parts = [kind]
        for k, v in fields.items():
            k = "from" if k == "frm" else k
            if isinstance(v, float):
                v = "%.6f" % v
            parts.append("%s=%s" % (k, v))
        self.lines.append(" ".join(parts))

    def send(self, cob_id, data):
        msg = can.Message(arbitration_id=cob_id, is_extended_id=False, data=data)
        for _ in range(50):
            try:
                self.bus.send(msg, timeout=0.1)
                self.sent += 1
                return
            except can.CanError:
                time.sleep(0.002)  # transmit queue full (ENOBUFS): retry
        self.send_errors += 1

    def dispatch(self, msg, now):
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            return
        cob = msg.arbitration_id
        data = bytes(msg.data)
        if cob == COB_NMT:
            if len(data) != 2:
                return
            cs, target = data[0], data[1]
            self.log("nmt", cs="0x%02X" % cs, node=target, t=now)
            for node in self.nodes:
                if target in (0, node.id):
                    node.on_nmt(cs)
            return
        is_sync = False
        for node in self.nodes:
            if cob == node.od.get(0x1005, 0) & 0x7FF:
                is_sync = True
        if is_sync:
            self.sync_count += 1
            self.log("sync", n=self.sync_count, t=now)
            for node in self.nodes:
                if cob == node.od.get(0x1005, 0) & 0x7FF:
                    node.on_sync(self.sync_count, now)
            return
        if COB_HEARTBEAT < cob <= COB_HEARTBEAT + 127 and len(data) == 1:
            for node in self.nodes:
                node.on_heartbeat(cob - COB_HEARTBEAT, data[0], now)
            return
        for node in self.nodes:
            if cob == COB_SDO_RX + node.id:
                node.on_sdo(data, now)
                return
            n = node.rpdo_cob_ids().get(cob)
            if n is not None:
                node.on_rpdo(n, data)

    def run(self, args):
        stop = []
        signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
        signal.signal(signal.SIGINT, lambda *_: stop.append(1))
        parent = os.getppid()
        for node in self.nodes:
            node.boot(reset_application=True)  # power-on
        if args.ready:
            with open(args.ready + ".tmp", "w") as f:
                f.write("ready %d\n" % os.getpid())
            os.rename(args.ready + ".tmp", args.ready)
        print("peer_drive: ready (%s)" % ", ".join(n.name for n in self.nodes), flush=True)
        end = time.monotonic() + args.max_seconds
        next_check = 0.0
        # Every system call is expensive inside user-mode-linux: one clock read per frame, the
        # parent check twice a second.
        while not stop:
            msg = self.bus.recv(timeout=0.005)
            now = time.monotonic()
            if msg is not None:
                self.dispatch(msg, now)
            for node in self.nodes:
                node.poll(now, idle=msg is None)
            if now >= next_check:
                next_check = now + 0.5
                if now > end or os.getppid() != parent:
                    self.log("exit", reason="time limit" if now > end else "parent gone")
                    break
        self.log("stats", sent=self.sent, send_errors=self.send_errors, syncs=self.sync_count)
        self.bus.shutdown()
        if args.log:
            with open(args.log + ".tmp", "w") as f:
                f.write("\n".join(self.lines) + "\n")
            os.rename(args.log + ".tmp", args.log)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--interface", default="socketcan", help="python-can interface")
    ap.add_argument("--channel", default="vcan0")
    ap.add_argument("--drive", action="append", default=[], help="ID[:INITIAL_POSITION]")
    ap.add_argument("--force", action="append", default=[], help="ID of a force-sensor node")
    ap.add_argument("--gain", default="", help="force channels: comma-separated gains")
    ap.add_argument("--offset", default="", help="force channels: comma-separated offsets")
    ap.add_argument("--log", default="")
    ap.add_argument("--ready", default="", help="file created once the nodes have booted")
    ap.add_argument("--max-seconds", type=float, default=300.0)
    args = ap.parse_args()
    if not args.drive and not args.force:
        ap.error("nothing to play: give --drive and/or --force")
    Peer(args).run(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
