"""Helpers of the LinuxCNC tests (tests/linuxcnc): a job, a bring-up run, its verdict, a client.

:class:`Client` is the bridge node's side of the HAL component's socket, driven by a test.

``bringup --cnc linuxcnc`` runs free (LinuxCNC keeps its own clock): a stall of a loop process
can trip a timing guard of the simulation (the sim drive's watchdog, the controller's
stale-input limit, its stamp tolerance; the allowance widens them, docs/linuxcnc.md "Time").
Such a run ends early, safely: the controller faults, LinuxCNC holds its feed and pauses.
:func:`timing_abort` recognises it by the product's codes, so that a test can check the safety
of every run and ask for the job's end from a run that no guard stopped (:data:`ATTEMPTS` at
most), saying how many it took.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
import socket
import subprocess
import sys
import time

from ladrc_linuxcnc import protocol as p
import pytest

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / 'tests' / 'data' / 'linuxcnc'
ATTEMPTS = 8
"""Runs a test may take to get one that no timing guard stopped (a stopped run ends within
seconds, safely). The budget's basis: under ``make test`` beside the other lane, with and
without two busy loops, the sim drive's 20 ms watchdog (the allowance) stopped up to about half
of these runs at their first pierce; with p = 0.5 the chance that 8 runs in a row are stopped
is 0.4 %. Every stopped run is checked for safety and reported; any other end fails at once.
Each run is counted in .test-logs/attempts.log (docs/testing.md, "Runs started again")."""
LINK_GUARDS = ('linuxcnc_late', 'linuxcnc_gone', 'controller_gone')
"""The bridge's link guards (ladrc_linuxcnc.sequence.ABORT_CODES) a stall can trip."""

SMALL_JOB = """name: lcnc_small
description: A 60 x 40 mm part with a round and a square hole on a wavy 100 x 70 mm sheet.
dxf: small.dxf
sheet:
  width_mm: 100
  height_mm: 70
  surface: {tilt_x: 0.0005, wave_amp_mm: 0.2, wave_length_mm: 60}
cut: {kerf_mm: 0.2, lead_in_mm: 2.0}
cnc: {feed_mm_s: 120, rapid_mm_s: 500, accel_mm_s2: 2000, cut_gap_mm: 1.0,
      pierce_heights_mm: [3.0, 2.0], pierce_dwell_s: [0.05, 0.05], thc_delay_s: 0.05,
      lift_mm: 6.0, leapfrog: true}
sensor: {noise_std_mm: 0.003, quant_mm: 0.001}
start_xy: [5.0, 5.0]
seed: 7
"""


CONTACT = 'expect_fault: true\ncontact: {nth_cut: 2, after_s: 0.3, rise_mm: 4.0}\n'
"""The job keys of a collision injected 0.3 s into the second contour's cut."""


def small_job(folder: Path, small_holes: int = 0, contact: bool = False) -> Path:
    """Write a 6 s job (three contours: a round and a square hole, the outline); its file.

    ``small_holes`` (up to 12): as many 5 mm holes more, in two rows beside the others, each
    a pierce and a leapfrog more (about 0.7 s each): a job that lasts while a fault is
    injected at a time of the bring-up's, which a loaded machine can delay by seconds.
    ``contact``: the material rises under the nozzle 0.3 s into the second contour's cut
    (:data:`CONTACT`), a collision the job declares.
    """
    import ezdxf

    doc = ezdxf.new('R2010')
    doc.header['$INSUNITS'] = 4  # mm
    msp = doc.modelspace()
    msp.add_lwpolyline([(20, 15), (80, 15), (80, 55), (20, 55)], close=True)
    msp.add_circle((35, 35), 6)
    msp.add_lwpolyline([(55, 28), (67, 28), (67, 42), (55, 42)], close=True)
    for k in range(min(small_holes, 12)):
        msp.add_circle((26 + 10 * (k % 6), 21 if k < 6 else 49), 2.5)
    folder.mkdir(parents=True, exist_ok=True)
    doc.saveas(str(folder / 'small.dxf'))
    (folder / 'small.yaml').write_text(SMALL_JOB + (CONTACT if contact else ''),
                                       encoding='utf-8')
    return folder / 'small.yaml'


def bringup_linuxcnc(job: str | Path, logs: Path, *extra: str, timeout_s: float = 600.0,
                     env: dict | None = None) -> tuple[int, dict, str]:
    """Run ``bringup --cnc linuxcnc --job JOB``; return (exit code, last line, stderr tail)."""
    cmd = ['bringup', '--cnc', 'linuxcnc', '--job', str(job), '--logs', str(logs),
           '--timeout', str(int(timeout_s)), *extra]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s + 180,
                       env=dict(os.environ) if env is None else env, check=False)
    lines = [ln for ln in r.stdout.strip().splitlines() if ln.startswith('{')]
    last = json.loads(lines[-1]) if lines else {}
    return r.returncode, last, r.stderr[-3000:]


def first_fault(figures: dict) -> dict:
    """Return the follow node's first fault of the run (code, reason, time), {} if none."""
    faults = (figures.get('run') or {}).get('faults') or []
    return faults[0] if faults else {}


def timing_abort(figures: dict) -> bool:
    """Return whether a timing guard stopped the run, by the product's codes (never by text).

    Every node exited cleanly, and either the follow node's first fault has a timing-guard
    ``FaultCode`` (ladrc_contract.codes.TIMING_GUARDS: stale input, the loop's timing, the
    drive's watchdog) or, with no fault of the controller, the bridge aborted on one of its
    link guards (:data:`LINK_GUARDS`). A crash or any other code is not a timing guard.
    """
    if any(c not in (0, -2, 130) for c in figures.get('exit_codes', {}).values()):
        return False
    fault = first_fault(figures)
    if fault:
        return bool(fault.get('timing_guard'))
    code = figures.get('linuxcnc', {}).get('bridge', {}).get('aborted_code', '')
    return code in LINK_GUARDS


def summary(figures: dict) -> str:
    """Return the figures a test prints (one line)."""
    keys = ('job_time_s', 'pierces', 'contacts', 'faults', 'min_gap_over_target_cutting',
            'holds', 'finished', 'aborted')
    lc = figures.get('linuxcnc', {})
    b = lc.get('bridge', {})
    return json.dumps({**{k: figures.get(k) for k in keys},
                       'linuxcnc': {k: lc.get(k) for k in ('events', 'fault')},
                       'bridge': {k: b.get(k) for k in ('pierces', 'holds', 'leapfrogs',
                                                        'moved_before_ready', 'fault_holds',
                                                        'linuxcnc_max_gap_ms', 'aborted')}})


def report(line: str) -> None:
    """Print a line the test log keeps (pytest -rA / the captured output).

    With ``LADRC_TEST_REPORT`` set (scripts/run-tests: .test-logs/attempts.log) the line is
    also appended there after the test's id: the runs and the runs a timing guard stopped,
    counted over every ``make test``, are the measured basis of :data:`ATTEMPTS`.
    """
    print(line, file=sys.stderr, flush=True)
    path = os.environ.get('LADRC_TEST_REPORT')
    if path:
        test = os.environ.get('PYTEST_CURRENT_TEST', '?').split(' ')[0]
        with open(path, 'a', encoding='utf-8') as f:
            f.write(f'{test} {line}\n')


class Client:
    """The bridge node's side of the socket, driven by the test."""

    def __init__(self, path: str) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.connect(path)
        self.sock.setblocking(False)
        self.reader = p.FrameReader()
        self.samples: list[tuple[float, p.LcncSample]] = []
        self.hello: dict = {}
        self.flags = p.O_HEIGHT_READY
        self.seq = 0
        self.silent = False

    def run_until(self, condition, timeout_s: float, what: str) -> None:
        """Exchange frames until ``condition(last sample)``; fail after ``timeout_s``."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            try:
                data = self.sock.recv(1 << 16)
                assert data, 'the component closed the socket'
                self.reader.feed(data)
            except BlockingIOError:
                pass
            for kind, value in self.reader.frames():
                if kind == p.SAMPLE:
                    self.samples.append((time.monotonic(), value))
                elif kind == p.HELLO:
                    self.hello = value
            if not self.silent:
                self.seq += 1
                self.sock.sendall(p.HalOutputs(self.seq, 1.0, self.flags, 0).pack())
            if self.samples and condition(self.samples[-1][1]):
                return
            time.sleep(0.001)
        last = self.samples[-1][1].as_dict() if self.samples else None
        pytest.fail(f'{what}: not within {timeout_s:g} s; last sample {last}')

    def since(self, t: float) -> list[p.LcncSample]:
        return [s for ts, s in self.samples if ts >= t]


def resume(lc) -> None:
    """Resume the program as the operator does (``halui.program.resume``, its rising edge)."""
    for v in ('1', '0'):
        r = lc.halcmd('setp', 'halui.program.resume', v)
        assert r.returncode == 0, r.stderr
        time.sleep(0.05)


def hal_u32(lc, pin: str) -> int:
    r = lc.halcmd('getp', pin)
    assert r.returncode == 0, r.stderr
    return int(r.stdout.split()[0])
