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
from dataclasses import dataclass, replace
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
from ladrc_cia402 import (
    ERROR_REGISTER,
    QUICK_STOP_OPTION_CODE,
    REG_COMMUNICATION,
    AnalogScale,
    DeviceFile,
    DriveUnits,
    State,
    entry_range,
    load_device,
    make_plan,
    mapping,
)

from .device import Cia402Device

log = logging.getLogger('ladrc_sim.cia402')

COMM_CYCLE = 0x1006
HEARTBEAT_CONSUMER = 0x1016
SUPPORTED_MODES = 0x6502
EMCY_HEARTBEAT = 0x8130  # life guard / heartbeat error
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


def default_device() -> Path:
    """Return the path of the shipped device file of the emulated drive (its EDS beside it)."""
    return Path(str(resources.files('ladrc_sim.cia402') / 'ladrc_z_drive.yaml'))


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

    def __init__(self, network: canopen.Network, node_id: int | None = None,
                 eds: Path | str | None = None, *, lockstep: bool = True,
                 units: DriveUnits | None = None, analog: AnalogScale | None = None,
                 lockstep_timeout_s: float = 10.0,
                 on_sample: Callable[[int, Any], None] | None = None,
                 h_s: float | None = None, device: Path | str | DeviceFile | None = None
                 ) -> None:
        """Load the dictionary of the device file's EDS (``eds`` instead, if given); SYNC.

        ``device``: the device file (default: the shipped one): the objects by role, the
        units, the gap's object and scale, and where the gap is on a CiA 401 I/O node, that
        node too (emulated here, its TPDO on the same SYNC). ``node_id``: the device file's
        unless given. ``on_sample(k, tick)``: called as sample k's TPDOs go out (the sim
        node's truth); ``h_s``: the world's period, the drive's 0x1006 (default: the EDS's).
        """
        self.network = network
        dev = device if isinstance(device, DeviceFile) else load_device(
            device or default_device())
        if node_id is not None:
            dev = replace(dev, node_id=node_id)
        if eds:
            dev = replace(dev, dcf=str(Path(eds).resolve()))
        self.plan = make_plan(dev, h_s or 0.0005)
        self.roles = self.plan.roles
        node_id = dev.node_id
        self.node = canopen.LocalNode(node_id, canopen.import_od(self.plan.eds_path, node_id))
        self.io = None
        if self.plan.io_node_id:
            self.io = canopen.LocalNode(self.plan.io_node_id, self.plan.io_od)
            network.add_node(self.io)
        self.node_id = node_id
        self.lockstep = lockstep
        self.units = units or self.plan.units
        self.analog = analog or self.plan.analog
        self.lockstep_timeout_ns = int(lockstep_timeout_s * 1e9)
        self.on_sample = on_sample
        self._hb_time_s = 0.0  # heartbeat consumer time (0x1016:01; 0: not watched)
        self._hb_cob = 0
        self._hb_last = 0.0
        self.heartbeats = 0
        od = self.node.object_dictionary
        if COMM_CYCLE in od:
            if h_s is not None:
                self._store(COMM_CYCLE, 0, int(round(h_s * 1e6)))
            self.h_s = self._raw(COMM_CYCLE) * 1e-6
        else:  # a drive without 0x1006: its period is the world's
            self.h_s = h_s if h_s is not None else 0.0005
        qso = self._raw(QUICK_STOP_OPTION_CODE) if QUICK_STOP_OPTION_CODE in od else 2
        # the drive's own limit: 200 mm/s in its units (the axis model limits it too)
        self.device = Cia402Device(_NoPlant(), self.units, quick_stop_option=qso,
                                   max_velocity_units=max(1, int(
                                       200.0 * self.units.velocity_units_per_mm_s)))
        self.supported_modes = 0
        if SUPPORTED_MODES in od:
            dflt = od[SUPPORTED_MODES].default
            # an EDS without a value: the drive's own answer (CSV and profile velocity)
            self.supported_modes = dflt if isinstance(dflt, int) and dflt else 0x104
        self.node.add_read_callback(self._on_read)
        self.node.add_write_callback(self._on_write)
        network.add_node(self.node)
        self._maps_dirty = True
        self._rpdos: list[tuple[int, tuple[mapping.Entry, ...]]] = []
        self._tpdos: list[tuple[int, int, tuple[mapping.Entry, ...]]] = []
        self._io_tpdos: list[tuple[int, int, tuple[mapping.Entry, ...]]] = []
        if self.io is not None:
            self.io.add_write_callback(self._on_io_write)
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
        return _raw(self.node, index, sub)

    def _store(self, index: int, sub: int, value: int) -> None:
        obj = self.node.object_dictionary[index]
        if not isinstance(obj, canopen.objectdictionary.ODVariable):
            obj = obj[sub]
        self.node.data_store.setdefault(index, {})[sub] = obj.encode_raw(value)

    def _role(self, role: str) -> tuple[int, int]:
        e = self.roles[role]
        return e.index, e.subindex

    def _on_read(self, index: int, subindex: int, od: Any) -> int | None:
        d = self.device
        key = (index, subindex)
        if key == self._role('statusword'):
            return d.statusword
        if key == self._role('modes_of_operation_display'):
            return d.mode_display
        if key == self._role('error_code'):
            return d.error_code
        if index == SUPPORTED_MODES:
            return self.supported_modes
        return None

    def _on_write(self, index: int, subindex: int, od: Any, data: bytes) -> None:
        value = od.decode_raw(data)
        if (index, subindex) == self._role('modes_of_operation'):
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
        elif index == HEARTBEAT_CONSUMER and subindex == 1:
            self._watch_heartbeat(value)
        elif 0x1400 <= index <= 0x1BFF:
            self._maps_dirty = True

    def _on_io_write(self, index: int, subindex: int, od: Any, data: bytes) -> None:
        if 0x1800 <= index <= 0x1BFF:
            self._maps_dirty = True

    # ---- the heartbeat consumer (0x1016:01: producer node << 16 | time ms) -------------
    def _watch_heartbeat(self, value: int) -> None:
        if self._hb_cob:
            self.network.unsubscribe(self._hb_cob, self._on_heartbeat)
        producer, ms = (value >> 16) & 0x7F, value & 0xFFFF
        self._hb_time_s = ms * 1e-3 if producer and ms else 0.0
        self._hb_cob = 0x700 + producer if self._hb_time_s else 0
        self._hb_last = 0.0  # armed by the first heartbeat
        if self._hb_cob:
            self.network.subscribe(self._hb_cob, self._on_heartbeat)

    def _on_heartbeat(self, can_id: int, data: bytes, timestamp: float) -> None:
        self._hb_last = time.monotonic()
        self.heartbeats += 1

    def heartbeat_lost(self) -> bool:
        """Whether the watched producer's heartbeat is older than the consumer time."""
        return bool(self._hb_time_s and self._hb_last
                    and time.monotonic() - self._hb_last > self._hb_time_s)

    # ---- PDOs -----------------------------------------------------------------------------
    def _maps_of(self, node: canopen.LocalNode, rpdos: list, tpdos: list, drive: bool) -> None:
        od = node.object_dictionary
        for comm, mp, out in ((mapping.RPDO_COMM, mapping.RPDO_MAP, rpdos),
                              (mapping.TPDO_COMM, mapping.TPDO_MAP, tpdos)):
            for k in range(4):
                if comm + k not in od or mp + k not in od:
                    continue
                cob = _raw(node, comm + k, 1)
                if cob & mapping.COB_ID_INVALID:
                    continue
                entries = []
                for s in range(1, _raw(node, mp + k, 0) + 1):
                    index, sub, bits = mapping.decode_entry(_raw(node, mp + k, s))
                    if index not in od:
                        break  # a mapping of no object of this node: not a valid PDO
                    obj = od[index]
                    if not isinstance(obj, canopen.objectdictionary.ODVariable):
                        if sub not in obj:
                            break
                        obj = obj[sub]
                    signed = obj.data_type in (canopen.objectdictionary.INTEGER8,
                                               canopen.objectdictionary.INTEGER16,
                                               canopen.objectdictionary.INTEGER32)
                    role = next((r for r, e in self.roles.items()
                                 if (e.index, e.subindex) == (index, sub)), obj.name)
                    if role == 'velocity_actual':
                        signed = self.roles[role].signed  # the device file's reading of it
                    entries.append(mapping.Entry(index, sub, bits, signed, role))
                if len(entries) != _raw(node, mp + k, 0):
                    continue
                if comm == mapping.RPDO_COMM:
                    out.append((cob & 0x7FF, tuple(entries)))
                    if k == 0 and drive:
                        ms = _raw(node, comm, 5) if 5 in od[comm] else 0
                        self._deadline_periods = (
                            max(1, math.ceil(ms * 1e-3 / self.h_s - 1e-9)) if ms else 0)
                else:
                    tt = _raw(node, comm + k, 2)
                    if 1 <= tt <= 240:
                        out.append((cob & 0x7FF, tt, tuple(entries)))

    def _read_maps(self) -> None:
        """Build the RPDO / TPDO tables from the dictionaries (as the master configured them)."""
        for cob, _entries in self._rpdos:
            self.network.unsubscribe(cob, self._on_rpdo)
        rpdos: list = []
        tpdos: list = []
        self._maps_of(self.node, rpdos, tpdos, True)
        io_tpdos: list = []
        if self.io is not None:
            self._maps_of(self.io, [], io_tpdos, False)
        self._rpdos, self._tpdos, self._io_tpdos = rpdos, tpdos, io_tpdos
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
        if not self.lockstep and tx:
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
        table = list(self._tpdos) if self.node.nmt.state == 'OPERATIONAL' else []
        if self.io is not None and self.io.nmt.state == 'OPERATIONAL':
            table += self._io_tpdos  # the I/O node samples its input on the same SYNC
        return table

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
        values = {'statusword': d.statusword,
                  'position_actual': (self.units.position_increments(enc)
                                      if not math.isnan(enc) else 0),
                  'velocity_actual': self.units.velocity_units(velocity),
                  'modes_of_operation_display': d.mode_display,
                  'error_code': d.error_code}
        if 'gap' in self.roles:
            values['gap'] = counts
        return {self._role(r): v for r, v in values.items()}

    def _pick(self, entries: tuple[mapping.Entry, ...], values: dict) -> tuple[int, ...]:
        out = []
        for e in entries:
            v = (values[(e.index, e.subindex)] if (e.index, e.subindex) in values
                 else self._raw(e.index, e.subindex))
            lo, hi = entry_range(e)
            out.append(max(lo, min(hi, v)))  # the object's data type (a 16-bit unit saturates)
        return tuple(out)

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
        if not self.lockstep and self.heartbeat_lost() and not self._hb_timed_out:
            self._hb_timed_out = True  # the master's heartbeat is gone: fault reaction
            d.fault(EMCY_HEARTBEAT, REG_COMMUNICATION)
        elif self._hb_timed_out and not self.heartbeat_lost():
            self._hb_timed_out = False
        if tick.drive_fault and not self._scenario_fault:
            d.fault(self._event_code)  # the scenario's drive fault
        self._scenario_fault = bool(tick.drive_fault)
        cw = self._raw(*self._role('controlword'))
        if not tick.drive_enabled and d.state is State.SWITCH_ON_DISABLED:
            cw = 0  # the enable input is off: no shutdown command takes effect
        cmd = d.command(cw, self._raw(*self._role('target_velocity')))
        d.settle(self._velocity_mm_s == 0.0)
        for e in d.events:
            if not self.bus_lost:
                try:
                    self.node.emcy.send(e.code, e.register, e.manufacturer)
                except Exception as exc:  # noqa: BLE001 -- the bus is gone: keep running
                    self._lost(exc)
            self._store(*self._role('error_code'), d.error_code)
            self._store(ERROR_REGISTER, 0, e.register if e.code else 0)
        d.events.clear()
        self._braking = cmd is None
        self.command_mm_s = 0.0 if cmd is None else cmd
        return self.command_mm_s

    _velocity_mm_s = 0.0
    _hb_timed_out = False
    _event_code = EMCY_HARDWARE
    _syncs_seen = False


def _raw(node: canopen.LocalNode, index: int, sub: int = 0) -> int:
    obj = node.object_dictionary[index]
    if not isinstance(obj, canopen.objectdictionary.ODVariable):
        obj = obj[sub]
    return obj.decode_raw(node.get_data(index, sub))


class _NoPlant:
    """The device's plant when the runner moves the axis (the device never steps it)."""

    position_mm = 0.0
    velocity_mm_s = 0.0

    def step(self, cmd_mm_s: float, enabled: bool = True, fault: bool = False
             ) -> tuple[float, float]:
        raise RuntimeError('the runner moves the axis of an emulated drive')
