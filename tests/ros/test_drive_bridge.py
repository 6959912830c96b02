"""The sim node's drive (node/drive_bridge.py) catching up a stall of its own process.

No DDS here: the bridge runs against a stand-in node and a clock the test moves, so the stall
is exact. What a wrong implementation gets wrong: a simulated axis that pauses during the stall
(slower than the clock), cycles caught up that publish or trip the watchdog on the simulator's
own stall, or a silent controller whose last command runs on through the stall.
"""

from __future__ import annotations

from types import SimpleNamespace

from ladrc_contract.tick import TickInput
from ladrc_sim.node import drive_bridge as db
import pytest

pytestmark = pytest.mark.ros  # (imports the rclpy-based loop I/O)

H_NS = 500_000


class _Node:
    """What the bridge uses of the sim node; counts what it publishes."""

    def __init__(self) -> None:
        self.h_s = H_NS * 1e-9
        self.watchdog_timeout_s = 0.005
        self.watchdog_recover_s = 0.05
        self.lockstep = False
        self.lockstep_timeout_s = 1.0
        self.context = None
        self.cmd_reader = SimpleNamespace(take=lambda: None)
        self.published: list[int] = []

    def publish_samples(self, seq, tick, fault, reason, truth, stamp_ns=None) -> None:
        self.published.append(seq)

    def get_logger(self):
        return SimpleNamespace(warning=lambda *_: None, error=lambda *_: None)


@pytest.fixture
def bridge(monkeypatch):
    monkeypatch.setattr(db, 'SampleWait', lambda context, readers: None)
    clock = SimpleNamespace(ns=1_000_000_000)
    monkeypatch.setattr(db.time, 'monotonic_ns', lambda: clock.ns)
    monkeypatch.setattr(db.time, 'sleep', lambda s: setattr(clock, 'ns', clock.ns + int(s * 1e9)))
    b = db.DriveBridge(_Node())
    b.clock = clock
    b.pending = []  # commands that arrived: taken at the next cycle, as from the reader

    def take() -> None:
        while b.pending:
            _command(b, b.pending.pop(0))

    b.take_commands = take
    return b


TICK = TickInput(0.0, 1.0, True, 0.0, 5.0, 0.0, True, False)


def _command(b, velocity: float) -> None:
    b._command(db._Command(b.cmd_count + 1, velocity, True, 0, '/ladrc_follow', 1, False))


def _run(b, ticks: int, velocity: float | None = None) -> list[float]:
    out = []
    for _ in range(ticks):
        if velocity is not None:
            _command(b, velocity)
        out.append(b.step(TICK))
    return out


def test_a_stall_is_caught_up_silently_at_the_held_command(bridge):
    b = bridge
    _run(b, 20, velocity=-2.0)  # on time: one command per cycle
    published, seq = len(b.node.published), b.seq
    b.clock.ns += 4 * H_NS  # descheduled for 4 cycles (under the watchdog)
    got = _run(b, 5)
    # the 2 cycles missed by more than one ran at once at the held command, publishing
    # nothing; the axis kept the clock (seq); then the one late by a cycle, then on time
    assert got == [-2.0] * 5 and b.seq == seq + 5
    assert b.late_ticks == 2 and len(b.node.published) == published + 3
    assert not b.fault_reason and b.watchdog_trips == 0


def test_commands_that_came_during_a_long_stall_do_not_trip_the_watchdog(bridge):
    b = bridge
    _run(b, 20, velocity=1.0)
    b.clock.ns += 40 * H_NS  # a 20 ms stall of the simulator; the controller went on sending
    b.pending = [1.2, 1.5]  # taken at the first caught-up cycle
    got = _run(b, 40)
    assert b.late_ticks > 30
    assert not b.fault_reason and b.watchdog_trips == 0 and got[-1] == 1.5


def test_a_controller_silent_before_a_stall_stops_the_axis_when_a_drive_would(bridge):
    b = bridge
    _run(b, 20, velocity=-3.0)
    last = b.last_cmd_ns
    b.clock.ns += 40 * H_NS  # the controller died, then the simulator stalled 20 ms
    got = _run(b, 40)
    assert b.watchdog_trips == 1 and 'caught up after a stall' in b.fault_reason
    assert b.quick_stop()
    # the cycles up to the watchdog's time ran the last command, every later one is zero
    moving = [v for v in got if v != 0.0]
    assert all(v == -3.0 for v in moving)
    assert 8 <= len(moving) <= 11  # ~5 ms of cycles after the last command, not 20 ms
    assert b.t_start_ns + (20 + len(moving)) * H_NS - last > 5_000_000 - H_NS
