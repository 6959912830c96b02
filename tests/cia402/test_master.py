"""The CiA 402 master's cyclic core (``ladrc_cia402.master``) against the emulated drive's model.

Plain Python, no bus, no ROS: a fake bus hands the master's RPDO and SYNC to
``ladrc_sim.cia402.device.Cia402Device`` (over the simulator's axis model) and answers each SYNC
with TPDO1/TPDO2 at once, as the emulator does. Drive-up one transition per cycle, the target
only in Operation enabled, quick stop on an exception, a missing TPDO as a fault, EMCY text in
the fault reason, the fault reset, and a downward command never rounded larger.
"""

from __future__ import annotations

from dataclasses import replace
import math

from ladrc_cia402 import emcy, mapping
from ladrc_cia402.device_file import load_device, make_plan
from ladrc_cia402.ds402 import CW_QUICK_STOP, MODE_CYCLIC_SYNC_VELOCITY, State
from ladrc_cia402.master import Command, ConfigError, DriverParams, Master, configure
from ladrc_sim.cia402.can_drive import default_device
from ladrc_sim.cia402.device import Cia402Device
from ladrc_sim.models.axis import Axis, AxisParams
import pytest

NODE = 5
DEVICE = str(default_device())  # the shipped drive's device file
PLAN = make_plan(load_device(DEVICE))


def _entries(role: str) -> tuple[int, tuple]:
    """Return the COB-ID and entries of the shipped plan's TPDO that carries ``role``."""
    for p in PLAN.tpdos:
        if any(e.name == role for e in p.entries):
            return p.cob_id(NODE), p.entries
    raise KeyError(role)
RUN = Command(0.0, False, admitted=True, commanded=True)


class FakeBus:
    """RPDO + SYNC into the device model; TPDOs and EMCYs back into the master, synchronously."""

    def __init__(self, analog_counts: int = 1500):
        self.device = Cia402Device(Axis(AxisParams(), 3.0, 0.0005))
        self.device.set_mode(MODE_CYCLIC_SYNC_VELOCITY)
        self.master: Master | None = None
        self.rx = (0, 0)
        self.rpdos: list[tuple[int, int]] = []
        self.silent = False  # the drive sends no TPDO
        self.broken = False  # the bus raises on send
        self.counts = analog_counts

    def send(self, cob: int, data: bytes) -> None:
        if self.broken:
            raise OSError('bus off')
        if cob == PLAN.rpdos[0].cob_id(NODE):
            self.rx = mapping.unpack(PLAN.rpdos[0].entries, data)
            self.rpdos.append(self.rx)
        elif cob == mapping.SYNC_COB_ID:
            d = self.device
            d.step(*self.rx)
            for e in d.events:
                self.master.on_frame(emcy.EMCY_COB_BASE + NODE,
                                     emcy.pack_emcy(e.code, e.register, e.manufacturer))
            d.events.clear()
            if self.silent:
                return
            values = {'statusword': d.statusword, 'position_actual': d.position_increments,
                      'velocity_actual': d.velocity_units, 'gap': self.counts}
            for p in PLAN.tpdos:
                self.master.on_frame(p.cob_id(NODE), mapping.pack(
                    p.entries, tuple(values[e.name] for e in p.entries)))


def _pair(**kw) -> tuple[Master, FakeBus]:
    bus = FakeBus()
    vu = kw.pop('velocity_units_per_mm_s', None)
    plan = PLAN
    if vu is not None:  # the device file's units
        dev = load_device(DEVICE)
        plan = make_plan(replace(dev, units=replace(dev.units, velocity_units_per_mm_s=vu)))
    m = Master(DriverParams(device=DEVICE, **kw), bus.send, plan)
    bus.master = m
    return m, bus


def _up(m: Master) -> int:
    for n in range(20):
        s = m.cycle(RUN, 0.0)
        if s.enabled:
            return n + 1  # cycles until the TPDO reports Operation enabled
    raise AssertionError(m.state)


def test_drive_up_one_transition_per_cycle_then_csv():
    m, bus = _pair()
    s = m.cycle(Command(), 0.0)  # no commander: not powered
    assert s.state is State.SWITCH_ON_DISABLED and not s.enabled and not s.fault
    assert s.gap_mm == 1.5 and s.gap_valid
    assert _up(m) == 3  # shutdown, switch on, enable operation
    assert bus.device.transitions == [1, 2, 3, 4]
    x0 = m.cycle(RUN, 0.0).position_mm
    for _ in range(400):
        s = m.cycle(Command(2.0, True, True, True), 0.0)
    assert s.target == 2000 and s.position_mm > x0 + 0.3 and s.velocity_mm_s > 1.9
    # enable false: hold zero (still enabled); no commander any more: switched off
    assert m.cycle(Command(2.0, False, True, True), 0.0).target == 0
    assert m.cycle(Command(2.0, True, False, True), 0.0).target == 0  # not admitted
    for _ in range(3):
        s = m.cycle(Command(), 0.0)
    assert s.state is State.SWITCH_ON_DISABLED and s.target == 0


def test_no_target_before_operation_enabled():
    m, bus = _pair()
    for _ in range(3):
        m.cycle(Command(-5.0, True, True, True), 0.0)
    assert all(t == 0 for _cw, t in bus.rpdos)


def test_a_downward_command_is_never_rounded_larger():
    m, _ = _pair(velocity_units_per_mm_s=7.3)
    _up(m)
    for v in (-0.0001, -0.137, -1.0 / 3.0, -2.9999, -123.456789):
        s = m.cycle(Command(v, True, True, True), 0.0)
        assert s.target <= 0 and abs(s.target) <= abs(v) * 7.3, (v, s.target)
        assert m.units.velocity_mm_s(s.target) >= v
    assert m.cycle(Command(math.nan, True, True, True), 0.0).target == 0


def test_an_exception_in_the_cycle_quick_stops():
    m, bus = _pair()
    _up(m)
    for _ in range(100):
        m.cycle(Command(-3.0, True, True, True), 0.0)
    # a statusword of no state (a broken frame) raises inside the cycle
    real = bus.device.__class__.statusword
    bus.device.__class__.statusword = property(lambda self: 0x0001)
    try:
        s = m.cycle(Command(-3.0, True, True, True), 0.0)
    finally:
        bus.device.__class__.statusword = real
    assert s.fault and 'driver exception: UnknownStatus' in s.fault_reason, s.fault_reason
    assert s.target == 0 and bus.rpdos[-1] == (CW_QUICK_STOP, 0)
    for _ in range(200):
        s = m.cycle(Command(-3.0, True, True, True), 0.0)
        assert s.target == 0 and s.fault
    assert bus.device.plant.velocity_mm_s == 0.0
    assert all(t == 0 for _cw, t in bus.rpdos[-200:])
    # a bus error: the same path; the reason names it
    bus.broken = True
    s = m.cycle(RUN, 0.0)
    assert s.fault and s.target == 0


def test_a_bus_error_is_a_fault_with_its_text():
    m, bus = _pair()
    _up(m)
    bus.broken = True
    s = m.cycle(Command(1.0, True, True, True), 0.0)
    assert s.fault and 'OSError: bus off' in s.fault_reason and s.target == 0


def test_missing_tpdos_fault_the_drive():
    m, bus = _pair(missing_tpdo_cycles=3)
    _up(m)
    bus.silent = True
    s = [m.cycle(Command(1.0, True, True, True), 0.001) for _ in range(3)]
    assert not s[0].fresh and not s[1].fault and s[2].fault
    assert 'no TPDO from node 5 for 3 cycles' in s[2].fault_reason
    bus.silent = False
    s = m.cycle(Command(1.0, True, True, True), 0.0)
    assert s.fault and s.target == 0 and bus.rpdos[-1][0] == CW_QUICK_STOP  # latched
    m.request_reset()
    for _ in range(10):
        s = m.cycle(Command(1.0, True, True, True), 0.0)
    assert not s.fault and s.enabled and s.target == 1000


def test_emcy_text_in_the_fault_reason_and_the_reset():
    m, bus = _pair()
    _up(m)
    bus.device.fault(0x8611)  # following error
    s = m.cycle(Command(1.0, True, True, True), 0.0)
    assert s.fault and s.fault_reason.startswith('EMCY 0x8611 following error'), s.fault_reason
    assert not s.enabled  # (this cycle's RPDO went out before the EMCY came)
    s = m.cycle(Command(1.0, True, True, True), 0.0)
    assert s.target == 0 and s.controlword in (CW_QUICK_STOP, 0)
    for _ in range(400):
        s = m.cycle(Command(1.0, True, True, True), 0.0)
    assert s.state is State.FAULT and s.fault  # stays faulted without the operator
    m.request_reset()
    cws = []
    for _ in range(10):
        s = m.cycle(Command(1.0, True, True, True), 0.0)
        cws.append(s.controlword)
    assert 0x80 in cws and 14 in bus.device.transitions and 15 in bus.device.transitions
    assert s.enabled and not s.fault and s.target == 1000


def test_the_analog_input_out_of_range_is_invalid():
    m, bus = _pair()
    bus.counts = 0x7FFF
    s = m.cycle(Command(), 0.0)
    assert not s.gap_valid and math.isnan(s.gap_mm)


class _Var:
    def __init__(self, store, key):
        self.store, self.key = store, key

    @property
    def raw(self):
        return self.store.get(self.key, 0)

    @raw.setter
    def raw(self, value):
        self.store[self.key] = value
        if self.key == (0x6060, 0):
            self.store[(0x6061, 0)] = value


class _Obj:
    def __init__(self, store, index):
        self.store, self.index = store, index

    def __getitem__(self, sub):
        return _Var(self.store, (self.index, sub))

    @property
    def raw(self):
        return _Var(self.store, (self.index, 0)).raw

    @raw.setter
    def raw(self, value):
        _Var(self.store, (self.index, 0)).raw = value


class _Sdo(dict):
    def __getitem__(self, index):
        return _Obj(self, index)


class _Nmt:
    state = 'PRE-OPERATIONAL'


def test_configure_writes_mapping_mode_period_and_deadline():
    sdo, nmt = _Sdo(), _Nmt()
    dict.__setitem__(sdo, (0x1000, 0), 0x00020192)
    line = configure(sdo, nmt, DriverParams(device=DEVICE, rpdo_deadline_ms=7, period_s=0.001))
    assert nmt.state == 'OPERATIONAL' and 'CSV' in line
    assert dict.__getitem__(sdo, (0x1400, 5)) == 7
    assert dict.__getitem__(sdo, (0x1006, 0)) == 1000
    assert dict.__getitem__(sdo, (0x6060, 0)) == 9
    assert dict.__getitem__(sdo, (0x1600, 2)) == 0x60FF0020  # INTEGER32 from the EDS
    assert dict.__getitem__(sdo, (0x1400, 1)) == 0x205


def test_configure_refuses_a_non_402_device_in_one_line():
    sdo, nmt = _Sdo(), _Nmt()
    dict.__setitem__(sdo, (0x1000, 0), 0x00000191)  # CiA 401 I/O module
    with pytest.raises(ConfigError, match='profile 401, not a CiA 402 drive'):
        configure(sdo, nmt, DriverParams(device=DEVICE))
    assert nmt.state == 'PRE-OPERATIONAL'


def test_parameters_are_declared_once_with_ranges():
    assert DriverParams().problems() == []
    assert DriverParams(node_id=0).problems() and DriverParams(bus_interface='udp').problems()


class _SdoWithOd(_Sdo):
    """A drive whose EDS has 0x6502 (supported modes) and 0x6007 (abort connection)."""

    od = {0x6502: None, 0x6007: None}


@pytest.mark.parametrize('modes, mode, name', [(0x104, 9, 'CSV'), (0x004, 3, 'profile velocity')])
def test_csv_where_the_drive_has_it_else_profile_velocity_and_quick_stop_on_a_lost_master(
        modes, mode, name):
    sdo, nmt = _SdoWithOd(), _Nmt()
    dict.__setitem__(sdo, (0x1000, 0), 0x00020192)
    dict.__setitem__(sdo, (0x6502, 0), modes)
    line = configure(sdo, nmt, DriverParams(device=DEVICE))
    assert f', {name}, SYNC' in line
    assert dict.__getitem__(sdo, (0x6060, 0)) == mode
    assert dict.__getitem__(sdo, (0x6007, 0)) == 3  # abort connection: quick stop


def test_a_drive_without_a_velocity_mode_is_refused_in_one_line():
    sdo, nmt = _SdoWithOd(), _Nmt()
    dict.__setitem__(sdo, (0x1000, 0), 0x00020192)
    dict.__setitem__(sdo, (0x6502, 0), 0x1)  # profile position only
    with pytest.raises(ConfigError, match='neither cyclic synchronous velocity nor profile'):
        configure(sdo, nmt, DriverParams(device=DEVICE))
    assert nmt.state == 'PRE-OPERATIONAL'
