"""Device files and plans: the driver configures a drive from its own EDS, not the emulator's.

Plain and fast: python-canopen reads the example EDS files (written with real drives' traits:
CRLF, ``DataType=0x7``, ``rww``, ``$NODEID + 0x600``, empty and commented values, no RPDO event
timer, no 0x1006, 16-bit velocity, arrays per motor, velocity actual typed unsigned, a CiA 401
I/O node), :func:`make_plan` plans them, and :func:`configure` runs against python-canopen
``LocalNode`` s built from the same files on an in-process virtual bus. Refusals are one line
naming the node and the object; ``ladrc cia402 plan`` exits 2 with that line.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
import re
import uuid

import canopen
from ladrc_cia402 import mapping
from ladrc_cia402.device_file import PlanError, load_device, make_plan, plan_text
from ladrc_cia402.master import Command, ConfigError, DriverParams, Master, configure
from ladrc_sim.cia402.can_drive import default_device
import pytest

ROOT = Path(__file__).resolve().parents[2]
EX = ROOT / 'ros2_ws' / 'src' / 'ladrc_cia402' / 'examples'
A, B, C = EX / 'servo_a_heartbeat.yaml', EX / 'servo_b_pv16.yaml', EX / 'hub_c_io401.yaml'
SHIPPED = default_device()


def _plan(path, **changes):
    dev = load_device(path)
    return make_plan(replace(dev, **changes) if changes else dev)


def _without(text: str, *indices: int) -> str:
    """Return the EDS text without the sections of these object indices."""
    for idx in indices:
        text = re.sub(rf'\[{idx:04X}(sub[0-9A-Fa-f]+)?\][^\[]*', '', text)
    return text


def _variant(tmp_path: Path, device: Path, edit) -> Path:
    """Return a copy of ``device`` whose drive EDS is ``edit(text)`` (same quirks otherwise)."""
    dev = load_device(device)
    eds = Path(dev.path).parent / dev.dcf
    text = eds.read_bytes().decode()
    (tmp_path / 'drive.eds').write_bytes(edit(text).encode())
    for other in Path(dev.path).parent.glob('*.eds'):
        if other.name != eds.name:
            (tmp_path / other.name).write_bytes(other.read_bytes())
    yaml_text = Path(device).read_text().replace(f'dcf: {dev.dcf}', 'dcf: drive.eds')
    out = tmp_path / 'device.yaml'
    out.write_text(yaml_text)
    return out


# ---- the EDS quirks python-canopen reads -------------------------------------------------
def test_the_quirky_eds_reads_as_the_drive_means_it():
    raw = (EX / 'servo_a_heartbeat.eds').read_bytes()
    assert b'\r\n' in raw and b'DataType=0x7\r\n' in raw and b'AccessType=rww' in raw
    assert b'$NODEID + 0x' in raw and b'DefaultValue=\r\n' in raw and b'; CiA 402' in raw
    od = canopen.import_od(str(EX / 'servo_a_heartbeat.eds'), 5)
    assert od[0x1000].default == 0x00020192  # the comment after the value is not the value
    assert od[0x1400][1].default == 0x205 and 5 not in od[0x1400]  # ends at sub 2
    assert od[0x1401][1].default == 0x80000305  # RPDO2 disabled by bit 31 at delivery
    assert od[0x6502].default is None and od[0x6060].access_type == 'wo'
    assert 0x1006 not in od and 0x6401 not in od


# ---- plans ---------------------------------------------------------------------------------
def test_each_shipped_device_file_plans_with_the_types_of_its_eds():
    ship = _plan(SHIPPED)
    assert ship.watchdog == 'rpdo_event_timer' and ship.deadline_ms == 10
    assert any((w.index, w.subindex, w.value) == (0x1400, 5, 10) for w in ship.writes)
    a = _plan(A)
    assert a.watchdog == 'heartbeat' and a.heartbeat_producer_ms == 20
    assert not any(w.index == 0x1400 and w.subindex == 5 for w in a.writes)
    assert not any(w.index == 0x1006 for w in a.writes)  # the drive has no 0x1006
    hb = [w for w in a.writes if w.index == 0x1016]
    assert [(w.subindex, w.value) for w in hb] == [(1, 127 << 16 | 100)]
    assert [w.index for w in a.writes][:3] == [0x2010, 0x3100, 0x6083]  # the vendor's first
    assert a.roles['gap'].index == 0x3100 and a.roles['gap'].bits == 16
    b = _plan(B)
    assert (b.roles['target_velocity'].bits, b.roles['target_velocity'].signed) == (16, True)
    assert (b.roles['gap'].bits, b.roles['gap'].signed) == (16, False)
    assert 'profile velocity' in b.mode_text
    assert b.analog.mm(6000 + 2500) == (1.0, True) and b.analog.hi == 65535
    c = _plan(C)
    assert c.io_node_id == 6 and c.roles['gap'].index == 0x6401
    assert c.roles['position_actual'].subindex == 1 and c.roles['velocity_actual'].signed
    assert not c.has_abort_connection and not any(w.index == 0x6007 for w in c.writes)
    assert {w.node_id for w in c.writes} == {5, 6}
    assert c.tpdo_cobs() == (0x185, 0x285, 0x186)
    t = _plan(SHIPPED, gap=replace(load_device(SHIPPED).gap, source='topic'))
    assert 'gap' not in t.roles and 'gap' not in [e.name for p in t.tpdos for e in p.entries]
    for p in (ship, a, b, c, t):
        text = plan_text(p)
        assert 'bus load' in text and 'watchdog' in text
        assert 0.0 < p.bus_load < 1.0


def test_refusals_are_one_line_naming_node_and_object(tmp_path):
    with pytest.raises(PlanError) as e:
        _plan(A, watchdog='rpdo_event_timer')
    assert str(e.value).startswith('node 5: 0x1400:05 RPDO1 event timer')
    assert 'watchdog: heartbeat' in str(e.value) and '\n' not in str(e.value)
    bare = _variant(tmp_path, A, lambda t: _without(t, 0x1016))
    with pytest.raises(PlanError) as e:  # the file names it: the object it needs
        make_plan(load_device(bare))
    assert str(e.value).startswith('node 5: 0x1016:01 Consumer heartbeat time: not in the EDS')
    with pytest.raises(PlanError) as e:  # auto: none of the three
        make_plan(replace(load_device(bare), watchdog='auto'))
    assert str(e.value).startswith('node 5: 0x1400:05 RPDO1 event timer')
    assert 'watchdog: none' in str(e.value)
    assert make_plan(replace(load_device(bare), watchdog='none')).watchdog == 'none'
    with pytest.raises(PlanError) as e:
        _plan(C, objects=replace(load_device(C).objects, velocity_actual_signed=False))
    assert '0x606C:01' in str(e.value) and 'UNSIGNED32' in str(e.value)
    with pytest.raises(PlanError) as e:  # a target of one sign cannot move the axis down
        _plan(C, objects=replace(load_device(C).objects, target_velocity='0x6083:00'))
    assert str(e.value).startswith('node 5: 0x6083:00 Profile acceleration: UNSIGNED32')
    with pytest.raises(PlanError) as e:
        _plan(C, objects=replace(load_device(C).objects, target_velocity='0x60FF:05'))
    assert str(e.value).startswith('node 5: 0x60FF:05')


def test_node_guarding_where_the_drive_has_neither_timer_nor_heartbeat(tmp_path):
    def edit(t):
        t = _without(t, 0x1016)
        guard = ('[100C]\nParameterName=Guard time\nObjectType=0x7\nDataType=0x0006\n'
                 'AccessType=rw\nDefaultValue=0\nPDOMapping=0\n\n[100D]\nParameterName='
                 'Life time factor\nObjectType=0x7\nDataType=0x0005\nAccessType=rw\n'
                 'DefaultValue=0\nPDOMapping=0\n\n')
        return t.replace('[1017]', guard + '[1017]')
    p = make_plan(replace(load_device(_variant(tmp_path, A, edit)), watchdog='auto'))
    assert p.watchdog == 'node_guarding' and p.guard_time_ms == 20
    assert [(w.index, w.value) for w in p.writes if w.index in (0x100C, 0x100D)] == [
        (0x100C, 20), (0x100D, 5)]


def test_array_target_velocity_and_no_velocity_mode_are_refused(tmp_path):
    def array_target(t):
        t = _without(t, 0x60FF)
        return t.replace('[6083]', '[60FF]\nParameterName=Target velocity\nObjectType=0x8\n'
                         'SubNumber=3\n\n[60FFsub0]\nParameterName=Number of motors\n'
                         'ObjectType=0x7\nDataType=0x0005\nAccessType=ro\nDefaultValue=2\n'
                         'PDOMapping=0\n\n[60FFsub1]\nParameterName=Target velocity motor 1\n'
                         'ObjectType=0x7\nDataType=0x0004\nAccessType=rww\nDefaultValue=0\n'
                         'PDOMapping=1\n\n[60FFsub2]\nParameterName=Target velocity motor 2\n'
                         'ObjectType=0x7\nDataType=0x0004\nAccessType=rww\nDefaultValue=0\n'
                         'PDOMapping=1\n\n[6083]')
    with pytest.raises(PlanError) as e:
        make_plan(load_device(_variant(tmp_path, C, array_target)))
    assert str(e.value).startswith('node 5: 0x60FF Target velocity: an ARRAY')
    pp_only = _variant(tmp_path, B, lambda t: t.replace(
        'ParameterName=Supported drive modes\nObjectType=0x7\nDataType=0x0007\nAccessType=ro\n'
        'DefaultValue=0x00000025', 'ParameterName=Supported drive modes\nObjectType=0x7\n'
        'DataType=0x0007\nAccessType=ro\nDefaultValue=0x00000001'))
    with pytest.raises(PlanError) as e:
        make_plan(load_device(pp_only))
    assert str(e.value).startswith('node 7: 0x6502:00 Supported drive modes = 0x00000001')


def test_ladrc_cia402_plan_prints_the_plan_or_one_line_and_exit_2(tmp_path, capsys):
    from ladrc_tools.cli import main

    assert main(['cia402', 'plan', str(A)]) == 0
    out = capsys.readouterr().out
    assert 'watchdog: heartbeat' in out and '0x1016:01' in out
    bad = tmp_path / 'bad.yaml'
    bad.write_text(A.read_text().replace('watchdog: heartbeat', 'watchdog: rpdo_event_timer')
                   .replace('dcf: servo_a_heartbeat.eds', f'dcf: {EX / "servo_a_heartbeat.eds"}'))
    assert main(['cia402', 'plan', str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and '0x1400:05 RPDO1 event timer' in err
    (tmp_path / 'typo.yaml').write_text('node_id: 5\nwatchdgo: none\n')
    assert main(['cia402', 'plan', str(tmp_path / 'typo.yaml')]) == 2
    assert "unknown key 'watchdgo'" in capsys.readouterr().err


# ---- configure against python-canopen LocalNodes of the same EDS files --------------------
class _Bus:
    """A drive (and an I/O node) as python-canopen LocalNodes, a master network: one channel."""

    def __init__(self, plan, supported_modes: int | None = None):
        ch = f'cia402-{uuid.uuid4().hex}'
        self.slave_net = canopen.Network()
        self.slave_net.connect(interface='virtual', channel=ch)
        self.master_net = canopen.Network()
        self.master_net.connect(interface='virtual', channel=ch)
        self.drive = canopen.LocalNode(plan.node_id, canopen.import_od(plan.eds_path,
                                                                       plan.node_id))
        mo = plan.roles['modes_of_operation']
        md = plan.roles['modes_of_operation_display']

        def on_write(index, subindex, od, data):
            if (index, subindex) == (mo.index, mo.subindex):  # the display follows the mode
                self.drive.data_store.setdefault(md.index, {})[md.subindex] = data

        def on_read(index, subindex, od):
            if index == 0x6502 and supported_modes is not None:
                return supported_modes
            return None
        self.drive.add_write_callback(on_write)
        self.drive.add_read_callback(on_read)
        self.slave_net.add_node(self.drive)
        self.io = None
        io = None
        if plan.io_node_id:
            self.io = canopen.LocalNode(plan.io_node_id, plan.io_od)
            self.slave_net.add_node(self.io)
            rio = canopen.RemoteNode(plan.io_node_id, plan.io_od)
            self.master_net.add_node(rio)
            io = (rio.sdo, rio.nmt)
        self.remote = canopen.RemoteNode(plan.node_id, canopen.import_od(plan.eds_path,
                                                                         plan.node_id))
        self.master_net.add_node(self.remote)
        self.io_client = io

    def close(self):
        self.master_net.disconnect()
        self.slave_net.disconnect()


def _stored(node, index, sub):
    obj = node.object_dictionary[index]
    if not isinstance(obj, canopen.objectdictionary.ODVariable):
        obj = obj[sub]
    return obj.decode_raw(node.get_data(index, sub))


@pytest.mark.parametrize('device, modes', [(SHIPPED, None), (A, 0x104), (B, None), (C, None)])
def test_configure_runs_against_the_drives_own_dictionary(device, modes):
    p = DriverParams(device=str(device), period_s=0.0005, sdo_timeout_s=5.0)
    plan = p.plan()
    bus = _Bus(plan, modes)
    try:
        line = configure(bus.remote.sdo, bus.remote.nmt, p, plan=plan, io=bus.io_client)
    finally:
        bus.close()
    assert 'operational' in line and bus.drive.nmt.state == 'OPERATIONAL'
    last = {(w.node_id, w.index, w.subindex): w for w in plan.writes}
    for w in last.values():  # every write of the plan landed in the node it names
        node = bus.drive if w.node_id == plan.node_id else bus.io
        assert _stored(node, w.index, w.subindex) == w.value, w
    mode = _stored(bus.drive, 0x6060, 0)
    assert mode == (3 if device == B else 9)
    if device == C:
        assert bus.io.nmt.state == 'OPERATIONAL'


def test_a_drive_that_answers_neither_csv_nor_pv_is_refused_at_configure():
    p = DriverParams(device=str(A), sdo_timeout_s=5.0)
    plan = p.plan()
    bus = _Bus(plan, supported_modes=0x1)  # the EDS has no value: the drive answers PP only
    try:
        with pytest.raises(ConfigError, match='neither cyclic synchronous velocity'):
            configure(bus.remote.sdo, bus.remote.nmt, p, plan=plan)
    finally:
        bus.close()
    assert bus.drive.nmt.state != 'OPERATIONAL'


def test_a_silent_io_node_faults_the_axis_and_names_the_node():
    """Drive C's cycle waits for the I/O node's TPDO of the same SYNC; without it: a fault."""
    p = DriverParams(device=str(C), missing_tpdo_cycles=3)
    plan = p.plan()
    io_alive = [True]

    def send(cob, data):
        if cob != mapping.SYNC_COB_ID:
            return
        values = {'statusword': 0x0237, 'position_actual': 1000, 'velocity_actual': 0,
                  'gap': 1500}
        for pdo in plan.tpdos:
            m.on_frame(pdo.cob_id(5), mapping.pack(pdo.entries,
                                                   tuple(values[e.name] for e in pdo.entries)))
        if io_alive[0]:
            for pdo in plan.io_tpdos:
                m.on_frame(pdo.cob_id(6), mapping.pack(pdo.entries, (1500,)))

    m = Master(p, send, plan)
    s = m.cycle(Command(), 0.0)
    assert s.fresh and s.gap_mm == 1.5 and s.gap_valid and not s.fault
    io_alive[0] = False
    for _ in range(3):
        s = m.cycle(Command(), 0.0)
    assert not s.fresh and s.fault and s.target == 0
    assert s.fault_reason.startswith('no TPDO from node 6 for 3 cycles')


def test_an_explicit_layout_in_the_device_file_is_taken_as_written():
    dev = load_device(A)
    p = make_plan(replace(dev, tpdo={
        1: {'transmission': 1, 'mapping': [{'index': 0x6041, 'sub_index': 0},
                                           {'index': 0x3100, 'sub_index': 1}]},
        3: {'transmission': 1, 'mapping': ['0x6064:00', '0x606C:00']}}))
    assert [(t.number, [e.name for e in t.entries]) for t in p.tpdos] == [
        (1, ['statusword', 'gap']), (3, ['position_actual', 'velocity_actual'])]
    assert p.tpdo_cobs() == (0x185, 0x385)
    # TPDO2 and TPDO4 unused: disabled by bit 31
    off = {w.index for w in p.writes if w.subindex == 1 and w.value & 0x80000000
           and 'unused' in w.text}
    assert {0x1801, 0x1803} <= off
    with pytest.raises(PlanError) as e:  # a role left out of the layout
        make_plan(replace(dev, tpdo={1: {'mapping': ['0x6041:00', '0x6064:00']}}))
    assert '(velocity_actual): in no PDO of the layout' in str(e.value)
