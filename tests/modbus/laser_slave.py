#!/usr/bin/python3
"""A laser distance sensor as a Modbus slave, for the integration tests of cdpr_modbus.

The protocol side is pymodbus 3.0 (its RTU / socket framers, request decoder and datastore);
only the byte I/O loop is ours, because pymodbus 3.0's own serial server needs
serial_asyncio, which Debian 12 does not install with python3-pymodbus.

The value is encoded from a register-map YAML file (config/lasers/*.yaml) independently of the
C++ decoder: PyYAML reads the map, struct packs the number big endian (bytes A B C D) and the
map's order (ABCD, CDAB, BADC, DCBA) puts the bytes on the wire.

  laser_slave.py --rtu /tmp/x/b --map map.yaml --slave 17 --distance 1.25 --ready /tmp/x/ready
  laser_slave.py --tcp 0 ...   (binds 127.0.0.1; the port is written to the ready file)

Modes: normal; bad-crc (answers with a corrupted CRC); silent (never answers).
Exits on SIGTERM, when its parent dies, or after --lifetime seconds.
"""

import argparse
import logging
import os
import select
import signal
import socket
import struct
import sys
import time

import yaml
from pymodbus.datastore import (ModbusSequentialDataBlock, ModbusServerContext,
                                ModbusSlaveContext)
from pymodbus.factory import ServerDecoder
from pymodbus.framer.rtu_framer import ModbusRtuFramer
from pymodbus.framer.socket_framer import ModbusSocketFramer

ORDERS = {("high_first", "big"): "ABCD", ("low_first", "big"): "CDAB",
          ("high_first", "little"): "BADC", ("low_first", "little"): "DCBA"}
PACK = {"u16": ">H", "i16": ">h", "u32": ">I", "i32": ">i", "f32": ">f"}


def value_order(value):
    if "order" in value:
        return value["order"]
    return ORDERS[(value.get("word_order", "high_first"), value.get("byte_order", "big"))]


def encode(raw, vtype, order):
    """Registers (as 16-bit ints, first wire byte high) holding raw in the given order."""
    if vtype != "f32":
        raw = int(round(raw))
    data = struct.pack(PACK[vtype], raw)  # A B (C D), most significant first
    if len(data) == 2:
        wire = data if order in ("ABCD", "CDAB") else data[::-1]
    else:
        wire = bytes(data["ABCD".index(c)] for c in order)
    return [(wire[i] << 8) | wire[i + 1] for i in range(0, len(wire), 2)]


class LaserBlock(ModbusSequentialDataBlock):
    """Registers of the sensor. Each read that covers the value advances the distance cycle.
    With a trigger, the value only holds a measurement right after the trigger was written."""

    def __init__(self, size, value_pdu, words_for, count, trigger_pdu=None, idle_words=None):
        super().__init__(0, [0] * size)
        self.value_pdu = value_pdu
        self.words_for = words_for  # index -> registers
        self.count = count
        self.index = 0
        self.trigger_pdu = trigger_pdu
        self.idle_words = idle_words
        self.armed = trigger_pdu is None
        self.triggers = 0

    def getValues(self, address, count=1):
        if address <= self.value_pdu < address + count:
            words = self.words_for(self.index) if self.armed else self.idle_words
            self.index += 1
            super().setValues(self.value_pdu, words)
            if self.trigger_pdu is not None:
                self.armed = False
        return super().getValues(address, count)

    def setValues(self, address, values):
        if self.trigger_pdu is not None and address == self.trigger_pdu:
            self.triggers += 1
            self.armed = True
        super().setValues(address, values)


def build_context(args):
    with open(args.map, encoding="utf-8") as f:
        m = yaml.safe_load(f)
    base = int(m.get("address_base", 0))
    value = m["value"]
    vtype = value["type"]
    order = value_order(value)
    scale = float(value["scale"])
    offset = float(value.get("offset", 0.0))
    value_pdu = int(value["register"]) - base

    def raw_words(raw):
        return encode(raw, vtype, order)

    if args.raw is not None:
        try:
            raw = float(int(args.raw, 0))
        except ValueError:
            raw = float(args.raw)
        cycle = [raw_words(raw)]
    else:
        cycle = [raw_words((d - offset) / scale) for d in args.distance]

    needed = [value_pdu + len(cycle[0])]
    quality = m.get("quality")
    trigger = m.get("trigger")
    if "read" in m:
        needed.append(int(m["read"]["start"]) - base + int(m["read"]["count"]))
    if quality:
        needed.append(int(quality["register"]) - base + 1)
    if trigger:
        needed.append(int(trigger["register"]) - base + 1)
    size = max(needed) + 4

    trigger_pdu = int(trigger["register"]) - base if trigger else None
    idle = raw_words(float(m["no_target"][0])) if trigger and m.get("no_target") else None
    block = LaserBlock(size, value_pdu, lambda i: cycle[i % len(cycle)], len(cycle), trigger_pdu,
                       idle)
    if quality:
        q = args.quality if args.quality is not None else int(quality["ok"][0])
        block.setValues(int(quality["register"]) - base, [q])

    empty = ModbusSequentialDataBlock(0, [0])
    if m["table"] == "input":
        store = ModbusSlaveContext(ir=block, hr=empty, di=empty, co=empty, zero_mode=True)
    else:
        store = ModbusSlaveContext(hr=block, ir=empty, di=empty, co=empty, zero_mode=True)
    return ModbusServerContext(slaves={args.slave: store}, single=False), block


class Responder:
    """Feeds bytes to a pymodbus framer and sends the answers."""

    def __init__(self, framer_cls, context, slave, mode, send):
        self.framer = framer_cls(ServerDecoder(), client=None)
        self.context = context
        self.slave = slave
        self.mode = mode
        self.send = send

    def feed(self, data):
        self.framer.processIncomingPacket(data, self.execute, unit=[self.slave], single=False)

    def execute(self, request):
        response = request.execute(self.context[request.unit_id])
        response.unit_id = request.unit_id
        response.transaction_id = request.transaction_id
        packet = bytearray(self.framer.buildPacket(response))
        if self.mode == "silent":
            return
        if self.mode == "bad-crc":
            packet[-1] ^= 0x5A
        self.send(bytes(packet))


def serve_rtu(args, context, alive):
    fd = os.open(args.rtu, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    responder = Responder(ModbusRtuFramer, context, args.slave, args.mode,
                          lambda b: os.write(fd, b))
    write_ready(args.ready, "rtu")
    last = time.monotonic()
    while alive():
        ready, _, _ = select.select([fd], [], [], 0.1)
        if not ready:
            continue
        try:
            data = os.read(fd, 512)
        except BlockingIOError:
            continue
        now = time.monotonic()
        if now - last > 0.02:  # a silent gap ends any partial frame (RTU t3.5)
            responder.framer.resetFrame()
        last = now
        if data:
            responder.feed(data)


def serve_tcp(args, context, alive):
    listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    listener.bind(("127.0.0.1", args.tcp))
    listener.listen(4)
    write_ready(args.ready, str(listener.getsockname()[1]))
    clients = {}
    while alive():
        ready, _, _ = select.select([listener] + list(clients), [], [], 0.1)
        for s in ready:
            if s is listener:
                conn, _ = listener.accept()
                clients[conn] = Responder(ModbusSocketFramer, context, args.slave, args.mode,
                                          conn.sendall)
                continue
            try:
                data = s.recv(512)
            except OSError:
                data = b""
            if not data:
                clients.pop(s).framer = None
                s.close()
                continue
            clients[s].feed(data)


def write_ready(path, text):
    tmp = path + ".tmp"
    with open(tmp, "w", encoding="utf-8") as f:
        f.write(text + "\n")
    os.rename(tmp, path)


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--rtu", help="serial device (pty) to serve on")
    where.add_argument("--tcp", type=int, help="TCP port on 127.0.0.1 (0: any free port)")
    p.add_argument("--map", required=True, help="register map YAML")
    p.add_argument("--slave", type=int, default=1)
    p.add_argument("--distance", type=float, nargs="+", default=[1.0],
                   help="metres served, cycled per read")
    p.add_argument("--raw", help="serve this raw value instead (e.g. 0xFFFF)")
    p.add_argument("--quality", type=int, help="quality register value")
    p.add_argument("--mode", choices=["normal", "bad-crc", "silent"], default="normal")
    p.add_argument("--ready", required=True, help="file written once serving")
    p.add_argument("--lifetime", type=float, default=120.0)
    args = p.parse_args()

    logging.basicConfig(level=logging.CRITICAL)
    context, block = build_context(args)
    parent = os.getppid()
    deadline = time.monotonic() + args.lifetime
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))

    def alive():
        return not stop and os.getppid() == parent and time.monotonic() < deadline

    if args.rtu:
        serve_rtu(args, context, alive)
    else:
        serve_tcp(args, context, alive)
    print(f"laser_slave: served {block.index} value reads, {block.triggers} triggers",
          file=sys.stderr)


if __name__ == "__main__":
    main()
