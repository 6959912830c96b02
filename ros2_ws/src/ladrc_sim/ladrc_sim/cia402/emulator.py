"""The emulated CiA 402 Z drive: the simulator's axis, sheet and sensor behind a CANopen node.

    python -m ladrc_sim.cia402.emulator --bus ws://127.0.0.1:PORT/ --node-id 5 [--eds PATH]
        [--scenario NAME]

A ``canopen.LocalNode`` built from the EDS (default: the shipped ``ladrc_z_drive.eds``) on a
python-can bus (a ``ws://`` URL: python-can-remote; otherwise a socketcan channel such as
``can0``). canopen gives the SDO server (the master writes the PDO mapping, 0x6060 ... by SDO),
the heartbeat producer (0x1017) and the EMCY producer; it does not send TPDOs on SYNC nor copy
received RPDOs into the dictionary, so this module does both, on the SYNC callback:

1. the RPDO received since the last SYNC is copied into the dictionary (a synchronous RPDO takes
   effect at the SYNC after it); none for longer than the RPDO event timer (0x1400 sub 5, ms,
   counted in SYNC periods of 0x1006) -> EMCY 0x8250 (RPDO timeout) and a fault (fault reaction:
   quick-stop braking, then Fault); two RPDOs within one SYNC period = two masters -> EMCY
   0x8200 (protocol error, manufacturer bytes ``b'2MSTR'``) and the same fault;
2. the drive advances exactly one period of ``h_s`` = 0x1006 (lock step: the drive moves by
   SYNCs, so a master that waits for the TPDOs before the next SYNC makes a run independent of
   load): :class:`~.device.Cia402Device` over the scenario's axis model
   (``ladrc_sim.models.axis.Axis``), the sheet below it and the capacitive sensor
   (``ladrc_sim.models.sensor.Sensor``, drawn by the headless runner's ``draw_world``);
3. the TPDOs mapped with a synchronous transmission type (1..240: every n-th SYNC) are sent:
   statusword, position actual, velocity actual, the sensor's reading on 0x6401 sub 1 (counts,
   ``AnalogScale``).

All callbacks run on python-can's Notifier thread (one thread: no locks needed); an exception
in one is logged by python-can and would be lost, so the SYNC handler catches, logs and faults
the drive (EMCY 0x6000 device software). The world's tick index is the number of SYNCs since
start; past the scenario's end the world holds its last tick.
"""

from __future__ import annotations

import argparse
from importlib import resources
import logging
import math
from pathlib import Path
import signal
import sys
import threading
import types
from typing import Any

import canopen
from canopen.sdo import SdoAbortedError
from ladrc_cia402 import mapping
from ladrc_cia402.ds402 import (
    CONTROLWORD,
    MODES_OF_OPERATION,
    MODES_OF_OPERATION_DISPLAY,
    QUICK_STOP_OPTION_CODE,
    STATUSWORD,
)
from ladrc_cia402.emcy import (
    ERROR_CODE,
    ERROR_REGISTER,
    REG_COMMUNICATION,
)
from ladrc_cia402.units import AnalogScale, DriveUnits

from ..headless.runner import draw_world
from ..headless.scenario import load_scenario
from ..models.axis import Axis
from .device import Cia402Device

log = logging.getLogger('ladrc_sim.cia402.emulator')

COMM_CYCLE = 0x1006
POSITION_ACTUAL, VELOCITY_ACTUAL, TARGET_VELOCITY = 0x6064, 0x606C, 0x60FF
ANALOG_INPUT = 0x6401
EMCY_RPDO_TIMEOUT = 0x8250
EMCY_PDO_LENGTH = 0x8210
EMCY_PROTOCOL = 0x8200
EMCY_SOFTWARE = 0x6000
SDO_VALUE_RANGE = 0x06090030
SDO_STATE = 0x08000022  # data cannot be transferred because of the present device state


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


class World:
    """The scenario's axis, sheet and sensor at the drive's period ``h_s``."""

    def __init__(self, scenario: str, h_s: float):
        sc = load_scenario(scenario)
        self.h_s = h_s
        self.n = max(1, int(round(sc.duration_s / h_s)))
        self.sheet, self.sensor = draw_world(sc, self.n, h_s)
        self.axis = Axis(sc.axis, self.sheet.height_mm(0) + sc.initial_gap_mm, h_s)
        self.i = 0

    def sample(self) -> tuple[float, bool]:
        """Return the reading at the current tick, ``(mm, valid)``; then the sheet moves on."""
        i = min(self.i, self.n - 1)
        gap = self.axis.position_mm - self.sheet.height_mm(i)
        reading, valid, _collision = self.sensor.measure(i, gap, 1.0)
        if self.sheet.plate is not None:
            self.sheet.plate.step(gap)
        self.i += 1
        return reading, valid


class Emulator:
    """One emulated drive on a canopen network (see the module docstring)."""

    def __init__(self, network: canopen.Network, node_id: int, eds: Path | str,
                 scenario: str = 'step', units: DriveUnits | None = None,
                 analog: AnalogScale | None = None):
        self.network = network
        self.node = canopen.LocalNode(node_id, canopen.import_od(str(eds), node_id))
        self.node_id = node_id
        self.scenario = scenario
        self.units = units or DriveUnits()
        self.analog = analog or AnalogScale()
        self.h_s = self._raw(COMM_CYCLE) * 1e-6
        self._new_world()
        self.node.add_read_callback(self._on_read)
        self.node.add_write_callback(self._on_write)
        network.add_node(self.node)
        self._maps_dirty = True
        self._rpdos: list[tuple[int, tuple[mapping.Entry, ...]]] = []
        self._tpdos: list[tuple[int, int, tuple[mapping.Entry, ...]]] = []
        self._rx: dict[int, tuple[tuple[mapping.Entry, ...], bytes]] = {}
        self._rx_count = 0  # RPDOs since the last SYNC
        self._syncs_since_rpdo = 0
        self._deadline_syncs = 0  # 0: no deadline
        self._armed = False  # the deadline runs from the first RPDO on
        self._timed_out = False
        self.syncs = 0
        self.reading = (math.nan, False)
        self.stop = threading.Event()
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

    def _new_world(self) -> None:
        self.world = World(self.scenario, self.h_s)
        old = getattr(self, 'device', None)
        self.device = Cia402Device(self.world.axis, self.units,
                                   quick_stop_option=self._raw(QUICK_STOP_OPTION_CODE))
        if old is not None:
            self.device.mode = old.mode

    def _value(self, index: int, sub: int) -> int | None:
        d = self.device
        if index == STATUSWORD:
            return d.statusword
        if index == POSITION_ACTUAL:
            return d.position_increments
        if index == VELOCITY_ACTUAL:
            return d.velocity_units
        if index == MODES_OF_OPERATION_DISPLAY:
            return d.mode_display
        if index == ERROR_CODE:
            return d.error_code
        if index == ANALOG_INPUT and sub == 1:
            return self.analog.counts(*self.reading)
        return None

    def _tpdo_value(self, e: mapping.Entry) -> int:
        v = self._value(e.index, e.subindex)
        return self._raw(e.index, e.subindex) if v is None else v

    def _on_read(self, index: int, subindex: int, od: Any) -> int | None:
        return self._value(index, subindex)

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
            if value <= 0:
                raise SdoAbortedError(SDO_VALUE_RANGE)
            if self.node.nmt.state == 'OPERATIONAL':
                raise SdoAbortedError(SDO_STATE)
            self.h_s = value * 1e-6
            self._new_world()
        elif 0x1400 <= index <= 0x1BFF:
            self._maps_dirty = True

    # ---- PDOs -----------------------------------------------------------------------------
    def _read_maps(self) -> None:
        """Build the RPDO / TPDO tables from the dictionary (as the master configured it)."""
        for cob, _entries in self._rpdos:
            self.network.unsubscribe(cob, self._on_rpdo)
        self._rpdos, self._tpdos = [], []
        od = self.node.object_dictionary
        for comm, mp, out in ((mapping.RPDO_COMM, mapping.RPDO_MAP, self._rpdos),
                              (mapping.TPDO_COMM, mapping.TPDO_MAP, self._tpdos)):
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
                        self._deadline_syncs = (max(1, math.ceil(ms * 1e-3 / self.h_s - 1e-9))
                                                if ms else 0)
                else:
                    tt = self._raw(comm + k, 2)
                    if 1 <= tt <= 240:
                        out.append((cob & 0x7FF, tt, tuple(entries)))
        for cob, _entries in self._rpdos:
            self.network.subscribe(cob, self._on_rpdo)
        self._maps_dirty = False

    def _on_rpdo(self, can_id: int, data: bytes, timestamp: float) -> None:
        if self.node.nmt.state != 'OPERATIONAL':
            return
        entries = next(e for cob, e in self._rpdos if cob == can_id)
        if len(data) != mapping.size(entries):
            self.node.emcy.send(EMCY_PDO_LENGTH, REG_COMMUNICATION | 1)
            return
        self._rx[can_id] = (entries, bytes(data))
        self._rx_count += 1

    def _on_sync(self, can_id: int, data: bytes, timestamp: float) -> None:
        try:
            self._sync()
        except Exception as exc:  # noqa: BLE001 -- python-can would only log it
            log.exception('SYNC handler failed')
            self.device.fault(EMCY_SOFTWARE, 1, str(type(exc).__name__).encode()[:5])

    def _sync(self) -> None:
        if self._maps_dirty:
            self._read_maps()
        operational = self.node.nmt.state == 'OPERATIONAL'
        d = self.device
        if operational:
            if self._rx_count:
                if self._rx_count > 1:
                    d.fault(EMCY_PROTOCOL, REG_COMMUNICATION, b'2MSTR')
                for entries, raw in self._rx.values():
                    for e, v in zip(entries, mapping.unpack(entries, raw), strict=True):
                        self._store(e.index, e.subindex, v)
                self._rx.clear()
                self._syncs_since_rpdo = 0
                self._armed = True
                self._timed_out = False
            elif self._armed:
                self._syncs_since_rpdo += 1
                if (self._deadline_syncs and self._syncs_since_rpdo >= self._deadline_syncs
                        and not self._timed_out):
                    self._timed_out = True
                    d.fault(EMCY_RPDO_TIMEOUT, REG_COMMUNICATION)
            self._rx_count = 0
        d.step(self._raw(CONTROLWORD), self._raw(TARGET_VELOCITY))
        self.reading = self.world.sample()
        for e in d.events:
            self.node.emcy.send(e.code, e.register, e.manufacturer)
            self._store(ERROR_CODE, 0, d.error_code)
            self._store(ERROR_REGISTER, 0, e.register if e.code else 0)
        d.events.clear()
        self.syncs += 1
        if operational:
            for cob, tt, entries in self._tpdos:
                if self.syncs % tt == 0:
                    values = tuple(self._tpdo_value(e) for e in entries)
                    self.network.send_message(cob, mapping.pack(entries, values))

    def boot(self) -> None:
        """Boot-up: the boot-up message, then pre-operational (the heartbeat starts)."""
        self.node.nmt.state = 'INITIALISING'
        self.node.nmt.state = 'PRE-OPERATIONAL'


def main(argv: list[str] | None = None) -> int:
    """Run one emulated drive until SIGTERM / SIGINT."""
    p = argparse.ArgumentParser(prog='python -m ladrc_sim.cia402.emulator',
                                description='Emulated CiA 402 Z drive on a CAN bus.')
    p.add_argument('--bus', required=True, help='ws://127.0.0.1:PORT/ (python-can-remote) '
                   'or a socketcan channel (can0)')
    p.add_argument('--node-id', type=int, default=5)
    p.add_argument('--eds', type=Path, default=None, help='default: the shipped EDS')
    p.add_argument('--scenario', default='step', help='the world: a scenario of the library')
    a = p.parse_args(argv)
    if not 1 <= a.node_id <= 127:
        p.error(f'--node-id {a.node_id}: 1..127')
    logging.basicConfig(level=logging.WARNING, format='emulator: %(levelname)s %(message)s')
    network = canopen.Network()
    network.connect(**bus_kwargs(a.bus))
    if bus_kwargs(a.bus)['interface'] == 'remote':
        software_periodic(network)
    emu = None
    try:
        emu = Emulator(network, a.node_id, a.eds or default_eds(), a.scenario)
        stop = threading.Event()
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: stop.set())
        emu.boot()
        print(f'emulator: node {a.node_id} on {a.bus}, h_s {emu.h_s:g} s', flush=True)
        while not stop.wait(0.5):
            pass
        return 0
    finally:
        if emu is not None:
            emu.node.nmt.stop_heartbeat()
        network.disconnect()


if __name__ == '__main__':
    sys.exit(main())
