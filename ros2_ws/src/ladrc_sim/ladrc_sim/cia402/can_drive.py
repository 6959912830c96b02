"""The emulated CiA 402 Z drive: the simulator's axis, sheet and sensor behind a CANopen node.

:class:`CanDrive` is a controller of the headless runner (:func:`ladrc_sim.headless.runner.run`,
:func:`ladrc_sim.job.runner.run_job`): the runner keeps its world (the axis model, the sheet, the
sensor, a job's CNC) and steps the drive once per period; the drive answers with the velocity the
CiA 402 device applies, from the target a CANopen master sent. One implementation of the world
for the sim node, the emulated drive and headless runs.

The CANopen side is a ``canopen.LocalNode`` built from the EDS (default: the shipped
``ladrc_z_drive.eds``). canopen gives the SDO server (the master writes the PDO mapping, 0x6060
... by SDO), the heartbeat producer (0x1017) and the EMCY producer; it neither sends TPDOs on
SYNC nor copies received RPDOs into the dictionary, so this module does both. Its callbacks run
on python-can's Notifier thread and only queue what came (the RPDOs since the last SYNC, the
SYNC); everything else happens in the runner's thread, in :meth:`CanDrive.step`.

One drive period (the device's :meth:`~.device.Cia402Device.command` and ``settle``):

1. the RPDO received before the period's SYNC is copied into the dictionary (controlword 0x6040,
   target velocity 0x60FF); two RPDOs within one SYNC period = two masters -> EMCY 0x8200
   (protocol error, manufacturer bytes ``b'2MSTR'``) and a fault; no RPDO for longer than the
   RPDO event timer (0x1400 sub 5, ms, counted in periods of 0x1006) -> EMCY 0x8250 (RPDO
   timeout) and a fault (fault reaction: quick-stop braking, then Fault);
2. the CiA 402 state machine makes at most one transition; in Operation enabled (CSV 9, or
   profile velocity 3) the target velocity is the period's velocity command, otherwise the axis
   brakes at its deceleration limit (:meth:`quick_stop`);
3. the TPDOs mapped with a synchronous transmission type (1..240: every n-th SYNC) carry the
   period's statusword, position actual (0x6064, the encoder in increments), velocity actual
   (0x606C, the encoder's difference over the period) and the capacitive sensor's reading on the
   analog input 0x6401 sub 1 (counts, ``AnalogScale``): one sample-synchronous pair per SYNC.

**Lock step** (``lockstep=True``): the drive advances exactly one period per SYNC. Step k sends
the TPDOs of sample k, then waits for SYNC k+1 and applies the RPDO sent before it over the
period [k, k+1): the command answering sample k acts on period k, the headless runner's
convention, so a run is independent of load (no own clock; no SYNC for ``lockstep_timeout_s``
of wall time -> :class:`LockstepAbort`). **Free-running**: the drive moves by its own clock as a
drive does, one period per ``h_s`` of wall time whether SYNCs come or not (a dead master: the
RPDO deadline stops the axis); each SYNC is answered at once, on the notifier thread, with the
sample latched at the latest period (its TPDO data prepared by the runner's thread), and the
RPDO received before it takes effect at the next period (one period of transport delay).

Scenario events on a drive: ``drive`` with ``fault: true`` -> EMCY 0x5000 (device hardware) and
the fault reaction; ``enabled: false`` -> the drive cannot leave Switch on disabled (its enable
input is off). A ``sensor_dropout`` reads the analog input's out-of-range count (the amplifier's
output without a sensor: ``valid`` false); an ``encoder_dropout`` holds position actual (the
drive latches the last count it had).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from importlib import resources
import logging
import math
from pathlib import Path
import threading
import time
import types
from typing import Any, Callable

import canopen
from canopen.sdo import SdoAbortedError
from ladrc_cia402 import mapping
from ladrc_cia402.ds402 import (
    CONTROLWORD,
    MODES_OF_OPERATION,
    MODES_OF_OPERATION_DISPLAY,
    QUICK_STOP_OPTION_CODE,
    STATUSWORD,
    State,
)
from ladrc_cia402.emcy import (
    ERROR_CODE,
    ERROR_REGISTER,
    REG_COMMUNICATION,
)
from ladrc_cia402.units import AnalogScale, DriveUnits

from .device import Cia402Device

log = logging.getLogger('ladrc_sim.cia402')

COMM_CYCLE = 0x1006
POSITION_ACTUAL, VELOCITY_ACTUAL, TARGET_VELOCITY = 0x6064, 0x606C, 0x60FF
ANALOG_INPUT = 0x6401
EMCY_RPDO_TIMEOUT = 0x8250
EMCY_PDO_LENGTH = 0x8210
EMCY_PROTOCOL = 0x8200
EMCY_SOFTWARE = 0x6000
EMCY_HARDWARE = 0x5000
EMCY_BUS_LOST = 0x8140  # CAN: bus off (the drive lost its bus)
SDO_VALUE_RANGE = 0x06090030
TWO_MASTERS = b'2MSTR'
FIRST_SYNC_S = 90.0  # lock step: the wait for the first SYNC (a master configuring, starting)


class LockstepAbort(Exception):
    """Lock step: no SYNC within ``lockstep_timeout_s`` of wall time (one line)."""


class StopDrive(Exception):
    """Raised inside the runner's loop to end the run (the process is asked to stop)."""


def default_eds() -> Path:
    """Return the path of the shipped EDS of the emulated drive."""
    return Path(str(resources.files('ladrc_sim.cia402') / 'ladrc_z_drive.eds'))


def bus_kwargs(url: str) -> dict[str, str]:
    """``can.Bus`` arguments for ``url``: ``ws://host:port/`` (python-can-remote) or a channel."""
    if url.startswith(('ws://', 'wss://')):
        return {'channel': url, 'interface': 'remote'}
    return {'channel': url, 'interface': 'socketcan'}


def software_periodic(network: canopen.Network) -> None:
    """Send the bus's periodic messages (canopen's heartbeat) from a python-can thread.

    python-can-remote 0.3.0's own periodic task is broken: its ``modify_data`` calls
    ``super(self)`` (TypeError), which canopen's heartbeat hits at every NMT state change, and
    the stop that precedes it leaves the server without the task, so a second stop (at
    shutdown) raises KeyError in the server, which closes the client's websocket (status 1011,
    reason 1797 = the heartbeat's COB-ID 0x705). python-can's own software task (a thread
    sending through ``bus.send``) has none of this; it sends under canopen's send lock, so its
    frames never interleave with the TPDOs on the websocket.
    """
    import can
    bus = network.bus
    bus._lock_send_periodic = network.send_lock
    bus._send_periodic_internal = types.MethodType(can.BusABC._send_periodic_internal, bus)


def connect(url: str) -> canopen.Network:
    """Return a canopen network on the bus ``url`` (the remote bus's periodic sends fixed)."""
    network = canopen.Network()
    network.connect(**bus_kwargs(url))
    if bus_kwargs(url)['interface'] == 'remote':
        software_periodic(network)
    return network


@dataclass
class _Sync:
    """One SYNC as the notifier thread saw it: the RPDOs received since the previous one."""

    rpdos: list[tuple[int, bytes]]


class CanDrive:
    """One emulated CiA 402 drive on a canopen network; a controller of the headless runner."""

    def __init__(self, network: canopen.Network, node_id: int, eds: Path | str | None = None,
                 *, lockstep: bool = True, units: DriveUnits | None = None,
                 analog: AnalogScale | None = None, lockstep_timeout_s: float = 10.0,
                 on_sample: Callable[[int, Any], None] | None = None,
                 h_s: float | None = None) -> None:
        """Load the dictionary from ``eds``; subscribe to SYNC.

        ``on_sample(k, tick)``: called as sample k's TPDOs go out (the sim node's truth);
        ``h_s``: the world's period, the drive's 0x1006 (default: the EDS's).
        """
        self.network = network
        self.node = canopen.LocalNode(node_id, canopen.import_od(str(eds or default_eds()),
                                                                 node_id))
        self.node_id = node_id
        self.lockstep = lockstep
        self.units = units or DriveUnits()
        self.analog = analog or AnalogScale()
        self.lockstep_timeout_ns = int(lockstep_timeout_s * 1e9)
        self.on_sample = on_sample
        if h_s is not None:
            self._store(COMM_CYCLE, 0, int(round(h_s * 1e6)))
        self.h_s = self._raw(COMM_CYCLE) * 1e-6
        self.device = Cia402Device(_NoPlant(), self.units,
                                   quick_stop_option=self._raw(QUICK_STOP_OPTION_CODE))
        self.node.add_read_callback(self._on_read)
        self.node.add_write_callback(self._on_write)
        network.add_node(self.node)
        self._maps_dirty = True
        self._rpdos: list[tuple[int, tuple[mapping.Entry, ...]]] = []
        self._tpdos: list[tuple[int, int, tuple[mapping.Entry, ...]]] = []
        # notifier thread -> runner thread
        self._cv = threading.Condition()
        self._pending: list[tuple[int, bytes]] = []  # RPDOs since the last SYNC
        self._syncs: deque[_Sync] = deque()
        self._tx: list[tuple[int, int, bytes]] = []  # free-running: the TPDOs for the next SYNC
        self.syncs_received = 0
        self.syncs_answered = 0
        # the drive's cycle (runner thread)
        self.running = True
        self.seq = 0  # samples sent (= periods stepped)
        self._started = False
        self.t_start_ns = 0
        self._periods_without_rpdo = 0
        self._deadline_periods = 0  # 0: no deadline
        self._armed = False  # the deadline runs from the first RPDO on
        self._timed_out = False
        self._braking = True  # not in Operation enabled: the runner brakes the axis
        self._prev_enc = math.nan
        self._held_enc = math.nan
        self._scenario_fault = False
        self.command_mm_s = 0.0
        self.late_periods = 0
        network.subscribe(mapping.SYNC_COB_ID, self._on_sync)

    # ---- the dictionary -----------------------------------------------------------------
    def _raw(self, index: int, sub: int = 0) -> int:
        obj = self.node.object_dictionary[index]
        if not isinstance(obj, canopen.objectdictionary.ODVariable):
            obj = obj[sub]
        return obj.decode_raw(self.node.get_data(index, sub))

    def _store(self, index: int, sub: int, value: int) -> None:
        obj = self.node.object_dictionary[index]
        if not isinstance(obj, canopen.objectdictionary.ODVariable):
            obj = obj[sub]
        self.node.data_store.setdefault(index, {})[sub] = obj.encode_raw(value)

    def _on_read(self, index: int, subindex: int, od: Any) -> int | None:
        d = self.device
        if index == STATUSWORD:
            return d.statusword
        if index == MODES_OF_OPERATION_DISPLAY:
            return d.mode_display
        if index == ERROR_CODE:
            return d.error_code
        return None

    def _on_write(self, index: int, subindex: int, od: Any, data: bytes) -> None:
        value = od.decode_raw(data)
        if index == MODES_OF_OPERATION:
            try:
                self.device.set_mode(value)
            except ValueError:
                raise SdoAbortedError(SDO_VALUE_RANGE) from None
        elif index == QUICK_STOP_OPTION_CODE:
            self.device.quick_stop_option = value
        elif index == COMM_CYCLE:
            # the world runs at its runner's period: the drive takes its own value, no other
            if value <= 0 or abs(value * 1e-6 - self.h_s) > 1e-9:
                raise SdoAbortedError(SDO_VALUE_RANGE)
        elif 0x1400 <= index <= 0x1BFF:
            self._maps_dirty = True

    # ---- PDOs -----------------------------------------------------------------------------
    def _read_maps(self) -> None:
        """Build the RPDO / TPDO tables from the dictionary (as the master configured it)."""
        for cob, _entries in self._rpdos:
            self.network.unsubscribe(cob, self._on_rpdo)
        rpdos, tpdos = [], []
        od = self.node.object_dictionary
        for comm, mp, out in ((mapping.RPDO_COMM, mapping.RPDO_MAP, rpdos),
                              (mapping.TPDO_COMM, mapping.TPDO_MAP, tpdos)):
            for k in range(4):
                if comm + k not in od:
                    continue
                cob = self._raw(comm + k, 1)
                if cob & mapping.COB_ID_INVALID:
                    continue
                entries = []
                for s in range(1, self._raw(mp + k, 0) + 1):
                    index, sub, bits = mapping.decode_entry(self._raw(mp + k, s))
                    obj = od[index] if sub == 0 and index in od else od[index][sub]
                    signed = obj.data_type in (canopen.objectdictionary.INTEGER8,
                                               canopen.objectdictionary.INTEGER16,
                                               canopen.objectdictionary.INTEGER32)
                    entries.append(mapping.Entry(index, sub, bits, signed, obj.name))
                if comm == mapping.RPDO_COMM:
                    out.append((cob & 0x7FF, tuple(entries)))
                    if k == 0:
                        ms = self._raw(comm, 5)
                        self._deadline_periods = (
                            max(1, math.ceil(ms * 1e-3 / self.h_s - 1e-9)) if ms else 0)
                else:
                    tt = self._raw(comm + k, 2)
                    if 1 <= tt <= 240:
                        out.append((cob & 0x7FF, tt, tuple(entries)))
        self._rpdos, self._tpdos = rpdos, tpdos
        for cob, _entries in self._rpdos:
            self.network.subscribe(cob, self._on_rpdo)
        self._maps_dirty = False

    # ---- notifier thread: queue what came ---------------------------------------------------
    def _on_rpdo(self, can_id: int, data: bytes, timestamp: float) -> None:
        if self.node.nmt.state != 'OPERATIONAL':
            return
        with self._cv:
            self._pending.append((can_id, bytes(data)))

    def _on_sync(self, can_id: int, data: bytes, timestamp: float) -> None:
        with self._cv:
            self._syncs.append(_Sync(self._pending))
            self._pending = []
            self.syncs_received += 1
            tx = self._tx
            self._cv.notify_all()
        if not self.lockstep and tx and self.node.nmt.state == 'OPERATIONAL':
            # free-running: the SYNC is answered at once with the latest period's sample
            for cob, _tt, data_out in tx:
                self._send(cob, data_out)
            self.syncs_answered += 1

    # ---- the runner's controller ----------------------------------------------------------
    def command(self, name: str, **kwargs: Any) -> None:
        """Take a scenario's follow command: a drive has no controller to give it to."""

    def drive_event(self, enabled: bool = True, fault: bool = False, error_code: int = 0
                    ) -> None:
        """Take a scenario's ``drive`` event: a fault raises ``error_code`` (0: 0x5000)."""
        if fault:
            self._event_code = error_code or EMCY_HARDWARE

    def quick_stop(self) -> bool:
        """Return True while the drive does not drive the axis (the runner brakes it at a_max)."""
        return self._braking

    def boot(self) -> None:
        """Boot-up: the boot-up message, then pre-operational (the heartbeat starts)."""
        self.node.nmt.state = 'INITIALISING'
        self.node.nmt.state = 'PRE-OPERATIONAL'

    def step(self, tick: Any) -> float:
        """One drive period of the runner (module docstring): the velocity for [t, t + h)."""
        if not self._started:
            self._start()
        if self.lockstep:
            return self._step_lockstep(tick)
        return self._step_free(tick)

    def _start(self) -> None:
        self._started = True
        self.t_start_ns = time.monotonic_ns()

    def _step_lockstep(self, tick: Any) -> float:
        if self.seq == 0:
            self._period(tick, [self._wait_sync()])  # SYNC 0: the first controlword
        values = self._sample_values(tick)
        if self.node.nmt.state == 'OPERATIONAL':
            for cob, tt, entries in self._tpdo_table():
                if (self.seq + 1) % tt == 0:
                    self._send(cob, mapping.pack(entries, self._pick(entries, values)))
        if self.on_sample is not None:
            self.on_sample(self.seq, tick)
        self.seq += 1
        return self._period(tick, [self._wait_sync()])

    def _step_free(self, tick: Any) -> float:
        period_ns = int(round(self.h_s * 1e9))
        due = self.t_start_ns + self.seq * period_ns
        now = time.monotonic_ns()
        while now < due and self.running:
            time.sleep((due - now) * 1e-9)
            now = time.monotonic_ns()
        if now - due > period_ns:
            self.late_periods += 1  # caught up: the drive's clock keeps wall time
        if not self.running:
            raise StopDrive()
        values = self._sample_values(tick)
        if self.node.nmt.state == 'OPERATIONAL':
            table = self._tpdo_table()
            tx = [(cob, tt, mapping.pack(entries, self._pick(entries, values)))
                  for cob, tt, entries in table]
            with self._cv:
                self._tx = tx
        if self.on_sample is not None:
            self.on_sample(self.seq, tick)
        self.seq += 1
        with self._cv:  # the SYNCs since the last period (none: the master is silent)
            syncs, self._syncs = list(self._syncs), deque()
        return self._period(tick, syncs)

    def _send(self, cob: int, data: bytes) -> None:
        """Put a frame on the bus; a bus that is gone faults the drive, which runs on."""
        if self.bus_lost:
            return
        try:
            self.network.send_message(cob, data)
        except Exception as exc:  # noqa: BLE001 -- a drive keeps its own clock without a bus
            self._lost(exc)

    def _lost(self, exc: BaseException) -> None:
        """Fault the drive: the bus is gone (its server closed the connection)."""
        self.bus_lost = f'{type(exc).__name__}: {exc}'
        log.warning('CAN bus lost (%s): drive fault, quick-stop braking', self.bus_lost)
        self.device.fault(EMCY_BUS_LOST, REG_COMMUNICATION)

    bus_lost = ''

    def _tpdo_table(self) -> list[tuple[int, int, tuple[mapping.Entry, ...]]]:
        if self._maps_dirty:
            self._read_maps()
        return self._tpdos

    def _wait_sync(self) -> _Sync:
        # the first SYNC comes once the driver has configured the drive and found its
        # controller (its wait_for_controller_s, 60 s): waited for that long at least
        first = self.seq == 0 and not self._syncs_seen
        self._syncs_seen = True
        limit = time.monotonic_ns() + max(self.lockstep_timeout_ns,
                                          int(FIRST_SYNC_S * 1e9) if first else 0)
        with self._cv:
            while not self._syncs:
                if not self.running:
                    raise StopDrive()
                left = limit - time.monotonic_ns()
                if left <= 0:
                    raise LockstepAbort(f'lock step: no SYNC for '
                                        f'{self.lockstep_timeout_ns * 1e-9:g} s at period '
                                        f'{self.seq} (the master stopped?)')
                self._cv.wait(min(left * 1e-9, 0.05))
            return self._syncs.popleft()

    def _sample_values(self, tick: Any) -> dict[tuple[int, int], int]:
        """Return the TPDO objects of the sample at ``tick`` (statusword as of this period)."""
        enc = tick.encoder_mm
        if tick.encoder_stamp_s != tick.t_s and not math.isnan(self._held_enc):
            enc = self._held_enc  # encoder dropout: the last count latched
        self._held_enc = enc
        velocity = 0.0
        if not math.isnan(self._prev_enc) and not math.isnan(enc):
            velocity = (enc - self._prev_enc) / self.h_s
        self._prev_enc = enc
        self._velocity_mm_s = velocity
        fresh_gap = tick.gap_stamp_s == tick.t_s  # a sensor dropout: out of range
        counts = self.analog.counts(float(tick.gap_mm), bool(tick.gap_valid) and fresh_gap,
                                    contact=fresh_gap and tick.gap_status == 2)
        d = self.device
        return {(STATUSWORD, 0): d.statusword,
                (POSITION_ACTUAL, 0): (self.units.position_increments(enc)
                                       if not math.isnan(enc) else 0),
                (VELOCITY_ACTUAL, 0): self.units.velocity_units(velocity),
                (ANALOG_INPUT, 1): counts,
                (MODES_OF_OPERATION_DISPLAY, 0): d.mode_display,
                (ERROR_CODE, 0): d.error_code}

    def _pick(self, entries: tuple[mapping.Entry, ...], values: dict) -> tuple[int, ...]:
        return tuple(values[(e.index, e.subindex)] if (e.index, e.subindex) in values
                     else self._raw(e.index, e.subindex) for e in entries)

    def _period(self, tick: Any, syncs: list[_Sync]) -> float:
        """Apply the RPDOs of the SYNCs since the last period; return the period's velocity.

        No SYNC since the last period: a period by the drive's own clock.
        """
        d = self.device
        if self._maps_dirty:
            self._read_maps()
        operational = self.node.nmt.state == 'OPERATIONAL'
        frames = [f for sync in syncs for f in sync.rpdos] if operational else []
        got_rpdo = bool(frames)
        if any(len(sync.rpdos) > 1 for sync in syncs) and operational:
            d.fault(EMCY_PROTOCOL, REG_COMMUNICATION, TWO_MASTERS)
        if frames:
            tables = dict(self._rpdos)
            for can_id, raw in frames:
                entries = tables.get(can_id)
                if entries is None:
                    continue
                if len(raw) != mapping.size(entries):
                    d.fault(EMCY_PDO_LENGTH, REG_COMMUNICATION | 1)
                    continue
                for e, v in zip(entries, mapping.unpack(entries, raw), strict=True):
                    self._store(e.index, e.subindex, v)
        if operational:
            if got_rpdo:
                self._periods_without_rpdo = 0
                self._armed = True
                self._timed_out = False
            elif self._armed:
                self._periods_without_rpdo += 1
                if (self._deadline_periods and not self._timed_out
                        and self._periods_without_rpdo >= self._deadline_periods):
                    self._timed_out = True
                    d.fault(EMCY_RPDO_TIMEOUT, REG_COMMUNICATION)
        if tick.drive_fault and not self._scenario_fault:
            d.fault(self._event_code)  # the scenario's drive fault
        self._scenario_fault = bool(tick.drive_fault)
        cw = self._raw(CONTROLWORD)
        if not tick.drive_enabled and d.state is State.SWITCH_ON_DISABLED:
            cw = 0  # the enable input is off: no shutdown command takes effect
        cmd = d.command(cw, self._raw(TARGET_VELOCITY))
        d.settle(self._velocity_mm_s == 0.0)
        for e in d.events:
            if not self.bus_lost:
                try:
                    self.node.emcy.send(e.code, e.register, e.manufacturer)
                except Exception as exc:  # noqa: BLE001 -- the bus is gone: keep running
                    self._lost(exc)
            self._store(ERROR_CODE, 0, d.error_code)
            self._store(ERROR_REGISTER, 0, e.register if e.code else 0)
        d.events.clear()
        self._braking = cmd is None
        self.command_mm_s = 0.0 if cmd is None else cmd
        return self.command_mm_s

    _velocity_mm_s = 0.0
    _event_code = EMCY_HARDWARE
    _syncs_seen = False


class _NoPlant:
    """The device's plant when the runner moves the axis (the device never steps it)."""

    position_mm = 0.0
    velocity_mm_s = 0.0

    def step(self, cmd_mm_s: float, enabled: bool = True, fault: bool = False
             ) -> tuple[float, float]:
        raise RuntimeError('the runner moves the axis of an emulated drive')
