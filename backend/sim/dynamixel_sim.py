"""A byte-level Dynamixel X-series servo (XM430-W350-like) on a pseudo-terminal.

:class:`DynamixelSimulator` opens a pty pair and, in a thread, plays the servo's end of
Dynamixel Protocol 2.0 as ROBOTIS's SDK (``dynamixel_sdk/protocol2_packet_handler.py``) speaks it:

Instruction packet (host -> servo), little-endian::

    FF FF FD 00 | ID | LEN_L LEN_H | INST | PARAM... | CRC_L CRC_H

``LEN`` counts INST + PARAM + CRC. ``CRC`` is the CRC-16 (polynomial 0x8005, initial 0, no
reflection: the SDK's ``updateCRC`` table) of every byte from ``FF`` up to the last parameter.
Inside INST..PARAM, each ``FF FF FD`` is followed by a stuffing byte ``FD`` (counted in LEN).
The status packet (servo -> host) is the same with ``INST = 0x55`` and an ``ERR`` byte before the
parameters. Instructions served: ``PING`` (0x01: model number u16 + firmware version u8),
``READ`` (0x02: address u16, length u16 -> the bytes) and ``WRITE`` (0x03: address u16, data).
Broadcast (ID 0xFE) writes are applied without a reply. A packet whose CRC is wrong is answered
with error 0x03 (CRC error) and not executed, as the e-Manual describes; an unknown instruction
gets 0x02, an address outside the control table or a read-only item 0x07 (access), a goal outside
0..4095 0x06 (data limit).

Control table (RAM/EEPROM items of the XM430 used here): model number 0 (u16, 1020), firmware
version 6, ID 7, baud rate 8, operating mode 11 (3 = position), torque enable 64, LED 65, moving
122, goal position 116 (i32), present position 132 (i32), present temperature 146. Positions are
ticks, 4096 per revolution, 2048 = centre. With torque on, the horn moves toward the goal at
``speed_deg_s`` and stops exactly on it; :meth:`true_angle_rad` is the physical angle (what a
simulated scanner on the horn sees), present position its tick count.

Faults: ``corrupt_every`` spoils the CRC of every n-th status packet (the SDK then reports
``COMM_RX_CORRUPT``). :attr:`port` is a symlink in a private folder, as for the YDLiDAR simulator.
"""

from __future__ import annotations

import math
import struct
import threading
import time

from backend.sim.pty_device import PtyDevice

TICKS_PER_REV = 4096
CENTER_TICKS = 2048

ADDR_MODEL_NUMBER = 0
ADDR_FIRMWARE_VERSION = 6
ADDR_ID = 7
ADDR_BAUD_RATE = 8
ADDR_OPERATING_MODE = 11
ADDR_TORQUE_ENABLE = 64
ADDR_LED = 65
ADDR_GOAL_POSITION = 116
ADDR_MOVING = 122
ADDR_PRESENT_POSITION = 132
ADDR_PRESENT_TEMPERATURE = 146
TABLE_SIZE = 147
WRITABLE = {ADDR_TORQUE_ENABLE, ADDR_LED, *range(ADDR_GOAL_POSITION, ADDR_GOAL_POSITION + 4)}

INST_PING = 0x01
INST_READ = 0x02
INST_WRITE = 0x03
INST_STATUS = 0x55
BROADCAST_ID = 0xFE

ERR_INSTRUCTION = 0x02
ERR_CRC = 0x03
ERR_DATA_LIMIT = 0x06
ERR_ACCESS = 0x07

XM430_W350_MODEL = 1020
HEADER = b"\xff\xff\xfd\x00"


def _crc_table() -> list[int]:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return table


_CRC_TABLE = _crc_table()


def crc16(data: bytes) -> int:
    """Dynamixel Protocol 2.0 CRC-16 (poly 0x8005, init 0, MSB first), as the SDK's ``updateCRC``."""
    crc = 0
    for b in data:
        crc = ((crc << 8) ^ _CRC_TABLE[((crc >> 8) ^ b) & 0xFF]) & 0xFFFF
    return crc


def stuff(body: bytes) -> bytes:
    """Insert ``FD`` after every ``FF FF FD`` in INST..PARAM (the bytes before them are the header)."""
    out = bytearray()
    for b in body:
        out.append(b)
        if b == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF:
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes) -> bytes:
    """Drop the stuffing byte of every ``FF FF FD FD``."""
    out = bytearray()
    i = 0
    while i < len(body):
        out.append(body[i])
        if body[i] == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF \
                and i + 1 < len(body) and body[i + 1] == 0xFD:
            i += 1
        i += 1
    return bytes(out)


def build_packet(dxl_id: int, body: bytes, corrupt: bool = False) -> bytes:
    """``FF FF FD 00 ID LEN INST|ERR|PARAM(stuffed) CRC`` for an unstuffed ``body`` (INST first)."""
    stuffed = stuff(body)
    head = HEADER + struct.pack("<BH", dxl_id, len(stuffed) + 2)
    crc = crc16(head + stuffed) ^ (0x5A5A if corrupt else 0)
    return head + stuffed + struct.pack("<H", crc)


def instruction_packet(dxl_id: int, instruction: int, params: bytes = b"", bad_crc: bool = False) -> bytes:
    """An instruction packet as the SDK sends it (for tests)."""
    return build_packet(dxl_id, bytes([instruction]) + params, corrupt=bad_crc)


def status_packet(dxl_id: int, error: int, params: bytes = b"", corrupt: bool = False) -> bytes:
    """A status packet (``INST = 0x55``)."""
    return build_packet(dxl_id, bytes([INST_STATUS, error]) + params, corrupt=corrupt)


class DynamixelSimulator(PtyDevice):
    """A simulated XM430 behind a pty; :attr:`port` is the path a driver opens."""

    def __init__(self, *, dxl_id: int = 1, model_number: int = XM430_W350_MODEL, speed_deg_s: float = 240.0,
                 initial_ticks: int = CENTER_TICKS, corrupt_every: int = 0):
        """Args:
        dxl_id: the servo's ID (1..252).
        model_number: reported by PING and at address 0 (XM430-W350 = 1020).
        speed_deg_s: how fast the horn turns toward the goal with torque on (deg/s).
        initial_ticks: present position at power-up (ticks).
        corrupt_every: spoil the CRC of every n-th status packet (0 = never).
        """
        self.dxl_id = dxl_id
        self.model_number = model_number
        self.speed_deg_s = float(speed_deg_s)
        self.corrupt_every = corrupt_every
        self.table = bytearray(TABLE_SIZE)
        struct.pack_into("<H", self.table, ADDR_MODEL_NUMBER, model_number)
        self.table[ADDR_FIRMWARE_VERSION] = 46
        self.table[ADDR_ID] = dxl_id
        self.table[ADDR_BAUD_RATE] = 1  # 57600
        self.table[ADDR_OPERATING_MODE] = 3  # position control
        self.table[ADDR_PRESENT_TEMPERATURE] = 31
        struct.pack_into("<i", self.table, ADDR_GOAL_POSITION, int(initial_ticks))
        self._position = float(initial_ticks)
        """Physical horn position (ticks, fractional while moving)."""
        self._last_update = time.monotonic()
        self._lock = threading.Lock()
        self.instructions: list[int] = []
        """Instruction bytes executed (good CRC, addressed to us), in order."""
        self.crc_errors = 0
        """Instruction packets rejected for a wrong CRC."""
        self.status_sent = 0
        self.corrupted_sent = 0
        super().__init__("ttyDXL")
        self._buf = b""

    # ------------------------------------------------------------------ physics
    def _update(self) -> None:
        """Advance the horn toward the goal (call with the lock held)."""
        now = time.monotonic()
        dt, self._last_update = now - self._last_update, now
        goal = struct.unpack_from("<i", self.table, ADDR_GOAL_POSITION)[0]
        if self.table[ADDR_TORQUE_ENABLE]:
            step = self.speed_deg_s / 360.0 * TICKS_PER_REV * dt
            diff = goal - self._position
            self._position = float(goal) if abs(diff) <= step else self._position + math.copysign(step, diff)
        struct.pack_into("<i", self.table, ADDR_PRESENT_POSITION, int(round(self._position)))
        self.table[ADDR_MOVING] = int(self._position != goal and bool(self.table[ADDR_TORQUE_ENABLE]))

    def true_angle_rad(self) -> float:
        """The horn's physical angle (rad) from the centre position, as ticks map to angles."""
        with self._lock:
            self._update()
            return (self._position - CENTER_TICKS) * 2.0 * math.pi / TICKS_PER_REV

    def present_ticks(self) -> int:
        with self._lock:
            self._update()
            return struct.unpack_from("<i", self.table, ADDR_PRESENT_POSITION)[0]

    def goal_ticks(self) -> int:
        with self._lock:
            return struct.unpack_from("<i", self.table, ADDR_GOAL_POSITION)[0]

    # ------------------------------------------------------------------ protocol
    def _execute(self, dxl_id: int, inst: int, params: bytes) -> tuple[int, bytes] | None:
        """Run one instruction; (error, reply parameters), or None for no reply."""
        with self._lock:
            self._update()
            if inst == INST_PING:
                return 0, struct.pack("<HB", self.model_number, self.table[ADDR_FIRMWARE_VERSION])
            if inst == INST_READ:
                if len(params) != 4:
                    return ERR_INSTRUCTION, b""
                addr, length = struct.unpack("<HH", params)
                if addr + length > TABLE_SIZE or length == 0:
                    return ERR_ACCESS, b""
                return 0, bytes(self.table[addr:addr + length])
            if inst == INST_WRITE:
                if len(params) < 3:
                    return ERR_INSTRUCTION, b""
                addr = params[0] | (params[1] << 8)
                data = params[2:]
                if any(a not in WRITABLE for a in range(addr, addr + len(data))):
                    return ERR_ACCESS, b""
                new = bytearray(self.table)
                new[addr:addr + len(data)] = data
                goal = struct.unpack_from("<i", new, ADDR_GOAL_POSITION)[0]
                if not 0 <= goal < TICKS_PER_REV:
                    return ERR_DATA_LIMIT, b""
                self.table[addr:addr + len(data)] = data
                self._update()
                return 0, b""
            return ERR_INSTRUCTION, b""

    def _reply(self, error: int, params: bytes) -> bytes:
        self.status_sent += 1
        corrupt = self.corrupt_every > 0 and self.status_sent % self.corrupt_every == 0
        self.corrupted_sent += corrupt
        return status_packet(self.dxl_id, error, params, corrupt=corrupt)

    def handle(self, data: bytes) -> bytes:
        """Feed bytes from the host; return the bytes the servo answers (for tests without a pty)."""
        buf = self._buf + data
        out = []
        while True:
            i = buf.find(HEADER)
            if i < 0:
                buf = buf[-3:]  # may hold the start of a header
                break
            buf = buf[i:]
            if len(buf) < 7:
                break
            dxl_id = buf[4]
            length = buf[5] | (buf[6] << 8)
            if length < 3 or length > 1024:
                buf = buf[1:]  # not a packet after all
                continue
            if len(buf) < 7 + length:
                break
            packet, buf = buf[:7 + length], buf[7 + length:]
            if dxl_id != self.dxl_id and dxl_id != BROADCAST_ID:
                continue
            if crc16(packet[:-2]) != (packet[-2] | (packet[-1] << 8)):
                self.crc_errors += 1
                if dxl_id == self.dxl_id:
                    out.append(self._reply(ERR_CRC, b""))
                continue
            body = unstuff(packet[7:-2])
            inst, params = body[0], body[1:]
            self.instructions.append(inst)
            result = self._execute(dxl_id, inst, params)
            if result is not None and dxl_id == self.dxl_id:
                out.append(self._reply(*result))
        self._buf = buf
        return b"".join(out)

    # ------------------------------------------------------------------ device loop
    def on_plug(self) -> None:
        """A power cycle loses half-received instructions; the horn stays where it is."""
        self._buf = b""

    def serve(self) -> None:
        while not self.stopping:
            data = self.read(0.01)
            if data is None:
                return
            if data and not self.write(self.handle(data)):
                return
