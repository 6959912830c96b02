"""``ladrc conform``: start the driver, run the live probe, evaluate the rules, write the output.

:func:`run_conform` is ``ladrc conform``: it starts the driver (the sim node, or a command) on an
isolated DDS domain, runs the probe, ends every process it started by PID, evaluates the rules
(:mod:`ladrc_tools.commissioning.conformance`) and writes report.md, conform.json and the bag
into one output folder (built under a temporary name, renamed when complete).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import json
import os
from pathlib import Path
import shlex
import subprocess
import sys
from typing import Callable

from ladrc_contract.node_entry import stop_signals
from ladrc_tools.commissioning.conformance import (
    ConformanceResult,
    Plan,
    Segment,
    Tolerances,
    evaluate,
    markdown,
    sim_scenario_yaml,
)
from ladrc_tools.offline.outdir import building

from .bringup import (
    MIDDLEWARE_KEYS,
    executable_path,
    interrupt_process,
    isolated_env,
)
from .conform_node import SIGNALLED, ConformError, ConformProbe


@dataclass
class ConformOptions:
    """What ``ladrc conform`` runs against and how."""

    output: Path
    sim: bool = False
    driver_cmd: str | None = None
    plan: Plan = field(default_factory=Plan)
    tolerances: Tolerances = field(default_factory=Tolerances)
    domain_id: int | None = None
    discovery_timeout_s: float = 30.0
    thread_priority: int = 50
    sim_start_gap_mm: float = 5.0
    sim_scenario: str | None = None  # with sim: this scenario file instead of the built-in one
    drive: str = ''  # 'cia402': the emulated CiA 402 drive and its driver node (cia402_stack)
    period_s: float = 0.0005  # with drive: the SYNC period (the tolerances are scaled to it)
    device: str = ''  # with drive: the drive's device file ('' = the shipped drive)


def _tail(path: Path) -> str:
    try:
        lines = [x for x in path.read_text(errors='replace').splitlines() if x.strip()]
    except OSError:
        return ''
    return lines[-1].strip()[:300] if lines else ''


def _start_driver(opts: ConformOptions, folder: Path, env: dict[str, str]
                  ) -> tuple[subprocess.Popen | None, str]:
    if opts.sim or opts.drive:
        scenario = folder / 'sim_scenario.yaml'
        if opts.sim_scenario:
            try:
                text = Path(opts.sim_scenario).read_text(encoding='utf-8')
            except (OSError, UnicodeDecodeError) as exc:
                raise ConformError(f'{opts.sim_scenario}: cannot read the scenario: {exc}'
                                   ) from None
        else:
            text = sim_scenario_yaml(opts.sim_start_gap_mm)
        scenario.write_text(text, encoding='utf-8')
        try:
            exe = executable_path('ladrc_sim', 'sim_node')
        except FileNotFoundError as exc:
            raise ConformError(str(exc)) from None
        # the sim's drive watchdog is the timeout the kit checks (--watchdog-timeout-ms)
        cmd = [exe, '--ros-args', '-p', f'scenario:={scenario}', '-p', 'exit_at_end:=true',
               '-p', f'watchdog_timeout_s:={opts.tolerances.watchdog_timeout_s!r}']
        label = 'the sim node (ladrc_sim sim_node, flat sheet, no follow commands)'
        if opts.drive == 'cia402':
            # the driver node's watchdog is the timeout the kit checks; the drive's own RPDO
            # deadline (10 ms) is behind it
            try:
                exe = executable_path('ladrc_bringup', 'cia402_stack')
            except FileNotFoundError as exc:
                raise ConformError(str(exc)) from None
            cmd = [exe, '--scenario', str(scenario), '--logs', str(folder / 'cia402'),
                   '--watchdog-timeout-s', repr(opts.tolerances.watchdog_timeout_s),
                   '--period-s', repr(opts.period_s)]
            if opts.device:
                cmd += ['--device', opts.device]
            label = ('the CiA 402 driver node (ladrc_cia402 driver_node) and the emulated '
                     'CiA 402 drive (ladrc_sim sim_node drive:=cia402, flat sheet) on the '
                     'test bus')
    elif opts.driver_cmd:
        cmd = shlex.split(opts.driver_cmd)
        if not cmd:
            raise ConformError('--driver-cmd is empty')
        label = opts.driver_cmd
    else:
        return None, f'the running driver on ROS_DOMAIN_ID={env.get("ROS_DOMAIN_ID", "0")}'
    log = open(folder / 'driver.log', 'wb')  # noqa: SIM115 - handed to the child
    try:
        proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, start_new_session=True)
    except OSError as exc:
        raise ConformError(f'cannot start the driver {cmd[0]!r}: {exc.strerror or exc}'
                           ) from None
    finally:
        log.close()
    return proc, label


def run_conform(opts: ConformOptions, log: Callable[[str], None] | None = None
                ) -> tuple[ConformanceResult, Path]:
    """Run ``ladrc conform``; return the result and the output folder."""
    log = log or (lambda text: print(text, file=sys.stderr, flush=True))
    out = Path(opts.output)
    if out.exists():
        raise ConformError(f'{out} exists already: outputs are never overwritten')
    problems = opts.plan.problems()
    if problems:
        raise ConformError('; '.join(problems))
    if sum(map(bool, (opts.sim, opts.driver_cmd, opts.drive))) > 1:
        raise ConformError('give one of --sim, --drive, --driver-cmd')
    if opts.drive not in ('', 'cia402'):
        raise ConformError(f"--drive {opts.drive}: the one offered is 'cia402'")
    if opts.domain_id is not None and not 0 <= opts.domain_id <= 232:
        raise ConformError(f'--domain-id {opts.domain_id}: must be in 0..232')
    own_driver = opts.sim or bool(opts.driver_cmd) or bool(opts.drive)
    if own_driver:
        env = isolated_env(opts.domain_id)
        # this process joins the driver's isolated domain (localhost discovery)
        for key in MIDDLEWARE_KEYS:
            if key in env:
                os.environ[key] = env[key]
        os.environ.pop('ROS_LOCALHOST_ONLY', None)
    else:
        env = dict(os.environ)
        if opts.domain_id is not None:
            env['ROS_DOMAIN_ID'] = os.environ['ROS_DOMAIN_ID'] = str(opts.domain_id)
    domain = int(env.get('ROS_DOMAIN_ID', '0') or 0)
    # SIGINT and SIGTERM both end the run through the same path: zero with enable=false, the
    # driver stopped, nothing written (a background job may even have SIGINT ignored). The
    # first one only: the clean-up that follows (zero commands, stopping the driver) must not
    # be cut. Only a flag here, raised at the probe's next poll: raising from the handler could
    # land inside a C extension call (rclpy's deserialize_message turning it into a TypeError)
    SIGNALLED.clear()
    with stop_signals() as stop:
        stop.on_stop(lambda: SIGNALLED.append(stop.stop_reason))
        return _run(opts, log, out, env, domain)


def _run(opts: ConformOptions, log: Callable[[str], None], out: Path, env: dict[str, str],
         domain: int) -> tuple[ConformanceResult, Path]:
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    with building(out) as tmp:
        proc = None
        probe = None
        rec = None
        stop_code = None
        context = None
        try:
            # everything from the driver's start on is inside the clean-up below
            proc, label = _start_driver(opts, tmp, env)
            log(f'conform: {label} on ROS_DOMAIN_ID={domain}')
            context = rclpy.Context()
            rclpy.init(context=context, domain_id=domain,
                       signal_handler_options=SignalHandlerOptions.NO)
            probe = ConformProbe(context, opts.plan, opts.tolerances, tmp / 'bag', log)
            if opts.thread_priority > 0:
                from ladrc_contract.realtime import apply_realtime

                _, warnings = apply_realtime(opts.thread_priority, [], False)
                for w in warnings:
                    probe.notes.append(w)

            def alive() -> bool:
                return proc is None or proc.poll() is None

            ready = probe.discover(opts.discovery_timeout_s, alive)
            if not alive():
                raise ConformError(f'the driver exited with code {proc.returncode} before the '
                                   f'tests: {_tail(tmp / "driver.log") or "no output"}')
            if not ready:
                probe.notes.append(f'the driver did not show all its endpoints and samples '
                                   f'within {opts.discovery_timeout_s:g} s')
            probe.run()
        finally:
            try:
                if probe is not None:
                    probe.stop_commands(release=True)
                    rec = probe.finish()
            finally:
                if proc is not None:
                    stop_code = interrupt_process(proc, 10.0)
                if probe is not None:
                    probe.destroy()
                if context is not None:
                    rclpy.try_shutdown(context=context)
        if SIGNALLED:  # a signal after the last poll: still nothing written
            raise KeyboardInterrupt(SIGNALLED.pop())
        result = evaluate(rec, opts.tolerances)
        lines = [f'driver: {label}', f'ROS_DOMAIN_ID {domain}',
                 f'commands: {probe.command_qos or "none sent"}',
                 f'plan: {json.dumps(opts.plan.as_dict())}']
        if proc is not None:
            lines.append(f'driver stopped by SIGINT (exit code {stop_code}); its output: '
                         'driver.log')
        result.extra.update({'driver': label, 'domain_id': domain,
                             'driver_pid': proc.pid if proc is not None else None,
                             'driver_exit_code': stop_code,
                             'bag': str(out / 'bag'), 'plan': opts.plan.as_dict(),
                             'tolerances': opts.tolerances.as_dict(),
                             'segments': [_segment_dict(s, rec.segments[0].start_ns)
                                          for s in rec.segments]})
        (tmp / 'report.md').write_text(markdown(result, label, lines, rec.segments),
                                       encoding='utf-8')
        (tmp / 'conform.json').write_text(json.dumps(result.as_dict(), indent=1) + '\n',
                                          encoding='utf-8')
    return result, out


def _segment_dict(s: Segment, t0: int) -> dict:
    return {'name': s.name, 'start_s': round((s.start_ns - t0) * 1e-9, 6),
            'end_s': round((s.end_ns - t0) * 1e-9, 6), 'start_ns': s.start_ns,
            'end_ns': s.end_ns, 'velocity_mm_s': s.velocity_mm_s, 'enable': s.enable,
            'commanded': s.commanded}
