"""The emulated drive in its own process on the test bus, driven by a canopen master here.

Three processes: python-can-remote's server on 127.0.0.1 (started and stopped by PID), the
emulator (``python -m ladrc_sim.cia402.emulator``), and this test as the master (a
``canopen.Network`` on the remote bus). Lock step: the master sends the next SYNC only after it
received both TPDOs of the previous one, so the drive advances exactly one period per SYNC and
the verdict does not depend on load (no timing asserts; the timeouts are only for a dead peer).

The master reads 0x1000 by SDO, writes the plan of the shipped device file (its PDO layout
and the RPDO deadline, ladrc_cia402.device_file), sets 0x6060 = 9 (CSV), starts the node
(NMT), drives the state machine to Operation enabled with ``next_controlword`` in RPDO1 +
SYNC, commands +2 mm/s for 200 cycles and sees position actual rise by 2 mm/s x 200 x h_s (in
increments, within the velocity loop's lag); then it stops sending RPDOs and sees EMCY 0x8250
and the Fault state; a fault reset brings it back to Switch on disabled; the heartbeat
reports Operational; two RPDOs in one cycle (two masters) fault it with EMCY 0x8200.
"""

from __future__ import annotations

import os
from pathlib import Path
import queue
import signal
import subprocess
import sys
import time

import canopen
from ladrc_cia402 import emcy, mapping
from ladrc_cia402.device_file import load_device, make_plan
from ladrc_cia402.ds402 import MODE_CYCLIC_SYNC_VELOCITY, Goal, State, next_controlword, state_of
from ladrc_cia402.units import DriveUnits
from ladrc_sim.cia402.bus import start_bus_server
from ladrc_sim.cia402.can_drive import bus_kwargs, default_device, default_eds
from ladrc_sim.headless.scenario import load_scenario
from ladrc_sim.models.axis import Axis
import pytest

ROOT = Path(__file__).resolve().parents[2]
SRC = ROOT / 'ros2_ws' / 'src'
NODE_ID = 5
TIMEOUT_S = 30.0  # a dead peer, not a slow one: lock step waits as long as it takes
H_S = 0.0005  # the EDS's 0x1006 = 500 us
PLAN = make_plan(load_device(default_device()), H_S, rpdo_deadline_ms=10)
RPDO1 = PLAN.rpdos[0]


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.kill(proc.pid, signal.SIGTERM)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait(20)


class Master:
    """The test's CANopen master: SDO through canopen, PDOs and SYNC by hand, in lock step."""

    def __init__(self, url: str):
        self.net = canopen.Network()
        self.net.connect(**bus_kwargs(url))
        self.node = canopen.RemoteNode(NODE_ID, str(default_eds()))
        self.net.add_node(self.node)
        self.tpdo: queue.Queue = queue.Queue()
        self.emcy: queue.Queue = queue.Queue()
        self.boot: queue.Queue = queue.Queue()
        self.tables = {pdo.cob_id(NODE_ID): pdo.entries for pdo in PLAN.tpdos}
        for cob in self.tables:
            self.net.subscribe(cob, self._on_tpdo)
        self.net.subscribe(emcy.EMCY_COB_BASE + NODE_ID,
                           lambda cid, data, ts: self.emcy.put(emcy.unpack_emcy(data)))
        self.net.subscribe(0x700 + NODE_ID, lambda cid, data, ts: self.boot.put(bytes(data)))
        self.cw = 0
        self.statusword = 0
        self.position = 0
        self.velocity = 0
        self.analog = 0

    def _on_tpdo(self, can_id, data, ts):
        self.tpdo.put((can_id, bytes(data)))

    def cycle(self, cw: int | None, target: int = 0, extra_rpdo: bool = False) -> None:
        """One lock-step cycle: RPDO (unless None), SYNC, wait for TPDO1 and TPDO2."""
        if cw is not None:
            self.cw = cw
            data = mapping.pack(RPDO1.entries, (cw, target))
            self.net.send_message(RPDO1.cob_id(NODE_ID), data)
            if extra_rpdo:
                self.net.send_message(RPDO1.cob_id(NODE_ID), data)
        self.net.send_message(mapping.SYNC_COB_ID, b'')
        got = set()
        values = {}
        while len(got) < len(self.tables):
            can_id, data = self.tpdo.get(timeout=TIMEOUT_S)
            entries = self.tables[can_id]
            values.update(zip((e.name for e in entries), mapping.unpack(entries, data),
                                 strict=True))
            got.add(can_id)
        self.statusword, self.position = values['statusword'], values['position_actual']
        self.velocity, self.analog = values['velocity_actual'], values['gap']

    @property
    def state(self) -> State:
        return state_of(self.statusword)

    def drive_to(self, goal: Goal, end: State, target: int = 0, limit: int = 50,
                 reset_fault: bool = False) -> int:
        for n in range(limit):
            if self.state is end:
                return n
            self.cycle(next_controlword(self.state, goal, reset_fault, self.cw), target)
        raise AssertionError(f'not {end} after {limit} cycles: {self.state}')

    def emcy_codes(self, wait_s: float = 0.0) -> list[int]:
        out = []
        try:
            while True:
                out.append(self.emcy.get(timeout=wait_s)[0])
                wait_s = 0.0
        except queue.Empty:
            return out

    def close(self) -> None:
        self.net.disconnect()


@pytest.fixture
def bus(tmp_path):
    server = start_bus_server(tmp_path / 'bus.log')
    try:
        yield server
    finally:
        server.stop()


def _start_emulator(url: str, log: Path) -> subprocess.Popen:
    env = dict(os.environ)
    paths = [str(SRC / p) for p in ('ladrc_cia402', 'ladrc_sim', 'ladrc_contract')]
    env['PYTHONPATH'] = os.pathsep.join(paths + [env.get('PYTHONPATH', '')])
    with open(log, 'wb') as out:
        return subprocess.Popen([sys.executable, '-m', 'ladrc_sim.cia402.emulator', '--bus', url,
                                 '--node-id', str(NODE_ID), '--scenario', 'step'],
                                stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                env=env)


def test_lock_step_csv_and_the_rpdo_watchdog(bus, tmp_path):
    units = DriveUnits()  # the emulator's defaults: 1000 increments/mm, increments/s
    master = Master(bus.url)
    emu = _start_emulator(bus.url, tmp_path / 'emulator.log')
    try:
        assert master.boot.get(timeout=TIMEOUT_S) == b'\x00'  # boot-up
        sdo = master.node.sdo
        sdo.RESPONSE_TIMEOUT = 5.0
        assert sdo[0x1000].raw == 0x00020192
        for w in PLAN.writes:
            if w.index == 0x1006:
                continue  # read below
            if w.index in (0x6007,):
                sdo[w.index].raw = w.value
            else:
                sdo[w.index][w.subindex].raw = w.value
        assert sdo[0x1400][5].raw == 10
        sdo[0x6060].raw = MODE_CYCLIC_SYNC_VELOCITY
        assert sdo[0x6061].raw == MODE_CYCLIC_SYNC_VELOCITY
        with pytest.raises(canopen.SdoAbortedError):
            sdo[0x6060].raw = 1  # profile position: not this drive's
        h_s = sdo[0x1006].raw * 1e-6
        assert h_s == H_S
        master.node.nmt.state = 'OPERATIONAL'
        master.cycle(0)
        assert master.state is State.SWITCH_ON_DISABLED
        t0 = time.monotonic()
        n_up = master.drive_to(Goal.OPERATION_ENABLED, State.OPERATION_ENABLED)
        assert n_up == 3  # shutdown, switch on, enable operation: one transition per cycle
        x0 = master.position
        target = units.velocity_command(2.0)
        n = 200
        for _ in range(n):
            master.cycle(0x0F, target)
        cycles = n_up + 1 + n
        rate = cycles / (time.monotonic() - t0)
        rise = master.position - x0
        expected = 2.0 * n * h_s * units.increments_per_mm  # 200 increments
        # the velocity loop's lag (T1 = 8 ms) takes about 2 mm/s x T1 = 16 increments; the
        # emulator runs the simulator's axis model, so the same model here gives the rise
        # exactly (lock step: one SYNC = one period), to the encoder's rounding
        axis = Axis(load_scenario('step').axis, 0.0, h_s)
        for _ in range(n):
            axis.step(units.velocity_mm_s(target))
        assert abs(rise - axis.position_mm * units.increments_per_mm) <= 1.0, rise
        assert expected - 25 <= rise <= expected, (rise, expected)
        assert master.velocity == pytest.approx(target, abs=5)
        assert master.analog > 0 and master.state is State.OPERATION_ENABLED
        print(f'lock step: {cycles} SYNC cycles at {rate:.0f} cycles/s; position rose '
              f'{rise} increments ({expected:g} commanded)')
        assert master.emcy_codes() == []
        # the heartbeat producer (0x1017 = 100 ms) reports Operational (5)
        limit = time.monotonic() + TIMEOUT_S
        while master.boot.get(timeout=TIMEOUT_S) != b'\x05':
            assert time.monotonic() < limit
        # the master falls silent: SYNC only (the deadline: 10 ms = 20 SYNC periods)
        for k in range(40):  # noqa: B007 -- k is reported below
            master.cycle(None)
            if master.state is State.FAULT:
                break
        assert master.state is State.FAULT, master.state
        codes = master.emcy_codes(wait_s=TIMEOUT_S)
        assert codes == [0x8250], codes
        assert sdo[0x603F].raw == 0x8250
        assert emcy.fault_text(sdo[0x603F].raw) == 'EMCY 0x8250 RPDO timeout'
        print(f'watchdog: Fault {k + 1} SYNCs after the last RPDO')
        # fault reset on the rising edge, then a second master
        master.drive_to(Goal.OPERATION_ENABLED, State.SWITCH_ON_DISABLED, reset_fault=True)
        assert master.emcy_codes(wait_s=TIMEOUT_S) == [0]  # error reset
        master.drive_to(Goal.OPERATION_ENABLED, State.OPERATION_ENABLED)
        master.cycle(0x0F, 0, extra_rpdo=True)
        for _ in range(40):
            if master.state is State.FAULT:
                break
            master.cycle(0x0F, 0)
        assert master.state is State.FAULT
        assert master.emcy_codes(wait_s=TIMEOUT_S) == [0x8200]
        assert emu.poll() is None
    finally:
        master.close()
        _stop(emu)
    log = (tmp_path / 'emulator.log').read_text()
    assert 'Traceback' not in log and emu.returncode == 0, log


def test_the_bus_server_listens_on_loopback_only_and_stops_by_pid(tmp_path):
    server = start_bus_server(tmp_path / 'bus.log')
    try:
        assert server.url == f'ws://127.0.0.1:{server.port}/'
        assert server.process.poll() is None
        log = (tmp_path / 'bus.log').read_text()
        assert f'Server listening on 127.0.0.1:{server.port}' in log, log
    finally:
        code = server.stop()
    assert code is not None and server.process.poll() is not None
