"""The wire between the bridge's two processes: LinuxCNC's HAL component and the ROS node.

Why two processes: LinuxCNC's Python modules (``hal``, ``linuxcnc``) are built for the system's
Python (3.11 on Debian 12, 3.12 on Ubuntu 24.04) and import in no other minor version; the ROS
node runs in the project's venv, made from any Python 3.10-3.13 (docs/linuxcnc.md). So the HAL
component (:mod:`.hal_component`) runs under ``/usr/bin/python3`` inside LinuxCNC's HAL, and the
node (:mod:`.bridge_node`) in the venv; they talk over a Unix stream socket that the component
listens on (one client at a time, mode 0600, in a directory only the run's user can enter).

Plain standard library, the same file on both interpreters. Fixed-size little-endian frames,
each starting with one type byte:

* ``S`` (component -> node), once per poll of the component (1 kHz): :class:`LcncSample`,
  LinuxCNC's state as HAL shows it;
* ``O`` (node -> component), whenever the node has computed the outputs (each sample):
  :class:`HalOutputs`, what the component drives on its output pins; the component falls back
  to its safe outputs (:data:`SAFE_OUTPUTS`) when none came for ``link_timeout_s``;
* ``H`` (component -> node), once after the connection: a JSON text (the component's
  configuration: its INI's limits, the pins it drives), length-prefixed.
"""

from __future__ import annotations

from dataclasses import astuple, dataclass
import json
import struct
from typing import Any

SAMPLE = b'S'
OUTPUTS = b'O'
HELLO = b'H'
VERSION = 2

# ---- LinuxCNC's motion.motion-type (emcmot): what the trajectory planner is executing --------
MOTION_IDLE = 0
MOTION_TRAVERSE = 1   # G0
MOTION_FEED = 2       # G1
MOTION_ARC = 3        # G2 / G3
MOTION_TOOLCHANGE = 4
MOTION_PROBING = 5
MOTION_INDEXROTARY = 6

# ---- the flag bits of a sample ---------------------------------------------------------------
F_SPINDLE_ON = 1 << 0       # spindle.0.on: M3 (the cut's request; the beam is the bridge's)
F_THC_OFF = 1 << 1          # motion.digital-out-02: M62/M64 P2 (hold the height)
F_TORCH_OFF = 1 << 2        # motion.digital-out-03: M62/M64 P3 (beam off while moving)
F_RUNNING = 1 << 3          # halui.program.is-running
F_PAUSED = 1 << 4           # halui.program.is-paused
F_IDLE = 1 << 5             # halui.program.is-idle
F_MACHINE_ON = 1 << 6       # halui.machine.is-on
F_ESTOP = 1 << 7            # halui.estop.is-activated
F_HOMED = 1 << 8            # motion.is-all-homed
F_IN_POSITION = 1 << 9      # motion.in-position
F_FEED_HOLD_IN = 1 << 10    # motion.feed-hold as motion sees it (the net's value)
F_AT_SPEED_IN = 1 << 11     # spindle.0.at-speed as motion sees it
F_LINK_SAFE = 1 << 12       # the component drives its safe outputs (no node, or it went silent)
F_BEAM_GATE = 1 << 13       # the laser gate as HAL drives it (bridge beam AND watchdog)
F_PROGRAM_ERROR = 1 << 14   # ladrc.program-error: LinuxCNC stopped the program on an error

FLAG_NAMES = {F_SPINDLE_ON: 'spindle_on', F_THC_OFF: 'thc_off', F_TORCH_OFF: 'torch_off',
              F_RUNNING: 'running', F_PAUSED: 'paused', F_IDLE: 'idle',
              F_MACHINE_ON: 'machine_on', F_ESTOP: 'estop', F_HOMED: 'homed',
              F_IN_POSITION: 'in_position', F_FEED_HOLD_IN: 'feed_hold_in',
              F_AT_SPEED_IN: 'at_speed_in', F_LINK_SAFE: 'link_safe',
              F_BEAM_GATE: 'beam_gate', F_PROGRAM_ERROR: 'program_error'}

# ---- the flag bits of the outputs --------------------------------------------------------------
O_AT_SPEED = 1 << 0         # -> spindle.0.at-speed (motion starts the cut's first feed move)
O_FEED_HOLD = 1 << 1        # -> motion.feed-hold (M53 P1 enables it, on by default)
O_BEAM = 1 << 2             # -> the laser's gate (ladrc.beam-on)
O_HEIGHT_READY = 1 << 3     # -> ladrc.height-ready (the cycle start's permissive)


@dataclass(frozen=True)
class LcncSample:
    """LinuxCNC's state, one poll of the HAL component (units: mm, mm/s, LinuxCNC's own)."""

    seq: int                  # +1 per sample
    t_ns: int                 # the component's CLOCK_MONOTONIC when it read the pins
    x_mm: float               # joint.0.pos-fb (machine X)
    y_mm: float               # joint.1.pos-fb (machine Y)
    current_vel_mm_s: float   # motion.current-vel: the planner's path speed now
    requested_vel_mm_s: float  # motion.requested-vel: the segment's F (or the rapid rate)
    actual_vel_mm_s: float    # hypot of the derivatives of the XY feedback (ddt in HAL)
    distance_to_go_mm: float  # motion.distance-to-go: left of the segment being executed
    feed_override: float      # halui.feed-override.value (1 = 100 %)
    motion_type: int          # motion.motion-type (MOTION_*)
    program_line: int         # motion.program-line (the G-code line being executed)
    flags: int                # F_* bits
    # the program's pierce (M68 E0/E1/E2: subroutines/touchoff.ngc; 0: none given, the job's)
    pierce_height_mm: float = 0.0  # motion.analog-out-00
    pierce_delay_s: float = 0.0    # motion.analog-out-01
    cut_height_mm: float = 0.0     # motion.analog-out-02

    _FMT = struct.Struct('<cQQdddddddiiIddd')

    def flag(self, bit: int) -> bool:
        """Return whether flag ``bit`` (``F_*``) is set."""
        return bool(self.flags & bit)

    def pack(self) -> bytes:
        """Return the frame."""
        return self._FMT.pack(SAMPLE, *astuple(self))

    @classmethod
    def unpack(cls, data: bytes) -> LcncSample:
        """Return the sample of a frame (``data`` starts with its type byte)."""
        return cls(*cls._FMT.unpack(data)[1:])

    @classmethod
    def size(cls) -> int:
        """Return the frame's size in bytes."""
        return cls._FMT.size

    def as_dict(self) -> dict[str, Any]:
        """Return the sample as plain values, the flags by name."""
        out = {k: v for k, v in zip(('seq', 't_ns', 'x_mm', 'y_mm', 'current_vel_mm_s',
                                     'requested_vel_mm_s', 'actual_vel_mm_s',
                                     'distance_to_go_mm', 'feed_override', 'motion_type',
                                     'program_line'), astuple(self), strict=False)}
        out.update(pierce_height_mm=self.pierce_height_mm, pierce_delay_s=self.pierce_delay_s,
                   cut_height_mm=self.cut_height_mm)
        out.update({name: self.flag(bit) for bit, name in FLAG_NAMES.items()})
        return out


@dataclass(frozen=True)
class HalOutputs:
    """What the node asks the component to drive (``O_*`` flags, the adaptive feed)."""

    seq: int                  # +1 per frame
    adaptive_feed: float      # -> motion.adaptive-feed (M52 P1), 0..1
    flags: int                # O_* bits
    pause_count: int          # +1 asks for one pause (halui.program.pause pulse)

    _FMT = struct.Struct('<cQdII')

    def pack(self) -> bytes:
        """Return the frame."""
        return self._FMT.pack(OUTPUTS, *astuple(self))

    @classmethod
    def unpack(cls, data: bytes) -> HalOutputs:
        """Return the outputs of a frame (``data`` starts with its type byte)."""
        return cls(*cls._FMT.unpack(data)[1:])

    @classmethod
    def size(cls) -> int:
        """Return the frame's size in bytes."""
        return cls._FMT.size


SAFE_OUTPUTS = HalOutputs(0, 1.0, O_FEED_HOLD, 0)
"""No height controller behind the bridge: feed hold, no at-speed, beam off, not ready."""

_LEN = struct.Struct('<I')


def pack_hello(info: dict[str, Any]) -> bytes:
    """Return the hello frame with ``info`` as JSON."""
    text = json.dumps({'version': VERSION, **info}).encode()
    return HELLO + _LEN.pack(len(text)) + text


class FrameReader:
    """Splits a byte stream into frames (``feed`` bytes, ``frames()`` yields them)."""

    SIZES = {SAMPLE: LcncSample.size(), OUTPUTS: HalOutputs.size()}

    def __init__(self) -> None:
        self._buf = bytearray()

    def feed(self, data: bytes) -> None:
        """Append received bytes."""
        self._buf += data

    def frames(self):
        """Yield ``(kind, value)`` for each whole frame received: a sample, outputs or a dict.

        Raises ValueError on a byte that starts no known frame (the stream is not ours).
        """
        buf = self._buf
        while buf:
            kind = bytes(buf[:1])
            if kind == HELLO:
                if len(buf) < 5:
                    return
                n = _LEN.unpack_from(buf, 1)[0]
                if n > 1 << 20:
                    raise ValueError(f'hello frame of {n} bytes')
                if len(buf) < 5 + n:
                    return
                text = bytes(buf[5:5 + n])
                del buf[:5 + n]
                yield HELLO, json.loads(text)
                continue
            size = self.SIZES.get(kind)
            if size is None:
                raise ValueError(f'not a bridge frame: type byte {kind!r}')
            if len(buf) < size:
                return
            frame = bytes(buf[:size])
            del buf[:size]
            yield kind, (LcncSample.unpack(frame) if kind == SAMPLE
                         else HalOutputs.unpack(frame))
