#!/usr/bin/python3
"""The headless display of the LADRC laser's LinuxCNC (its ``[DISPLAY]DISPLAY``; system Python).

LinuxCNC starts its display last and shuts down when the display exits; this one has no
window. It plays the operator of an unattended run, with LinuxCNC's ``linuxcnc`` module:

1. estop reset, machine on, home all joints (immediate homing to the job's start point);
2. the program's ``[FILTER]`` (the INI's, by extension, as AXIS runs it; here the Z filter,
   ``z_filter.py``): its output is the program LinuxCNC reads, its log goes to the status file;
3. auto mode, open the program (LinuxCNC's own interpreter reads it: errors are LinuxCNC's);
4. wait for the height controller: the bridge's ``ladrc.height-ready`` pin (cycle start's
   permissive), at most ``[LADRC]READY_TIMEOUT_S``; then cycle start;
5. watch: pauses (the bridge pauses the program on a FAULT), estop, machine off, errors on
   LinuxCNC's error channel, the program's end; then exit ``[LADRC]LINGER_S`` after the end
   when ``[LADRC]EXIT_AT_END`` is 1, else stay until stopped (SIGTERM).

Every step is a JSON line in ``[LADRC]STATUS_FILE`` (``{"t": wall time, "event": ..., ...}``):
the bring-up waits for ``ready`` before it starts the ROS nodes and reads the rest into the
run's figures. A step that fails is an ``error`` line and exit 1 (LinuxCNC then shuts down).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
import shlex
import signal
import subprocess
import sys
import time

RUNNING = [True]


class Status:
    """The status file: one JSON line per event, flushed."""

    def __init__(self, path: str) -> None:
        self.file = open(path, 'a', encoding='utf-8') if path else None  # noqa: SIM115

    def __call__(self, event: str, **values) -> None:
        """Write one event."""
        line = json.dumps({'t': round(time.time(), 4), 'event': event, **values})
        if self.file is not None:
            self.file.write(line + '\n')
            self.file.flush()
        print(f'ladrc display: {line}', file=sys.stderr, flush=True)


def wait_for(stat, condition, timeout_s: float, period_s: float = 0.02) -> bool:
    """Poll ``stat`` until ``condition()`` or the timeout (or a stop); return whether it held."""
    end = time.monotonic() + timeout_s
    while RUNNING[0] and time.monotonic() < end:
        stat.poll()
        if condition():
            return True
        time.sleep(period_s)
    return False


def run_filter(ini, program: Path, out_dir: Path, status: Status) -> Path:
    """Run the INI's [FILTER] program for the file's extension; return the file to open."""
    ext = program.suffix.lower().lstrip('.')
    command = ini.find('FILTER', ext) if ext else None
    if not command:
        status('filter', program=str(program), filter='', note='no filter for this extension')
        return program
    out = out_dir / f'{program.stem}.filtered{program.suffix}'
    with open(out, 'wb') as stdout:
        proc = subprocess.run([*shlex.split(command), str(program)], stdout=stdout,
                              stderr=subprocess.PIPE, timeout=120, check=False)
    log = [ln for ln in proc.stderr.decode(errors='replace').splitlines()
           if ln.strip() and not ln.startswith('FILTER_PROGRESS=')]
    if proc.returncode != 0:
        raise RuntimeError(f'filter {command} on {program} exit {proc.returncode}: '
                           + ' '.join(log)[-500:])
    status('filter', program=str(program), filter=command, output=str(out), log=log)
    return out


def error_messages(channel) -> list[str]:
    """Return the messages waiting on LinuxCNC's error channel."""
    out = []
    while True:
        msg = channel.poll()
        if not msg:
            return out
        out.append(str(msg[1]))


def main(argv: list[str]) -> int:
    """Entry point: ``display.py -ini FILE`` (LinuxCNC's display convention)."""
    import hal
    import linuxcnc

    if '-ini' not in argv:
        print('ladrc display: run by linuxcnc with -ini FILE', file=sys.stderr)
        return 2
    ini_path = argv[argv.index('-ini') + 1]
    ini = linuxcnc.ini(ini_path)
    status = Status(ini.find('LADRC', 'STATUS_FILE') or '')
    program = Path(ini.find('LADRC', 'PROGRAM') or '')
    ready_timeout_s = float(ini.find('LADRC', 'READY_TIMEOUT_S') or 120)
    exit_at_end = (ini.find('LADRC', 'EXIT_AT_END') or '0').strip() == '1'
    linger_s = float(ini.find('LADRC', 'LINGER_S') or 2)
    joints = int(ini.find('KINS', 'JOINTS') or 2)

    def _stop(_signum, _frame):
        RUNNING[0] = False

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    s, c, e = linuxcnc.stat(), linuxcnc.command(), linuxcnc.error_channel()
    me = hal.component('ladrc-display')  # (hal.get_value needs this process in HAL)
    me.ready()
    status('start', pid=os.getpid(), ini=ini_path, python=sys.version.split()[0])
    try:
        c.state(linuxcnc.STATE_ESTOP_RESET)
        c.wait_complete()
        c.state(linuxcnc.STATE_ON)
        c.wait_complete()
        if not wait_for(s, lambda: s.task_state == linuxcnc.STATE_ON, 10.0):
            raise RuntimeError(f'machine not on (task state {s.task_state}): '
                               + '; '.join(error_messages(e)))
        c.mode(linuxcnc.MODE_MANUAL)
        c.wait_complete()
        c.teleop_enable(0)
        c.wait_complete()
        c.home(-1)
        c.wait_complete()
        if not wait_for(s, lambda: all(s.homed[:joints]) and s.inpos, 30.0):
            raise RuntimeError(f'not homed within 30 s (homed {list(s.homed[:joints])}): '
                               + '; '.join(error_messages(e)))
        s.poll()
        status('homed', position_mm=[round(v, 4) for v in s.actual_position[:2]])
        if not program.name:
            raise RuntimeError('no [LADRC]PROGRAM to run')
        path = run_filter(ini, program, Path(ini_path).parent, status)
        c.mode(linuxcnc.MODE_AUTO)
        c.wait_complete()
        c.program_open(str(path))
        c.wait_complete()
        time.sleep(0.2)
        s.poll()
        errors = error_messages(e)
        if errors or s.file != str(path):
            raise RuntimeError(f'cannot open {path}: ' + '; '.join(errors))
        status('ready', program=str(program), opened=str(path))
        end = time.monotonic() + ready_timeout_s
        while RUNNING[0] and not hal.get_value('ladrc.height-ready'):
            if time.monotonic() > end:
                raise RuntimeError(f'no height controller (ladrc.height-ready) within '
                                   f'{ready_timeout_s:g} s')
            time.sleep(0.02)
        if not RUNNING[0]:
            status('stopped', before='run')
            return 0
        c.auto(linuxcnc.AUTO_RUN, 0)
        status('run')
        watch(s, e, status)
        s.poll()
        status('end', interp_state=s.interp_state, task_state=s.task_state,
               position_mm=[round(v, 4) for v in s.actual_position[:2]])
        if exit_at_end:
            end = time.monotonic() + linger_s
            while RUNNING[0] and time.monotonic() < end:
                time.sleep(0.05)
        else:
            while RUNNING[0]:
                for msg in error_messages(e):
                    status('error_channel', text=msg)
                time.sleep(0.1)
        status('exit')
        return 0
    except Exception as exc:  # noqa: BLE001 (one line, LinuxCNC shuts down)
        status('error', text=' '.join(str(exc).split())[:600])
        return 1


def watch(s, e, status: Status) -> None:
    """Follow the run to the program's end (or a stop), writing each change of state."""
    import linuxcnc

    seen_running = False
    last = None
    while RUNNING[0]:
        s.poll()
        for msg in error_messages(e):
            status('error_channel', text=msg)
        state = ('estop' if s.task_state == linuxcnc.STATE_ESTOP
                 else 'off' if s.task_state != linuxcnc.STATE_ON
                 else 'paused' if s.paused
                 else 'idle' if s.interp_state == linuxcnc.INTERP_IDLE
                 else 'running')
        if state != last:
            status(state, line=s.motion_line,
                   position_mm=[round(v, 4) for v in s.actual_position[:2]])
            last = state
        if state in ('running', 'paused'):
            seen_running = True
        elif state == 'idle' and seen_running:
            return
        elif state in ('estop', 'off') and seen_running:
            return
        time.sleep(0.02)


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
