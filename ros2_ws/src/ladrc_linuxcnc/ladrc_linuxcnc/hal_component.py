#!/usr/bin/python3
"""The bridge's HAL component: LinuxCNC's side of the height controller (system Python).

Run by LinuxCNC itself, from the machine's HAL file (``config/ladrc_xy.hal``)::

    loadusr -Wn ladrc /usr/bin/python3 [LADRC]COMPONENT --socket [LADRC]SOCKET

It must run on the interpreter LinuxCNC's ``hal`` module was built for (the system's Python,
3.11 on Debian 12): the ROS node (:mod:`.bridge_node`) runs in the project's venv, whose Python
may be another minor version that cannot import it. The two talk over a Unix socket this
process listens on (:mod:`.protocol`; one client at a time).

Every ``period_s`` (1 ms) it reads its input pins (the HAL file nets them to LinuxCNC's motion,
spindle, digital-out, analog-out and halui pins: docs/linuxcnc.md has the table; the
program's pierce values come on ``ladrc.pierce-height``, ``pierce-delay``, ``cut-height`` from
M68 E0-E2, and the headless display sets ``ladrc.program-error`` when LinuxCNC stops the
program on an error), sends them to the node as a sample, takes the node's newest outputs and
drives its output pins:

* ``ladrc.at-speed`` -> ``spindle.0.at-speed``: motion waits for it before the first feed move
  after each M3, so the cut starts only once the height controller is ready to move;
* ``ladrc.feed-hold`` -> ``motion.feed-hold`` (through an ``or2`` with the real-time watchdog);
* ``ladrc.adaptive-feed`` -> ``motion.adaptive-feed`` (M52 P1);
* ``ladrc.beam-on``: the laser's gate (``and2`` with the watchdog);
* ``ladrc.height-ready``: the cycle start's permissive (the headless display waits for it);
* ``ladrc.program-pause`` -> ``halui.program.pause``: a pulse per pause the node asks for;
* ``ladrc.heartbeat``: toggles every period; a real-time ``watchdog`` in the servo thread holds
  the feed and closes the beam gate if it stops (this process hung or killed). LinuxCNC's
  ``watchdog`` latches a timeout until ``enable-in`` goes false and true again: this process
  reads ``ok-out`` back (``ladrc.watchdog-ok``) and, finding it tripped (it stalled past
  ``[LADRC]WATCHDOG_S``), counts the trip, pauses a running program as a lost link does and
  re-arms the watchdog (``watchdog-enable`` low for ``REARM_PERIODS`` steps and as long in
  time, then high); while ``ok-out`` stays false ``REARM_RETRY_PERIODS`` after the rising edge
  (the servo thread missed the low phase), the low phase is repeated. The operator resumes.

**Safe outputs.** No node connected, the node silent for ``link_timeout_s``, its stream not
ours, or this process ending: feed hold, no at-speed, beam off, not ready
(:data:`.protocol.SAFE_OUTPUTS`), and if the program runs, one pause. Every exception in the
loop ends in the safe outputs before the process exits.

Standard library and LinuxCNC's ``hal`` and ``linuxcnc`` modules only (no numpy, no ROS).
"""

from __future__ import annotations

import argparse
import errno
import math
import os
from pathlib import Path
import signal
import socket
import sys
import time

if __package__ in (None, ''):  # run as a file by LinuxCNC: the package is beside this file
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ladrc_linuxcnc import protocol as p  # noqa: E402

IN_FLOAT = ('x-mm', 'y-mm', 'current-vel', 'requested-vel', 'actual-vel', 'distance-to-go',
            'feed-override')
IN_S32 = ('motion-type', 'program-line')
IN_PIERCE = ('pierce-height', 'pierce-delay', 'cut-height')
"""The program's pierce (M68 E0/E1/E2, subroutines/touchoff.ngc): mm, s, mm; 0: none given."""
IN_BIT = {'spindle-on': p.F_SPINDLE_ON, 'thc-off': p.F_THC_OFF, 'torch-off': p.F_TORCH_OFF,
          'is-running': p.F_RUNNING, 'is-paused': p.F_PAUSED, 'is-idle': p.F_IDLE,
          'machine-on': p.F_MACHINE_ON, 'estop': p.F_ESTOP, 'homed': p.F_HOMED,
          'in-position': p.F_IN_POSITION, 'feed-hold-in': p.F_FEED_HOLD_IN,
          'at-speed-in': p.F_AT_SPEED_IN, 'beam-gate-in': p.F_BEAM_GATE,
          'program-error': p.F_PROGRAM_ERROR}
OUT_BIT = {'at-speed': p.O_AT_SPEED, 'feed-hold': p.O_FEED_HOLD, 'beam-on': p.O_BEAM,
           'height-ready': p.O_HEIGHT_READY}
SEND_BUFFER_MAX = 64 * 1024  # a node that reads nothing for this much: samples are dropped
REARM_PERIODS = 10  # watchdog-enable low this many steps and periods (several servo periods)
REARM_RETRY_PERIODS = 100  # ok-out still false this long after the rising edge: re-arm again


class Component:
    """The HAL pins and the socket (module docstring)."""

    def __init__(self, name: str, socket_path: str, period_s: float, link_timeout_s: float,
                 pause_pulse_s: float) -> None:
        import hal  # LinuxCNC's: the system Python's (module docstring)

        self.period_s = period_s
        self.link_timeout_ns = int(link_timeout_s * 1e9)
        self.pause_pulse_ns = int(pause_pulse_s * 1e9)
        self.comp = hal.component(name)
        self.pins_in_float = [self.comp.newpin(n, hal.HAL_FLOAT, hal.HAL_IN) for n in IN_FLOAT]
        self.pins_in_s32 = [self.comp.newpin(n, hal.HAL_S32, hal.HAL_IN) for n in IN_S32]
        self.pins_in_pierce = [self.comp.newpin(n, hal.HAL_FLOAT, hal.HAL_IN) for n in IN_PIERCE]
        self.pins_in_bit = [(self.comp.newpin(n, hal.HAL_BIT, hal.HAL_IN), bit)
                            for n, bit in IN_BIT.items()]
        self.pins_out_bit = [(self.comp.newpin(n, hal.HAL_BIT, hal.HAL_OUT), bit)
                             for n, bit in OUT_BIT.items()]
        self.pin_adaptive = self.comp.newpin('adaptive-feed', hal.HAL_FLOAT, hal.HAL_OUT)
        self.pin_pause = self.comp.newpin('program-pause', hal.HAL_BIT, hal.HAL_OUT)
        self.pin_heartbeat = self.comp.newpin('heartbeat', hal.HAL_BIT, hal.HAL_OUT)
        self.pin_watchdog_enable = self.comp.newpin('watchdog-enable', hal.HAL_BIT, hal.HAL_OUT)
        self.pin_link = self.comp.newpin('link-ok', hal.HAL_BIT, hal.HAL_OUT)
        self.pin_dropped = self.comp.newpin('samples-dropped', hal.HAL_U32, hal.HAL_OUT)
        self.pin_safe_trips = self.comp.newpin('safe-trips', hal.HAL_U32, hal.HAL_OUT)
        self.pin_watchdog_ok = self.comp.newpin('watchdog-ok', hal.HAL_BIT, hal.HAL_IN)
        self.pin_watchdog_trips = self.comp.newpin('watchdog-trips', hal.HAL_U32, hal.HAL_OUT)
        self.apply(p.SAFE_OUTPUTS)
        self.comp.ready()
        self.socket_path = socket_path
        try:
            os.unlink(socket_path)
        except FileNotFoundError:
            pass
        self.server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        old = os.umask(0o177)
        try:
            self.server.bind(socket_path)
        finally:
            os.umask(old)
        self.server.listen(1)
        self.server.setblocking(False)
        self.client: socket.socket | None = None
        self.reader = p.FrameReader()
        self.outbuf = bytearray()
        self.outputs = p.SAFE_OUTPUTS
        self.last_outputs_ns = 0
        self.pause_seen = 0       # the node's pause_count already pulsed
        self.pulse_end_ns = 0
        self.safe = True
        self.seq = 0
        self.dropped = 0
        self.safe_trips = 0
        self.watchdog_armed = False  # ok-out seen true since the last (re-)arming
        self.watchdog_trips = 0
        self.rearm_end_ns = 0        # watchdog-enable low until then
        self.rearm_steps = 0         # ... and for this many more steps
        self.running = True
        self.hello = hello_info()

    # ---- pins ------------------------------------------------------------------------------
    def sample(self, now_ns: int) -> p.LcncSample:
        """Read the input pins: the bits first.

        The program's pierce values (M68) are set before its M3, so a sample that shows the
        spindle on shows them too.
        """
        flags = 0
        for pin, bit in self.pins_in_bit:
            if pin.get():
                flags |= bit
        f = [pin.get() for pin in self.pins_in_float]
        s = [pin.get() for pin in self.pins_in_s32]
        pierce = [float(pin.get()) for pin in self.pins_in_pierce]
        if self.safe:
            flags |= p.F_LINK_SAFE
        self.seq += 1
        return p.LcncSample(self.seq, now_ns, *(float(v) for v in f), int(s[0]), int(s[1]),
                            flags, *pierce)

    def apply(self, out: p.HalOutputs) -> None:
        """Drive the output pins from ``out`` (the adaptive feed within 0..1)."""
        for pin, bit in self.pins_out_bit:
            pin.set(bool(out.flags & bit))
        a = out.adaptive_feed
        self.pin_adaptive.set(min(max(a, 0.0), 1.0) if math.isfinite(a) else 0.0)

    # ---- the socket ----------------------------------------------------------------------------
    def accept(self, now_ns: int) -> None:
        """Take a waiting connection (one at a time: a second one is closed at once)."""
        try:
            conn, _ = self.server.accept()
        except (BlockingIOError, InterruptedError):
            return
        if self.client is not None:
            conn.close()
            return
        conn.setblocking(False)
        self.client = conn
        self.reader = p.FrameReader()
        self.outbuf = bytearray(p.pack_hello(self.hello))
        self.last_outputs_ns = 0
        self.outputs = p.SAFE_OUTPUTS
        self.pause_seen = -1  # the node's first frame sets it (no pulse for an old count)

    def drop_client(self) -> None:
        """Close the node's connection (its outputs stop counting)."""
        if self.client is not None:
            try:
                self.client.close()
            except OSError:
                pass
        self.client = None
        self.outbuf = bytearray()

    def exchange(self, sample: p.LcncSample, now_ns: int) -> None:
        """Send the sample, take the node's frames (the newest outputs count)."""
        c = self.client
        if c is None:
            return
        if len(self.outbuf) < SEND_BUFFER_MAX:
            self.outbuf += sample.pack()
        else:
            self.dropped += 1
        try:
            n = c.send(self.outbuf)
            del self.outbuf[:n]
        except (BlockingIOError, InterruptedError):
            pass
        except OSError:
            self.drop_client()
            return
        while True:
            try:
                data = c.recv(65536)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                self.drop_client()
                return
            if not data:  # the node closed (or died)
                self.drop_client()
                return
            self.reader.feed(data)
        try:
            for kind, value in self.reader.frames():
                if kind == p.OUTPUTS:
                    if self.pause_seen < 0:
                        self.pause_seen = value.pause_count
                    self.outputs = value
                    self.last_outputs_ns = now_ns
        except ValueError:  # not our protocol: that client is nobody's
            self.drop_client()

    # ---- one period --------------------------------------------------------------------------
    def step(self, now_ns: int) -> None:
        """One period: inputs out, outputs in, pins driven (safe when the link is not up)."""
        self.accept(now_ns)
        sample = self.sample(now_ns)
        self.exchange(sample, now_ns)
        live = (self.client is not None and self.last_outputs_ns > 0
                and now_ns - self.last_outputs_ns <= self.link_timeout_ns)
        watchdog_ok = bool(self.pin_watchdog_ok.get())
        period_ns = int(self.period_s * 1e9)
        enable_low = now_ns < self.rearm_end_ns or self.rearm_steps > 0
        if self.watchdog_armed and not watchdog_ok:  # it timed out on us (a stall): latched
            self.watchdog_trips += 1
            self.watchdog_armed = False
            self.rearm_end_ns = now_ns + REARM_PERIODS * period_ns
            self.rearm_steps = REARM_PERIODS
            enable_low = True
            live = False  # a trip as a lost link: safe outputs, a running program paused
        elif watchdog_ok and not enable_low:
            self.watchdog_armed = True
        elif (not self.watchdog_armed and not enable_low and self.watchdog_trips
              and now_ns >= self.rearm_end_ns + REARM_RETRY_PERIODS * period_ns):
            self.rearm_end_ns = now_ns + REARM_PERIODS * period_ns  # the edge was missed
            self.rearm_steps = REARM_PERIODS
            enable_low = True
        if enable_low and self.rearm_steps > 0:
            self.rearm_steps -= 1
        running = sample.flag(p.F_RUNNING) and not sample.flag(p.F_PAUSED)
        if live:
            self.apply(self.outputs)
            if self.outputs.pause_count != self.pause_seen and self.pause_seen >= 0:
                self.pause_seen = self.outputs.pause_count
                self.pulse_end_ns = now_ns + self.pause_pulse_ns
        else:
            self.apply(p.SAFE_OUTPUTS)
            if not self.safe:  # the link was lost: the program pauses (once)
                self.safe_trips += 1
                if running:
                    self.pulse_end_ns = now_ns + self.pause_pulse_ns
        self.safe = not live
        self.pin_pause.set(now_ns < self.pulse_end_ns)
        self.pin_link.set(live)
        self.pin_heartbeat.set(not self.pin_heartbeat.get())
        self.pin_watchdog_enable.set(not enable_low)
        self.pin_dropped.set(self.dropped)
        self.pin_safe_trips.set(self.safe_trips)
        self.pin_watchdog_trips.set(self.watchdog_trips)

    def run(self) -> None:
        """Step every ``period_s`` until stopped (a late step is not repeated)."""
        period_ns = int(self.period_s * 1e9)
        deadline = time.monotonic_ns()
        while self.running:
            now = time.monotonic_ns()
            self.step(now)
            deadline += period_ns
            now = time.monotonic_ns()
            if deadline < now - 5 * period_ns:  # far behind (a stall): start again from now
                deadline = now
            if deadline > now:
                time.sleep((deadline - now) * 1e-9)

    def close(self) -> None:
        """Safe outputs, no heartbeat; the socket closed and removed."""
        try:
            self.apply(p.SAFE_OUTPUTS)
            self.pin_link.set(False)
        finally:
            self.drop_client()
            self.server.close()
            try:
                os.unlink(self.socket_path)
            except OSError:
                pass
            try:
                self.comp.exit()
            except Exception:  # noqa: BLE001 (HAL may be going down with LinuxCNC)
                pass


def hello_info() -> dict:
    """Return what the node learns once: this process and the INI's XY limits (mm, s)."""
    info: dict = {'pid': os.getpid(), 'python': sys.version.split()[0]}
    ini_path = os.environ.get('INI_FILE_NAME', '')
    if ini_path:
        try:
            import linuxcnc

            ini = linuxcnc.ini(ini_path)

            def number(section: str, key: str) -> float | None:
                text = ini.find(section, key)
                try:
                    return float(text) if text is not None else None
                except ValueError:
                    return None

            info.update({
                'ini': ini_path,
                'max_velocity_mm_s': number('TRAJ', 'MAX_LINEAR_VELOCITY'),
                'max_accel_mm_s2': number('TRAJ', 'MAX_LINEAR_ACCELERATION'),
                'axis_max_velocity_mm_s': [number(f'AXIS_{a}', 'MAX_VELOCITY') for a in 'XY'],
                'axis_max_accel_mm_s2': [number(f'AXIS_{a}', 'MAX_ACCELERATION')
                                         for a in 'XY'],
            })
        except Exception as exc:  # noqa: BLE001 (the hello is information only)
            info['ini_error'] = str(exc)
    return info


def main(argv: list[str] | None = None) -> int:
    """Entry point (LinuxCNC's loadusr)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--name', default='ladrc', help='the HAL component name [ladrc]')
    ap.add_argument('--socket', required=True, help='the Unix socket the node connects to')
    ap.add_argument('--period-s', type=float, default=0.001)
    ap.add_argument('--link-timeout-s', type=float, default=0.2,
                    help='no outputs from the node for this long: safe outputs [0.2]')
    ap.add_argument('--pause-pulse-s', type=float, default=0.3,
                    help='length of the halui.program.pause pulse [0.3]')
    ap.add_argument('--priority', type=int, default=0,
                    help='SCHED_FIFO priority of this process (0: the normal scheduler)')
    a = ap.parse_args(argv)
    for name, v, lo, hi in (('--period-s', a.period_s, 1e-4, 0.1),
                            ('--link-timeout-s', a.link_timeout_s, 0.005, 10.0),
                            ('--pause-pulse-s', a.pause_pulse_s, 0.05, 5.0)):
        if not lo <= v <= hi:
            print(f'ladrc hal component: {name} {v:g} outside {lo:g}..{hi:g}', file=sys.stderr)
            return 2
    if a.priority > 0:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(a.priority))
        except OSError as exc:
            print(f'ladrc hal component: SCHED_FIFO {a.priority} not applied: '
                  f'{exc.strerror}', file=sys.stderr)
    try:
        comp = Component(a.name, a.socket, a.period_s, a.link_timeout_s, a.pause_pulse_s)
    except OSError as exc:
        why = errno.errorcode.get(exc.errno, '') if exc.errno else ''
        print(f'ladrc hal component: cannot listen on {a.socket}: {exc.strerror or exc} {why}',
              file=sys.stderr)
        return 1

    def _stop(_signum, _frame):
        comp.running = False

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    try:
        comp.run()
    except Exception as exc:  # noqa: BLE001 (every path ends in the safe outputs)
        print(f'ladrc hal component: stopped by {type(exc).__name__}: {exc}', file=sys.stderr)
        return 1
    finally:
        comp.close()
    return 0


if __name__ == '__main__':
    sys.exit(main())
