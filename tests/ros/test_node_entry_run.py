"""The node entry (ladrc_contract.node_entry.run_node) with a real rclpy node, as a process.

A tiny node (written here, run by the test's Python on the test's domain, localhost only:
tests/ros/conftest.py) records what the entry did to a file: the zero hook (its stop reason,
whether the ROS context was still valid, whether its publish went out), the deferred clean-up.
Stopped by SIGTERM / SIGINT sent to its PID, it exits 0 after its zero command; a constructor
that raises is one line on stderr and exit 2; a callback that raises ends in the zero command
and exit 1. Every process is ended by its PID at teardown.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from ladrc_contract.node_entry import EXIT_CONFIG, EXIT_FAILED, EXIT_OK
import pytest

# The wall-clock waits: a process's start (rclpy import, DDS participant) takes 1-3 s here, up
# to ~15 s on a loaded 2-core machine; 60 s is the budget.
START_S = 60.0
END_S = 30.0

TINY = """
import json, sys, time
from ladrc_contract.node_entry import StartError, run_node, spin
from rclpy.node import Node
from std_msgs.msg import String

MODE, OUT = sys.argv[1], sys.argv[2]


def record(**event):
    with open(OUT, 'a', encoding='utf-8') as f:
        f.write(json.dumps(event) + '\\n')


class Tiny(Node):
    def __init__(self):
        if MODE == 'slow_start':
            record(event='constructing')
            time.sleep(3.0)  # the stop signal arrives in here
        if MODE == 'bad_config':
            raise ValueError('no sensor named z9\\nname one of the sensor table')
        super().__init__('tiny_entry')
        self.pub = self.create_publisher(String, 'tiny_entry/command', 10)
        self.ticks = 0
        self.create_timer(0.02, self.tick)

    def tick(self):
        self.ticks += 1
        if self.ticks == 1:
            record(event='spinning')
        if MODE == 'fail' and self.ticks == 3:
            raise RuntimeError('sensor lost')


def run(node, node_run):
    node_run.defer(lambda: record(event='deferred', context_ok=node.context.ok()))
    if MODE == 'start_error_in_run':
        raise StartError('bus can9 not found: name an existing bus')
    return spin(node, node_run)


def zero(node, reason):
    ok = node.context.ok()
    node.pub.publish(String(data='zero'))  # raises once the context is gone
    record(event='zero', reason=reason, context_ok=ok, published=True)


sys.exit(run_node('tiny_entry', Tiny, run, zero=zero))
"""


class Tiny:
    """One tiny node process; its events, its exit."""

    def __init__(self, folder: Path, mode: str) -> None:
        self.script = folder / 'tiny_entry.py'
        self.script.write_text(TINY, encoding='utf-8')
        self.out = folder / f'{mode}.jsonl'
        self.proc = subprocess.Popen([sys.executable, str(self.script), mode, str(self.out)],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     env=dict(os.environ), start_new_session=True)

    def events(self) -> list[dict]:
        if not self.out.exists():
            return []
        return [json.loads(line) for line in self.out.read_text().splitlines() if line]

    def wait_event(self, name: str) -> None:
        end = time.monotonic() + START_S
        while not any(e['event'] == name for e in self.events()):
            assert self.proc.poll() is None, f'ended before {name}: {self.finish()}'
            assert time.monotonic() < end, f'no {name} within {START_S:g} s'
            time.sleep(0.05)

    def finish(self) -> tuple[int, str]:
        _, err = self.proc.communicate(timeout=END_S)
        return self.proc.returncode, err

    def close(self) -> None:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()


@pytest.fixture()
def tiny(tmp_path):
    started = []

    def start(mode: str) -> Tiny:
        started.append(Tiny(tmp_path, mode))
        return started[-1]

    yield start
    for t in started:
        t.close()


def _kinds(events: list[dict]) -> list[str]:
    return [e['event'] for e in events]


@pytest.mark.parametrize('sig', [signal.SIGTERM, signal.SIGINT])
def test_a_stop_signal_ends_in_the_zero_command_and_exit_0(tiny, sig):
    t = tiny('spin')
    t.wait_event('spinning')
    os.kill(t.proc.pid, sig)
    code, err = t.finish()
    assert code == EXIT_OK, err
    events = t.events()
    assert _kinds(events) == ['spinning', 'zero', 'deferred'], events
    zero = events[1]
    assert zero['reason'] == signal.Signals(sig).name
    assert zero['context_ok'] and zero['published']  # while the context was still valid
    assert 'Traceback' not in err


def test_a_stop_signal_during_the_start_is_not_lost(tiny):
    t = tiny('slow_start')
    t.wait_event('constructing')
    os.kill(t.proc.pid, signal.SIGTERM)
    code, err = t.finish()
    assert code == EXIT_OK, err
    events = t.events()
    assert _kinds(events) == ['constructing', 'zero', 'deferred'], events  # never spun
    assert events[1]['reason'] == 'SIGTERM' and events[1]['context_ok']


def test_a_constructor_that_raises_is_one_line_and_exit_2(tiny):
    t = tiny('bad_config')
    code, err = t.finish()
    assert code == EXIT_CONFIG
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('tiny_entry: '), err
    assert 'z9' in lines[0]  # the object it cannot take
    assert t.events() == []  # no node: nothing to zero


def test_a_failing_callback_ends_in_the_zero_command_and_exit_1(tiny):
    t = tiny('fail')
    code, err = t.finish()
    assert code == EXIT_FAILED, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and 'Traceback' not in err, err
    events = t.events()
    assert _kinds(events) == ['spinning', 'zero', 'deferred'], events
    assert events[1]['context_ok'] and events[1]['published']


def test_a_start_error_in_the_run_is_exit_2_after_the_zero_command(tiny):
    t = tiny('start_error_in_run')
    code, err = t.finish()
    assert code == EXIT_CONFIG
    assert len(err.strip().splitlines()) == 1 and 'can9' in err, err
    assert _kinds(t.events()) == ['zero', 'deferred']
