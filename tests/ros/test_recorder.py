"""The recorder as a real process over DDS: nothing lost at 2 kHz, and a SIGKILL leaves a bag."""

from __future__ import annotations

import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

import pytest

pytest.importorskip('rclpy')
from ladrc_bags import open_bag  # noqa: E402
from ladrc_contract.topics import SEQ_FIELD, TOPIC_TYPES  # noqa: E402
from rosbags.highlevel import AnyReader  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
RECORDER = ROOT / 'ros2_ws' / 'install' / 'ladrc_bags' / 'lib' / 'ladrc_bags' / 'recorder'
PUB = Path(__file__).with_name('recorder_pub.py')

pytestmark = pytest.mark.ros


def _start(cmd: list[str], procs: list) -> subprocess.Popen:
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    procs.append(p)
    return p


@pytest.fixture()
def procs():
    started: list[subprocess.Popen] = []
    try:
        yield started
    finally:
        for p in started:
            if p.poll() is None:
                p.kill()
            p.wait(timeout=10)


def _recorder(bag: Path, procs: list, storage: str = 'mcap') -> subprocess.Popen:
    if not RECORDER.exists():
        pytest.skip('recorder console script not installed (build the workspace)')
    rec = _start([str(RECORDER), '--ros-args', '-p', f'output:={bag}', '-p',
                  f'storage:={storage}', '-p', 'reliable:=true'], procs)
    # its bag exists (empty, valid) once it subscribes: the tests start from there, however
    # long a loaded machine takes to start it
    deadline = time.monotonic() + 120.0
    while not (bag / 'metadata.yaml').exists():
        if rec.poll() is not None:
            raise AssertionError(f'recorder ended: {rec.stderr.read()[-2000:]}')
        assert time.monotonic() < deadline, 'the recorder did not start within 120 s'
        time.sleep(0.05)
    return rec


def _wait_line(p: subprocess.Popen, word: str, timeout_s: float = 60.0) -> str:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        line = p.stdout.readline()
        if line.startswith(word):
            return line
        if not line and p.poll() is not None:
            raise AssertionError(f'publisher ended: {p.stderr.read()[-2000:]}')
    raise AssertionError(f'no {word!r} line from the publisher')


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_records_every_topic_without_loss(tmp_path, procs, storage):
    bag = tmp_path / 'live'
    rec = _recorder(bag, procs, storage)
    pub = _start([sys.executable, str(PUB), '3.0'], procs)
    _wait_line(pub, 'publishing')
    ticks = int(_wait_line(pub, 'done').split()[1])
    assert pub.wait(timeout=30) == 0
    time.sleep(0.5)
    rec.send_signal(signal.SIGINT)
    out, err = rec.communicate(timeout=60)
    assert rec.returncode == 0, err[-2000:]
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary['messages_lost'] == 0 and summary['messages_dropped'] == 0, summary
    for topic in SEQ_FIELD:
        assert summary['messages']['/' + topic] == ticks, (topic, summary)
    assert json.loads((bag / 'recording.json').read_text()) == summary
    with AnyReader([bag]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        counts = {t: i.msgcount for t, i in reader.topics.items()}
        seqs = [reader.deserialize(d, c.msgtype).seq for c, _, d
                in reader.messages([c for c in reader.connections if c.topic == '/sim/truth'])]
    # fully qualified names, as ros2 bag record stores them
    assert types == {'/' + t.lstrip('/'): v for t, v in TOPIC_TYPES.items()}
    assert seqs == list(range(ticks))
    # latched topics published before the recorder started arrive (transient local)
    assert counts['/follow/events'] == 1 and counts['/run/scenario'] == 1
    assert counts['/diagnostics'] >= 1
    with open_bag(bag) as b:
        assert b.seq_loss('follow/status') == (ticks, 0)


def test_sigkill_leaves_a_readable_bag(tmp_path, procs):
    bag = tmp_path / 'killed'
    rec = _recorder(bag, procs)
    pub = _start([sys.executable, str(PUB), '30.0'], procs)
    _wait_line(pub, 'publishing')
    # killed once 4 s have passed and the publisher has sent 4000 ticks (2 s at its rate: a
    # loaded machine slows it)
    start = time.monotonic()
    while int(_wait_line(pub, 'published').split()[1]) < 4000:
        pass
    time.sleep(max(0.0, start + 4.0 - time.monotonic()))
    kill_ns = time.time_ns()
    os.kill(rec.pid, signal.SIGKILL)
    rec.wait(timeout=10)
    pub.kill()
    with open_bag(bag) as b:
        assert b.recovered  # the file has no summary: read by a scan
        stamps = b.columns('follow/status', ['tick'])['timestamp_ns']
        assert b.seq_loss('axis/feedback')[1] == 0
    assert len(stamps) > 1000
    # chunks are flushed every 0.25 s: the bag holds data up to shortly before the kill (well
    # under a second on a quiet machine; the writer's queue on a loaded machine adds to it;
    # a writer that flushed only at its end would leave nothing)
    lag_s = (kill_ns - int(stamps.max())) * 1e-9
    assert lag_s < 3.0, f'last message {lag_s:.2f} s before the kill'
