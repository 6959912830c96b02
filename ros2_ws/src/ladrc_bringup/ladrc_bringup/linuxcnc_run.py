"""``bringup --cnc linuxcnc --job NAME``: a cutting job with LinuxCNC as its CNC.

LinuxCNC (the shipped XY machine configuration of ``ladrc_linuxcnc``, its headless display, its
Z filter) runs the job's G-code: the job's part program post-processed (``ladrc_tools.cam``),
or the job file's own ``gcode:`` program. The bridge (``ladrc_linuxcnc``: its HAL component
inside LinuxCNC, its node on the graph) plays the CNC on the CNC interface; the sim node
(``separate_cnc``: XY, beam and the contours cut from ``cnc/motion``, the world of ``bringup
--separate-cnc``) plays the axis, the sheet and the sensor; the follow node controls; the
recorder records. The run ends when the bridge publishes the job's end (``cnc/job``) and the sim
node has written the job's figures; the last line of output is them, with LinuxCNC's part
(``linuxcnc``: the program, the filter's log, the display's events, the bridge's log) and the
allowance the run had.

**A run that fails says so.** LinuxCNC refusing the program (its interpreter reads it to its
end before the open: an undefined subroutine, a refused ``o<touchoff>`` value) or stopping it
(an error while it runs: the display aborts it, the bridge ends the job) ends the run: one line
on stderr (``bringup: LinuxCNC ...: TEXT (line N of FILE)``), the figures' ``finished`` false,
``aborted`` and ``linuxcnc.program_error`` (text, line, when, seconds after the open or the
cycle start) saying it, exit 1. A program that cut nothing (0 pierces) is not finished either
(the bridge's rule), nor one whose run pierced fewer times than LinuxCNC's interpreter counted
cut requests in it before the run (LinuxCNC went idle before its end): one line, exit 1.

A G-code job's ``dxf_origin_mm`` (where its program's (0, 0) lies on the sheet) is LinuxCNC's
G54 work offset; a post-processed program is written in the sheet's coordinates (offset 0).

Order: LinuxCNC first (homed, the program open: it waits for the height controller's
``ladrc.height-ready`` before cycle start), then the nodes; at the end the follow node first
(zero command), the sim, the recorder, the bridge, then LinuxCNC (by PID, its shared memory
cleaned: ``ladrc_linuxcnc.machine``).

**Time**. LinuxCNC runs by its own clock: these runs are free-running (lock
step is refused). ``--allowance`` (default: ``config/linuxcnc_allowance.yaml``) widens the
simulation-side timing guards for these runs only (the sim drive's watchdog, the controller's
stale-input and stale-CNC limits); ``--allowance none`` runs with the product's values. The
figures say which (``allowance``).

**Faults** (``--fault KIND@SECONDS``, seconds after cycle start; the fault matrix's rows):
``kill-linuxcnc`` (every LinuxCNC process SIGKILLed: the bridge sees its component gone, aborts
and lifts the head), ``kill-bridge`` (the bridge node SIGKILLed: the component's safe outputs,
the controller's stale-CNC hold; the run is ended ``FAULT_SETTLE_S`` later), ``estop``
(LinuxCNC's estop while cutting: ``halui.estop.activate``).
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import shutil
import signal
import sys
import tempfile
import time
from typing import Any

from ladrc_contract.node_entry import take_stop_signals
from ladrc_contract.run_log import verdict as run_verdict
import yaml

from .bringup import (
    Bringup,
    NodeSpec,
    default_params_file,
    isolated_env,
    job_figures,
    node_specs,
    run_summary,
)

FAULT_KINDS = ('kill-linuxcnc', 'kill-bridge', 'estop')
SERVO_PRIORITY = 55
"""SCHED_FIFO of LinuxCNC's servo thread in these runs: above the loops (50, their middleware
51), which would otherwise hold it up on two cores (it takes about 10 us a millisecond)."""
COMPONENT_PRIORITY = 52
BRIDGE_PRIORITY = 45
"""SCHED_FIFO of the bridge's HAL component (above the loops: 1 kHz, about 10 % of a core) and
of its node (below the loops: it waits for nothing of theirs; about 20 %, most of it the
middleware taking ``follow/status`` at 2 kHz). At the normal scheduler a LinuxCNC sample can
reach the node about 100 ms late at p99 on a loaded 2-core machine (the sim's nozzle then jumps
along the path when it comes, below 0.7 x the target at ``thin_warped``'s warped corner); at
these priorities about 20 ms (bench/linuxcnc_jobs.py). With the loops (sim
and follow node, about 0.55-0.6 of a core each) the real-time load stays below the kernel's
budget (95 % of each CPU, ``sched_rt_runtime_us``), past which it stops every real-time thread
for up to 50 ms (``RT throttling activated``)."""
PROGRAM_ERROR_END_S = 10.0
"""After LinuxCNC stopped the program, the run waits this long at most for the nodes' end."""
FAULT_SETTLE_S = 4.0
"""After a killed bridge, the run goes on this long (LinuxCNC holds, the controller holds)."""
BRIDGE_KEYS = ('pierce_heights_mm', 'pierce_dwell_s', 'cut_gap_mm', 'thc_delay_s', 'lift_mm',
               'leapfrog', 'honour_override')
"""The job's CNC settings the bridge takes (job/cnc.py ``CncSettings`` -> ``BridgeParams``)."""


class RunError(Exception):
    """The run cannot start; one line, exit 2."""


ALLOWANCE_KEYS: dict[str, tuple[str, ...]] = {
    'controller': (),  # any controller parameter (the parameter set's validation checks them)
    'follow_node': ('stamp_tolerance_s',),
    'sim_node': ('watchdog_timeout_s', 'watchdog_recover_s'),
    'bridge': ('link_timeout_s', 'controller_timeout_s', 'sample_delay_limit_s'),
    'linuxcnc': ('link_timeout_s',),
}
"""The allowance file's sections and the keys each may widen."""


def allowance_file() -> Path:
    """Return the shipped allowance file (install space, else the source tree)."""
    try:
        from ament_index_python.packages import get_package_share_directory

        path = Path(get_package_share_directory('ladrc_bringup')) / 'config' / \
            'linuxcnc_allowance.yaml'
        if path.is_file():
            return path
    except (ImportError, LookupError, ValueError):
        pass
    return Path(__file__).resolve().parents[1] / 'config' / 'linuxcnc_allowance.yaml'


def load_allowance(name: str) -> dict[str, Any]:
    """Return the allowance (``controller``, ``follow_node``, ``sim_node``, ``file``).

    'none': the product's values.
    """
    if name == 'none':
        return {'file': 'none', **{k: {} for k in ALLOWANCE_KEYS}}
    path = allowance_file() if name in ('', 'default') else Path(name)
    try:
        data = yaml.safe_load(path.read_text(encoding='utf-8')) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise RunError(f'--allowance {path}: {" ".join(str(exc).split())[:200]}') from None
    if not isinstance(data, dict) or set(data) - set(ALLOWANCE_KEYS):
        raise RunError(f'--allowance {path}: a mapping of {", ".join(ALLOWANCE_KEYS)}')
    out: dict[str, Any] = {'file': str(path)}
    for section, allowed in ALLOWANCE_KEYS.items():
        values = data.get(section) or {}
        if not isinstance(values, dict) or (allowed and set(values) - set(allowed)):
            raise RunError(f'--allowance {path}: {section}: only {", ".join(allowed)}')
        out[section] = dict(values)
    return out


def params_file(job: Any, base_file: str | None, allowance: dict[str, Any],
                folder: Path) -> str:
    """Write the follow node's parameters: the base set, the job's section, the allowance.

    Through the same validation and stability gate as ``bringup --job`` (one line if bad).
    """
    from ladrc_follow import (
        ParameterError,
        check_gate,
        dotted,
        dump_params,
        load_params,
        params_from_dict,
        params_to_dict,
    )

    try:
        base = load_params(base_file or default_params_file())
        params = check_gate(params_from_dict({**dotted(params_to_dict(base)),
                                              **dotted(job.controller),
                                              **dotted(allowance['controller'])}))
    except ParameterError as exc:
        raise RunError(f'{job.path}: controller (with the allowance): '
                       f'{" ".join(str(exc).split())}') from None
    path = folder / 'job_params.yaml'
    path.write_text(dump_params(params, '/**'), encoding='utf-8')
    return str(path)


def program_file(job: Any, folder: Path, blend_mm: float | None) -> tuple[Path, dict]:
    """Return the program LinuxCNC runs and what it is: the job's G-code, or its post."""
    if job.gcode is not None:
        return job.gcode, {'source': 'gcode', 'file': str(job.gcode)}
    from ladrc_tools.cam.postprocess import PostSettings, postprocess

    settings = PostSettings(**({'blend_mm': blend_mm} if blend_mm is not None else {}))
    bad = settings.problems()
    if bad:
        raise RunError(f'--blend-mm: {bad[0]}')
    result = postprocess(job, settings)
    path = folder / f'{job.name}.ngc'
    path.write_text(result.text, encoding='utf-8')
    return path, {'source': 'post', 'file': str(path), 'lines': result.lines,
                  'hold_stretches': sum(len(h) for h in result.holds_mm), **result.settings}


def bridge_spec(job: Any, socket_path: str) -> NodeSpec:
    """Return the bridge node with the job's pierce stages, heights and feeds."""
    c = job.cnc
    params: dict[str, object] = {'socket_path': socket_path, 'job': job.name,
                                 'thread_priority': BRIDGE_PRIORITY}
    for key in BRIDGE_KEYS:
        value = getattr(c, key)
        params[key] = list(value) if isinstance(value, tuple) else value
    return NodeSpec('ladrc_linuxcnc', 'bridge_node', 'ladrc_bridge', parameters=params)


def last_json(path: Path) -> dict[str, Any]:
    """Return the last line of a log that is a JSON object ({} if none)."""
    try:
        lines = path.read_text(encoding='utf-8', errors='replace').splitlines()
    except OSError:
        return {}
    for line in reversed(lines):
        line = line.strip()
        if line.startswith('{'):
            try:
                value = json.loads(line)
            except ValueError:
                continue
            if isinstance(value, dict):
                return value
    return {}


def parse_fault(text: str | None) -> tuple[str, float] | None:
    """Return ``(kind, seconds)`` of ``--fault KIND@SECONDS``; RunError (one line) if bad."""
    if not text:
        return None
    kind, _, at = text.partition('@')
    try:
        seconds = float(at)
    except ValueError:
        seconds = -1.0
    if kind not in FAULT_KINDS or not 0.0 <= seconds <= 3600.0:
        raise RunError(f'--fault {text}: KIND@SECONDS, KIND one of {", ".join(FAULT_KINDS)}')
    return kind, seconds


def cpu_seconds(pid: int) -> float:
    """Return the CPU time (user + system, its threads included) of a live process [s]."""
    try:
        text = Path(f'/proc/{pid}/stat').read_text()
    except OSError:
        return float('nan')
    f = text[text.rindex(')') + 2:].split()
    return (int(f[11]) + int(f[12])) / os.sysconf('SC_CLK_TCK')


def cpu_shares(procs: dict[str, int], t0: dict[str, float], wall_s: float) -> dict[str, float]:
    """Return each process's CPU share over ``wall_s`` (1.0: one core all the time)."""
    out = {}
    for name, pid in procs.items():
        used = cpu_seconds(pid) - t0.get(name, 0.0)
        if used == used and wall_s > 0:  # (NaN: gone)
            out[name] = round(used / wall_s, 3)
    return out


def hal_snapshot(lc: Any) -> dict[str, Any]:
    """Return LinuxCNC's view now: the bridge component's pins (feed hold, pause, link)."""
    r = lc.halcmd('show', 'pin', 'ladrc')
    out: dict[str, Any] = {}
    for line in r.stdout.splitlines():
        f = line.split()
        if len(f) >= 5 and f[4].startswith('ladrc.'):
            v = f[3]
            out[f[4][6:]] = v == 'TRUE' if v in ('TRUE', 'FALSE') else v
    return out


def main_linuxcnc(args: argparse.Namespace) -> int:
    """Run ``bringup --cnc linuxcnc`` (module docstring); return the exit code."""
    from ladrc_linuxcnc import LinuxCnc, LinuxCncError, RunSettings, missing, render_run_config
    from ladrc_sim import JobError, find_job

    if not args.job:
        print('bringup: --cnc linuxcnc needs --job (LinuxCNC runs a job)', file=sys.stderr)
        return 2
    if args.lockstep:
        print('bringup: --cnc linuxcnc runs free: LinuxCNC keeps its own clock (no lock step; '
              'docs/linuxcnc.md)', file=sys.stderr)
        return 2
    if args.bag and Path(args.bag).exists():
        print(f'bringup: {args.bag} exists; choose a new bag folder', file=sys.stderr)
        return 2
    why = missing()
    if why:
        print(f'bringup: --cnc linuxcnc: {why}', file=sys.stderr)
        return 2
    keep = Path(args.logs) if args.logs else None
    folder = (keep / 'linuxcnc' if keep is not None
              else Path(tempfile.mkdtemp(prefix='bringup-linuxcnc-')))
    try:
        fault = parse_fault(getattr(args, 'fault', None))
        job = find_job(args.job)
        allowance = load_allowance(getattr(args, 'allowance', 'default') or 'default')
        folder.mkdir(parents=True, exist_ok=True)
        params = params_file(job, args.params, allowance, folder)
        program, program_info = program_file(job, folder, getattr(args, 'blend_mm', None))
    except (RunError, JobError, ValueError) as exc:
        if keep is None:
            shutil.rmtree(folder, ignore_errors=True)
        print(f'bringup: {exc}', file=sys.stderr)
        return 2
    ini = render_run_config(folder / 'run', RunSettings(
        program=program, home_xy_mm=job.start_xy,
        work_offset_mm=job.dxf_origin_mm if job.gcode is not None else (0.0, 0.0),
        rapid_mm_s=job.cnc.rapid_mm_s,
        accel_mm_s2=job.cnc.accel_mm_s2, component_priority=COMPONENT_PRIORITY,
        servo_priority=SERVO_PRIORITY,
        extra=({('LADRC', 'LINK_TIMEOUT_S'): allowance['linuxcnc']['link_timeout_s']}
               if 'link_timeout_s' in allowance['linuxcnc'] else {})))
    lc = LinuxCnc(ini)
    log_dir = keep or folder / 'logs'
    figures_file = folder / 'figures.json'
    specs = [s for s in node_specs(args.scenario, params, args.bag, args.loop, args.storage,
                                   job=str(job.path), separate_cnc=True)
             if s.name != 'ladrc_cnc']
    sim = next(s for s in specs if s.name == 'ladrc_sim')
    sim.parameters.update({'figures_file': str(figures_file), **allowance['sim_node']})
    summary_file = folder / 'run.json'  # the follow node's run: every fault with its code
    next(s for s in specs if s.name == 'ladrc_follow').parameters.update(
        {**allowance['follow_node'], 'summary_file': str(summary_file)})
    specs.append(bridge_spec(job, lc.socket_path))
    specs[-1].parameters.update(allowance['bridge'])
    env = isolated_env(args.domain_id)
    stop = take_stop_signals()  # SIGINT/SIGTERM: the nodes are stopped, the run reported
    print(f'bringup: ROS_DOMAIN_ID={env["ROS_DOMAIN_ID"]} job={job.name} cnc=linuxcnc '
          f'allowance={allowance["file"]}', file=sys.stderr)
    up = Bringup(specs, env, log_dir)
    codes: dict[str, int] = {}
    watched: dict[str, int] = {}
    cpu: dict[str, float] = {}
    fault_report: dict[str, Any] = {}
    lc_stop: dict[str, Any] = {}
    error = ''
    try:
        try:
            lc.start(timeout_s=120.0)
        except LinuxCncError as exc:
            error = str(exc)
            raise
        up.start()
        t_start = time.monotonic()
        watched = {n: p.pid for n, p in up.procs.items()}
        watched.update({f'linuxcnc:{_comm(pid)}:{pid}': pid for pid in lc.pids()})
        cpu0 = {n: cpu_seconds(pid) for n, pid in watched.items()}
        deadline = time.monotonic() + args.timeout
        t_run: float | None = None
        fault_done = False
        end_at: float | None = None
        while not stop.stop_requested and time.monotonic() < deadline:
            if up.wait('ladrc_sim', 0.2) is not None:
                break
            if end_at is not None and time.monotonic() > end_at:
                break
            events = lc.events()
            if t_run is None and any(e.get('event') == 'run' for e in events):
                t_run = time.monotonic()
            if end_at is None and any(e.get('event') == 'error' for e in events):
                # LinuxCNC stopped the program: the bridge ends the job (aborted), the sim
                # follows; this bounds the wait for them
                end_at = time.monotonic() + PROGRAM_ERROR_END_S
            if fault and not fault_done and t_run is not None \
                    and time.monotonic() - t_run >= fault[1]:
                fault_done = True
                fault_report = {'t_wall_s': time.time(), **inject(fault[0], lc, up)}
                fault_report['at_s'] = round(time.monotonic() - t_run, 3)
                if fault[0] == 'kill-bridge':
                    end_at = time.monotonic() + FAULT_SETTLE_S
                    time.sleep(FAULT_SETTLE_S / 2)
                    fault_report['linuxcnc_after'] = hal_snapshot(lc)
            # the bridge ends when its job has (exit 0); the sim node follows it at once
            early = {n: p.returncode for n, p in up.procs.items() if n != 'ladrc_sim'
                     and p.poll() is not None and not (n == 'ladrc_bridge' and p.returncode == 0)
                     and not (fault_done and fault and fault[0] == 'kill-bridge'
                              and n == 'ladrc_bridge')}
            if early:
                print('bringup: a node exited early: ' + ', '.join(
                    f'{n}={c}' for n, c in early.items()), file=sys.stderr)
                error = error or f'a node exited early: {early}'
                break
    except LinuxCncError:
        pass
    finally:
        if watched:
            cpu = cpu_shares(watched, cpu0, time.monotonic() - t_start)
        codes = up.stop(['ladrc_follow', 'ladrc_sim', 'ladrc_recorder', 'ladrc_bridge'])
        lc_stop = lc.stop()
    figures = job_figures(figures_file)
    run = run_summary(summary_file)
    bridge = last_json(log_dir / 'ladrc_bridge.log')
    events = lc.events()
    failed = program_error(events)
    linuxcnc = {
        'program': program_info,
        'filter': next((e.get('log') for e in events if e.get('event') == 'filter'), None),
        'events': [e['event'] for e in events],
        'errors': [e.get('text') for e in events if e.get('event') in ('error',
                                                                      'error_channel')],
        'paused': any(e.get('event') == 'paused' for e in events),
        'estop': any(e.get('event') == 'estop' for e in events),
        'bridge': bridge, 'stop': lc_stop, 'run_dir': str(folder) if keep else None,
        'servo_threads': lc.servo_threads,
        'cpu_share': cpu,
        **({'error': error} if error else {}),
        **({'program_error': failed} if failed else {}),
    }
    if fault_report:
        linuxcnc['fault'] = fault_report
    if keep is None:
        shutil.rmtree(folder, ignore_errors=True)
    verdict = ''
    if failed:
        verdict = (f'LinuxCNC {"refused" if failed["when"] == "open" else "stopped"} the '
                   f'program: {failed["text"]} (line {failed["line"]} of {failed["program"]})')
        figures.update(finished=False, aborted=verdict)
    elif figures.get('finished') and early_end(events, bridge):
        verdict = early_end(events, bridge)
        figures.update(finished=False, aborted=verdict)
    elif not error and not bridge.get('pierces', figures.get('pierces')):
        verdict = ('the run cut nothing: 0 pierces ('
                   f'{bridge.get("aborted") or figures.get("aborted") or "no figures"})')
        figures['finished'] = False
    elif error:
        verdict = error
    elif not run:
        verdict = 'the follow node wrote no run summary'
    elif not fault and not run_verdict(run, job.expect_fault)[0]:
        verdict = run_verdict(run, job.expect_fault)[1]
    if verdict:
        print(f'bringup: FAILED: {" ".join(verdict.split())}', file=sys.stderr)
    elif run:
        print(f'bringup: ok: {run_verdict(run, job.expect_fault)[1]}', file=sys.stderr)
    print(json.dumps({'bag': args.bag, 'exit_codes': codes, 'job': job.name, 'cnc': 'linuxcnc',
                      'allowance': allowance,
                      **figures, 'run': run, 'linuxcnc': linuxcnc}, default=str))
    ok = not verdict and all(c in (0, -2, 130) for n, c in codes.items()
                             if not (fault and n == 'ladrc_bridge'))
    return 0 if ok else 1


def early_end(events: list[dict[str, Any]], bridge: dict[str, Any]) -> str:
    """Return why a run that looks finished did not run its program to its end ('' if it did).

    LinuxCNC's interpreter counted the program's cut requests before the run (the display's
    ``check``); the bridge pierced fewer: the program went idle before its end.
    """
    check = next((e for e in events if e.get('event') == 'check'), {})
    expected, pierced = check.get('cut_requests'), bridge.get('pierces')
    if not isinstance(expected, int) or not isinstance(pierced, int) or pierced >= expected:
        return ''
    idle = next((e for e in events if e.get('event') == 'idle'), {})
    return (f'LinuxCNC ended the program before its end: {pierced} of its {expected} cut '
            f'requests reached (motion at line {idle.get("line", "?")} when it went idle)')


def program_error(events: list[dict[str, Any]]) -> dict[str, Any] | None:
    """Return LinuxCNC's refusal or stop of the program from the display's events, or None.

    ``text``, ``line`` (of the program's file), ``when`` (``open``: its interpreter refused the
    program before the run; ``run``), ``program``, and ``after_s``: seconds from the program's
    filter (open) or the cycle start (run) to the display's error line.
    """
    err = next((e for e in events if e.get('event') == 'error' and 'line' in e), None)
    if err is None:
        return None
    ref = next((e for e in events if e.get('event') == ('run' if err.get('when') == 'run'
                                                         else 'filter')), None)
    return {'text': err.get('program_error', err.get('text', '')), 'line': err.get('line'),
            'when': err.get('when', ''), 'program': err.get('program', ''),
            'after_s': round(float(err['t']) - float(ref['t']), 3) if ref else None}


def _comm(pid: int) -> str:
    try:
        return Path(f'/proc/{pid}/comm').read_text().strip()
    except OSError:
        return '?'


def inject(kind: str, lc: Any, up: Bringup) -> dict[str, Any]:
    """Inject a fault of the matrix (module docstring); return what was done."""
    if kind == 'kill-linuxcnc':
        return {'kind': kind, 'killed_pids': lc.kill()}
    if kind == 'kill-bridge':
        proc = up.procs['ladrc_bridge']
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        return {'kind': kind, 'killed_pid': proc.pid}
    r = lc.halcmd('setp', 'halui.estop.activate', '1')
    time.sleep(0.3)
    lc.halcmd('setp', 'halui.estop.activate', '0')
    return {'kind': kind, 'halcmd': r.returncode, 'stderr': r.stderr.strip()[-200:]}
