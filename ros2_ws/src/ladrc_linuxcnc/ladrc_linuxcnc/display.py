#!/usr/bin/python3
"""The headless display of the LADRC laser's LinuxCNC (its ``[DISPLAY]DISPLAY``; system Python).

LinuxCNC starts its display last and shuts down when the display exits; this one has no
window. It plays the operator of an unattended run, with LinuxCNC's ``linuxcnc`` module:

1. estop reset, machine on, home all joints (immediate homing to the job's start point);
2. the program's ``[FILTER]`` (the INI's, by extension, as AXIS runs it; here the Z filter,
   ``z_filter.py``): its output is the program LinuxCNC reads, its log goes to the status file;
3. LinuxCNC's interpreter reads the program to its end (below); auto mode, open it;
4. wait for the height controller: the bridge's ``ladrc.height-ready`` pin (cycle start's
   permissive), at most ``[LADRC]READY_TIMEOUT_S``; then cycle start;
5. watch: pauses (the bridge pauses the program on a FAULT), estop, machine off, messages on
   LinuxCNC's error channel, the program's end; then exit ``[LADRC]LINGER_S`` after the end
   when ``[LADRC]EXIT_AT_END`` is 1, else stay until stopped (SIGTERM).

**A program error.** Before the open, LinuxCNC's interpreter reads the filtered program to its
end (:func:`check_program`, as AXIS's preview): an error (an undefined subroutine, an arc
without a centre, ``o<touchoff>`` refusing a value) refuses the program before anything runs.
While it runs, an error on LinuxCNC's error channel (the interpreter's, task's, motion's: a
move past the machine's limits) sets ``ladrc.program-error`` (the bridge ends the job,
aborted) and aborts the program (LinuxCNC would otherwise run out the moves it had queued).
Either ends in an ``error`` line with LinuxCNC's text, the program's ``line`` (the filtered
program has the file's lines) and ``when`` (``open``, ``run``), and exit 1. A program that
never runs (idle :data:`START_GRACE_S` after cycle start) ends too: it cannot hang the run.

Every step is a JSON line in ``[LADRC]STATUS_FILE`` (``{"t": wall time, "event": ..., ...}``):
the bring-up waits for ``ready`` before it starts the ROS nodes and reads the rest into the
run's figures. A step that fails is an ``error`` line and exit 1 (LinuxCNC then shuts down).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
import re
import shlex
import signal
import subprocess
import sys
import time

RUNNING = [True]
START_GRACE_S = 1.0
"""After cycle start, an interpreter idle this long without having run: the program's end."""


NAMED_LINE = re.compile(r'\b(?:from line:|on line) (\d+)')
"""The program line LinuxCNC's own text names: an o-word search (an undefined subroutine) ends
at the file's end and names the call's line (``from line: N``); motion names the move that
would leave the machine's limits (``Linear move on line N would exceed ...``)."""


class ProgramError(RuntimeError):
    """LinuxCNC refused or stopped the program: its text, the program's line, when (open, run)."""

    def __init__(self, text: str, line: int, when: str) -> None:
        m = NAMED_LINE.search(text)
        self.line = int(m.group(1)) if m else int(line)
        self.text = ' '.join(text.split())[:600]
        self.when = when
        super().__init__(self.text + (f' (line {self.line})' if self.line > 0 else ''))


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


def check_program(path: Path, program: Path, initcode: str, status: Status) -> None:
    """Read the program with LinuxCNC's interpreter to its end before it runs, as AXIS's preview.

    ``gcode_path.py`` (the ``gcode`` module, this LinuxCNC's INI: its subroutines) in a process
    of its own. Raises :class:`ProgramError` with the interpreter's error and line, so that a
    program LinuxCNC cannot read to its end (an undefined subroutine, an arc without centre,
    ``o<touchoff>``'s refusal of a value) is refused before anything is cut. A reader that
    cannot run is noted (``check``); LinuxCNC's own run still reads the program.
    """
    import tempfile

    t0 = time.monotonic()
    try:
        with tempfile.TemporaryDirectory(prefix='ladrc-check-') as scratch:
            r = subprocess.run([sys.executable, str(Path(__file__).with_name('gcode_path.py')),
                                str(path), initcode], capture_output=True, text=True,
                               timeout=300, check=False, cwd=scratch)
        result = json.loads(r.stdout.strip().splitlines()[-1])
    except (OSError, subprocess.TimeoutExpired, ValueError, IndexError) as exc:
        status('check', program=str(program), checked=False, note=' '.join(str(exc).split())[:200])
        return
    ok = result['result'] <= result['min_error']
    status('check', program=str(program), checked=True, ok=ok, moves=len(result['moves']),
           cut_requests=result.get('cut_requests'), seconds=round(time.monotonic() - t0, 3))
    if not ok:
        raise ProgramError(result['error_text'].replace(str(path), str(program)),
                           int(result['line']), 'open')


def error_messages(channel, with_kind: bool = False) -> list:
    """Return the messages waiting on LinuxCNC's error channel (``(kind, text)`` with kinds)."""
    out = []
    while True:
        msg = channel.poll()
        if not msg:
            return out
        out.append((int(msg[0]), str(msg[1])) if with_kind else str(msg[1]))


def is_error(kind: int) -> bool:
    """Return whether an error channel message is an error (not a text or a display message)."""
    import linuxcnc

    return kind in (linuxcnc.NML_ERROR, linuxcnc.OPERATOR_ERROR)


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
        check_program(path, program, ini.find('RS274NGC', 'RS274NGC_STARTUP_CODE') or '',
                      status)
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
        c.auto(linuxcnc.AUTO_RUN, 0)  # (no wait_complete: it lasts while moves are queued)
        status('run')
        try:
            watch(s, e, status, str(path), str(program))
        except ProgramError:
            hal.set_p('ladrc.program-error', '1')  # the bridge: the job aborted
            c.abort()  # (not the moves LinuxCNC queued before the error)
            c.wait_complete()
            raise
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
    except ProgramError as exc:
        s.poll()
        status('error', text=str(exc), program_error=exc.text, line=exc.line, when=exc.when,
               program=str(program), position_mm=[round(v, 4) for v in s.actual_position[:2]])
        return 1
    except Exception as exc:  # noqa: BLE001 (one line, LinuxCNC shuts down)
        status('error', text=' '.join(str(exc).split())[:600])
        return 1


def watch(s, e, status: Status, opened: str = '', program: str = '') -> None:
    """Follow the run to the program's end (or a stop), writing each change of state.

    Raises :class:`ProgramError` on an error on LinuxCNC's error channel (its line: the one
    LinuxCNC's text names, else the one motion was executing; the text names the program,
    not its filtered copy ``opened``).
    """
    import linuxcnc

    seen_running = False
    last = None
    t_run = time.monotonic()
    while RUNNING[0]:
        s.poll()
        for kind, msg in error_messages(e, with_kind=True):
            if is_error(kind):
                raise ProgramError(msg.replace(opened, program) if opened else msg,
                                   int(s.motion_line), 'run')
            status('error_channel', text=msg, kind=kind)
        state = ('estop' if s.task_state == linuxcnc.STATE_ESTOP
                 else 'off' if s.task_state != linuxcnc.STATE_ON
                 else 'paused' if s.paused
                 else 'idle' if s.interp_state == linuxcnc.INTERP_IDLE
                 else 'running')
        if state != last:
            status(state, line=s.motion_line, read_line=s.read_line, mode=s.task_mode,
                   interp=s.interp_state, exec=s.exec_state, queue=s.queue,
                   position_mm=[round(v, 4) for v in s.actual_position[:2]])
            last = state
        if state in ('running', 'paused'):
            seen_running = True
        elif state == 'idle' and (seen_running or time.monotonic() - t_run > START_GRACE_S):
            return
        elif state in ('estop', 'off') and seen_running:
            return
        time.sleep(0.02)


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
