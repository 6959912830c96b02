"""The project's figures, measured by the benches and written to docs/figures.md.

    scripts/in-env python bench/figures.py [--quick] [--only ID,ID] [--list] [--dry-run]
                                           [--out DIR]

Each figure is one row: what it is, its value, the command that prints it, and when, at which
commit and on which machine (cores, CPU) it was measured. The benches (``bench/*.py``) print
their figures as the last line of JSON; this script runs them (all, those marked quick with
``--quick``, or the ones named with ``--only``, with every row their run also fills), takes the
figures out of that line, and writes
``docs/figures.json`` (the data) and ``docs/figures.md`` (the table, rendered from the data),
keeping the rows it did not run as they were. A few figures are printed by a tool of the project
rather than a bench (``ladrc conform``, ``bringup``: ``TOOLS``), run the same way; ``OUT`` in
such a command is a fresh folder of the run. A full run also regenerates docs/quality.md's
suite table (``ladrc suite --law-only``, between ``suite:begin`` and ``suite:end``). The
README's short table (between the
``figures:begin`` and ``figures:end`` markers) is rendered from the same data. Docs that cite a
figure link to its row (``docs/figures.md#<id>``) instead of restating it.

``--quick``: the figures whose benches take seconds; the full run takes hours (the fault
matrix, the long bags, the live benches).
A bench that fails or prints no JSON leaves its rows as they were and is named on stderr;
the exit code is then 1.

Last line: JSON with ``figures`` (ids measured now), ``failed`` (ids whose bench failed),
``wall_s``, ``written`` (the files).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
import datetime as dt
import json
import os
from pathlib import Path
import platform
import re
import subprocess
import sys
import tempfile
import time
from typing import Any, Callable

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / 'docs'
DATA = DOCS / 'figures.json'
TABLE = DOCS / 'figures.md'
README = ROOT / 'README.md'
TOOLS = {'ladrc': 'ladrc_tools.cli', 'bringup': 'ladrc_bringup.bringup'}
"""Figures printed by a tool of the project instead of a bench: the tool's module."""
OUT = '{out}'
"""In a figure's arguments: a fresh folder of the run (``OUT`` in the command shown)."""


def _f(x: Any, nd: int = 3) -> str:
    """Format a number with ``nd`` significant digits (ints, and larger numbers, whole)."""
    if isinstance(x, bool) or x is None:
        return str(x)
    if isinstance(x, int):
        return f'{x:,}'.replace(',', ' ')
    if abs(x) >= 10 ** nd:  # whole units rather than an exponent
        return f'{x:,.0f}'.replace(',', ' ')
    return f'{x:.{nd}g}'


def _span(values: list, nd: int = 3) -> str:
    """Return ``a–b`` for the least and largest of ``values`` (``a`` when equal, ``–`` if none)."""
    vals = [v for v in values if isinstance(v, (int, float)) and not isinstance(v, bool)]
    if not vals:
        return '–'
    lo, hi = _f(min(vals), nd), _f(max(vals), nd)
    return lo if lo == hi else f'{lo}–{hi}'


def _grouped(rows: list[dict], key: str, item: Callable[[dict], str]) -> str:
    """Render rows grouped by ``row[key]`` in first-seen order: ``group: item, item; ...``."""
    groups: dict[str, list[str]] = {}
    for x in rows:
        groups.setdefault(str(x[key]), []).append(item(x))
    return '; '.join(f'{g}: {", ".join(items)}' for g, items in groups.items())


def _short_setting(setting: str) -> str:
    """Shorten a nonlinear-observer setting's name (``fal on the disturbance, δ 10 µm`` ...)."""
    return (setting.replace(' (shipped)', '').replace('fal on the disturbance, δ ', 'fal δ')
            .replace('fal on all (NESO), δ ', 'NESO δ').replace(', ', ' '))


def _state(n: Any) -> str:
    """Return the follow state's name (``FollowStatus.STATE_*``), the number if unknown."""
    try:
        from ladrc_contract.codes import FollowState

        return FollowState(n).name
    except (ImportError, ValueError, TypeError):
        return str(n)


def _hold(run: dict, kind: str, what: str = 'count') -> Any:
    """Return a job run's hold figure (``holds``: corner_lock, void_lock, hold, edge_ahead)."""
    return ((run.get('holds') or {}).get(kind) or {}).get(what)


CONFORM = (('rate', 'rate', ' Hz', 4), ('jitter', 'arrival p99', ' ms', 3),
           ('seq_increments', 'wrong seq steps', '', 3),
           ('stamps_not_future', 'stamp after reception at most', ' ms', 2),
           ('stamp_age', 'stamp age median', ' ms', 2), ('drive_ready', 'gap', ' mm', 4),
           ('enable_false_holds', 'travel with enable false', ' mm', 3),
           ('motion_speed', 'encoder slope / command', '', 4),
           ('velocity_feedback', 'velocity feedback / encoder slope', '', 4),
           ('gap_tracks_encoder', 'gap / encoder slope', '', 4),
           ('watchdog_fault', 'watchdog fault after', ' ms', 3),
           ('watchdog_stop', 'at rest after', ' ms', 3),
           ('one_commander', 'second commander refused after', ' ms', 3),
           ('motion_bag', 'bag', ' messages', 6))
"""The conformance rules a figure row shows: rule, what its figure is, unit, digits."""


def _conform(r: dict) -> str:
    """Render ``ladrc conform``'s last line: the verdict, then each rule's figure."""
    figs = r['figures']
    failed = f' (failed: {", ".join(r["rules_failed"])})' if r['rules_failed'] else ''
    return (f'{r["rules_passed"]} of {r["rules_total"]} rules passed{failed}; '
            + ', '.join(f'{what} {_f(figs[k], nd)}{unit}' for k, what, unit, nd in CONFORM
                        if k in figs))


def _pair(values: list, nd: int = 3) -> str:
    """Return ``first / span of the rest``: a headless figure beside its live runs'."""
    return f'{_f(values[0], nd)} / {_span(values[1:], nd)}'


def _linuxcnc_side(r: dict) -> str:
    """Each job headless vs its LinuxCNC runs to the end (``bench/linuxcnc_jobs.py``)."""
    out = []
    for n, e in r['jobs'].items():
        lc = [x for rs in e['linuxcnc'].values() for x in rs if x.get('finished')]
        if not lc:
            out.append(f'{n}: no LinuxCNC run to its end')
            continue
        runs = [e['headless'], *lc]
        holds = {k: _pair([_hold(x, k) for x in runs])
                 for k in ('corner_lock', 'hold', 'edge_ahead', 'void_lock')}
        out.append(
            f'{n} (headless / LinuxCNC, {len(lc)} runs): job '
            f'{_pair([x.get("job_time_s") for x in runs], 4)} s, corner lock '
            f'{holds["corner_lock"]} holds, commanded hold (M62 P2) {holds["hold"]}, edge ahead '
            f'{holds["edge_ahead"]}, void lock {holds["void_lock"]}, corner excursion '
            f'{_pair([x.get("corner_max_down_mm") for x in runs])} mm, min true gap / target '
            f'{_pair([x.get("min_gap_over_target_cutting") for x in runs])}')
    return '; '.join(out)


def _job_run(x: dict) -> str:
    """One job run's figures: to the end or why not, time, contacts, closest approach."""
    end = 'to the end' if x.get('finished') else f'aborted ({str(x.get("aborted"))[:80]})'
    return (f'{end}, {_f(x.get("job_time_s"), 4)} s, {x.get("pierces")} pierces, '
            f'{x.get("contacts")} contacts, {x.get("faults")} faults, min true gap / target '
            f'{_f(x.get("min_gap_over_target_cutting"))}, corner excursion '
            f'{_f(x.get("corner_max_down_mm"))} mm, corner lock {_hold(x, "corner_lock")} '
            f'({_f(_hold(x, "corner_lock", "seconds"))} s), void lock {_hold(x, "void_lock")}')


def _fault_rows_linuxcnc(r: dict) -> str:
    """Render the LinuxCNC rows of the fault matrix (``--only linuxcnc``)."""
    rows = [
        f'{x["row"]}: {"CONTACT" if x.get("contact") else "no contact"}, down '
        f'{_f(x.get("down_after_mm"))} mm and up {_f(x.get("lift_mm"))} mm after the fault, '
        f'controller {_state(x.get("final_state"))}'
        + (', held on the stale CNC' if x.get('stale_hold') else '')
        + f', LinuxCNC paused {x.get("paused")}, feed hold {x.get("feed_hold")}, link ok '
          f'{x.get("link_ok")}, job aborted: {str(x.get("job_aborted"))[:60]}'
        for x in r['rows']]
    if r.get('linuxcnc_rows_not_run'):
        rows.append(f'{r["linuxcnc_rows_not_run"]} rows not run')
    return '; '.join(rows)


def _linuxcnc_safety(r: dict) -> str:
    """Render each job's verdict under LinuxCNC, the bridge's timing, why runs stopped."""
    out = []
    for n, e in r['jobs'].items():
        runs = [x for rs in e['linuxcnc'].values() for x in rs]
        stopped = ''.join(
            f', {k} stopped: ' + ' / '.join(str(x.get('aborted'))[:50] for x in rs
                                             if not x.get('finished'))
            for k, rs in e['linuxcnc'].items() if any(not x.get('finished') for x in rs))
        out.append(
            f'{n}: {e["verdict"] or "ok"}, moved before ready '
            f'{sum(x.get("bridge_moved_before_ready") or 0 for x in runs)}, samples late p99 '
            f'{_span([x.get("bridge_sample_delay_ms_p99") for x in runs])} ms, component gap '
            f'max {_span([x.get("bridge_component_max_gap_ms") for x in runs])} ms{stopped}')
    return '; '.join(out) + f'; all ok: {r["all_ok"]}'


def _fleet_flags(r: dict) -> str:
    """Render the flags of ``bench/fleet_scaling.py`` against the fleet's truth."""
    deg = r['degraded_flagged']
    return (f'degraded machines flagged by their rule: {sum(d["found"] for d in deg.values())} '
            f'of {len(deg)} ('
            + ', '.join(f'{d["how"]}: {" + ".join(d["flagged_by"]) or "none"}'
                        for d in deg.values())
            + f'); healthy machines flagged: {len(r["healthy_flagged"])}'
            + ''.join(f', {m}: {" + ".join(v)}' for m, v in r['healthy_flagged'].items()))


def _interval(r: dict) -> str:
    """Render ``bench/identified_plant.py``'s error RMS ranges over the ±1σ interval."""
    law = {'ladrc': 'LADRC', 'pid': 'PID'}
    return '; '.join(
        f'{k.removesuffix("_rms_range_mm").rsplit("_", 1)[0]}, '
        f'{law.get(k.removesuffix("_rms_range_mm").rsplit("_", 1)[1], "?")}: '
        f'{_f(v[0])}–{_f(v[1])} mm' for k, v in r.items() if k.endswith('_rms_range_mm'))


@dataclass(frozen=True)
class Figure:
    """One figure: its id (the row's anchor), what it is, the bench and how to read it."""

    id: str
    label: str
    bench: str
    args: tuple[str, ...]
    value: Callable[[dict], str]
    quick: bool = False
    readme: bool = False  # in the README's short table


FIGURES: tuple[Figure, ...] = (
    Figure('core-step', 'full controller step (TD + ESO + Kalman + law + limits), scalar, '
           'plain Python', 'core_step', (),
           lambda r: f'{_f(r["scalar_step_us"])} µs; batch of 1000 sets '
                     f'{_f(r["batch_realtime_x"]["1000"])}× real time', quick=True, readme=True),
    Figure('headless-speed', 'headless closed loop, full controller, showcase', 'headless_speed',
           ('--repeat', '1'),
           lambda r: f'{_f(r["realtime_x"])}× real time, {_f(r["us_per_tick"])} µs per tick',
           quick=True, readme=True),
    Figure('cia402-units', "CiA 402 path vs the simulator's drive: error RMS, each integer "
           'unit', 'cia402_units', (),
           lambda r: '; '.join(
               f'{s}: all {100 * v["all"]["relative"]:+.2f} % (analog counts '
               f'{100 * v["gap_counts"]["relative"]:+.2f} %, command units '
               f'{100 * v["velocity_units"]["relative"]:+.3f} %, power-up '
               f'{100 * v["power_up"]["relative"]:+.2f} %)' for s, v in r['scenarios'].items()),
           quick=True),
    Figure('paper-eso-compensator', 'paper §5.1, max |x2 error| LESO → LESO+D away from the '
           'kinks of |cos t|', 'paper_eso_compensator', (),
           lambda r: f'{_f(r["leso_x2_err_away"])} → {_f(r["leso_d_x2_err_away"])} '
                     f'(paper {_f(r.get("paper_leso_x2_err", float("nan")))} → '
                     f'{_f(r.get("paper_leso_d_x2_err", float("nan")))})', quick=True),
    Figure('paper-eso-frequency', 'paper §4 (Fig. 2), Ω where the compensation is lost',
           'paper_eso_frequency', (),
           lambda r: f'{_f(r["omega_0p1db_i3"], 4)} / {_f(r["omega_0p1db_i4"], 4)} '
                     f'(i = 3 / 4; paper {_f(r["omega_lost_paper"])})', quick=True),
    Figure('job-speed', 'headless cutting jobs', 'job_speed', ('--repeat', '1'),
           lambda r: f'{_f(r["realtime_x_min"])}× real time at least (target '
                     f'{_f(r["target_x"])}×)', quick=True),
    Figure('jobs-headless',
           'shipped jobs headless: job time, pierces, contacts, faults, least gap / target',
           'live_jobs',
           ('--lockstep', '--jobs', 'plate_holes', 'tipping_pair'),
           lambda r: '; '.join(
               f'{n}: {_f(j["headless"]["job_time_s"], 4)} s, {j["headless"]["pierces"]} '
               f'pierces, {j["headless"]["contacts"]} contacts, {j["headless"]["faults"]} '
               f'faults, {_f(j["headless"]["min_gap_over_target_cutting"])}'
               for n, j in r['jobs'].items())),
    Figure('jobs-lockstep', 'shipped jobs live in lock step (unpaced, recorder): verdict, '
           'figures equal to headless, speed', 'live_jobs',
           ('--lockstep', '--jobs', 'plate_holes', 'tipping_pair'),
           lambda r: '; '.join(
               f'{n}: {j["verdict"]}, '
               + ('equal' if all(j['live'].get(k) == v for k, v in j['headless'].items())
                  else 'differs')
               + f', {_f(j["live"]["realtime_x"])}× real time' for n, j in r['jobs'].items())),
    Figure('jobs-lockstep-separate', 'shipped jobs live in lock step with the CNC node '
           '(--separate-cnc)', 'live_jobs',
           ('--lockstep', '--separate-cnc', '--jobs', 'plate_holes', 'tipping_pair'),
           lambda r: '; '.join(
               f'{n}: {j["verdict"]}, '
               + ('equal' if all(j['live'].get(k) == v for k, v in j['headless'].items())
                  else 'differs')
               + f', {_f(j["live"]["realtime_x"])}× real time' for n, j in r['jobs'].items())),
    Figure('jobs-free', 'shipped jobs live, free-running (real time)', 'live_jobs',
           ('--jobs', 'plate_holes', 'tipping_pair'),
           lambda r: '; '.join(
               f'{n}: {j["verdict"]} ({_f(j["live"]["job_time_s"])} s of job)'
               for n, j in r['jobs'].items())),
    Figure('seed-experiments', "the notes' experiments as the notes ran them",
           'seed_experiments', ('--quick',),
           lambda r: f'5 Hz sine on the target: TD {_f(r["sine5_td_ratio"])} (notes 0.72); '
                     f'thin sheet: LADRC {_f(r["thin_sheet_ladrc_range_mm"])} mm range vs PID '
                     f'{_f(r["thin_sheet_pid_range_mm"])} mm', quick=True, readme=True),
    Figure('seed-sine-steps', "the notes' 5 Hz target sine run by the LADRC: TD and gap ratio "
           "(gap phase); the notes' steps: command chatter above 20 Hz in mm/s (re-interpolated "
           'in brackets), nozzle travel', 'seed_experiments', (),
           lambda r: 'sine: ' + ', '.join(
               f'{x["observer"]} {_f(x["td_ratio"])} / {_f(x["gap_ratio"])} '
               f'({_f(x["gap_phase_deg"])}°)' for x in r['rows']
               if x['experiment'] == 'sine on the target')
           + '; ' + _grouped(
               [x for x in r['rows'] if x['experiment'] == 'step' and not x['reinterpolate']],
               'step', lambda x: f'{x["observer"]} {_f(x["chatter_mm_s"])}'
               + ''.join(f' ({_f(y["chatter_mm_s"])})' for y in r['rows']
                         if y['experiment'] == 'step' and y['reinterpolate']
                         and (y['step'], y['observer']) == (x['step'], x['observer']))
               + f', travel {_f(x["travel_mm"])} mm')),
    Figure('seed-thin-sheet', "the notes' thin sheet: deviation (range) per setting",
           'seed_experiments', (),
           lambda r: '; '.join(
               f'{x["setting"]}: {x["deviation_min_mm"]:+.2f}…{x["deviation_max_mm"]:+.2f} mm '
               f'({_f(x["range_mm"])})' for x in r['rows'] if x['experiment'] == 'thin sheet')),
    Figure('seed-fal', 'nonlinear observer (fal) vs linear, per scenario: error RMS mm / chatter '
           'mm/s (the sine on the target: RMS / gap ratio)', 'seed_experiments', (),
           lambda r: _grouped(
               [x for x in r['rows'] if x['experiment'] == 'nonlinear observer'], 'scenario',
               lambda x: f'{_short_setting(x["setting"])} ' + ' / '.join(
                   _f(x[k]) for k in ('error_rms_mm', 'chatter_mm_s', 'gap_ratio') if k in x))),
    Figure('seed-kalman', 'Kalman filter in the loop (plain, gated), per scenario: error RMS / '
           'max mm, chatter mm/s', 'seed_experiments', (),
           lambda r: _grouped(
               [x for x in r['rows'] if x['experiment'] == 'kalman'], 'scenario',
               lambda x: f'{x["setting"]} {_f(x["error_rms_mm"])} / {_f(x["error_max_mm"])}, '
                         f'{_f(x["chatter_mm_s"])}')),
    Figure('sweep-speed', 'batch closed loop, 1000 parameter sets × the batchable library',
           'sweep_speed', (),
           lambda r: f'{_f(r["wall_s"])} s wall, {_f(r["aggregate_realtime_x"])}× real time '
                     'aggregate'),
    Figure('bag-read', 'reading a bag into columns (every field, strings included)',
           'bag_read', ('--seconds', '120'),
           lambda r: f'{_f(r["indexed_msgs_per_s"])} messages/s, {_f(r["speedup"])}× rosbags '
                     'message by message', quick=True),
    Figure('bag-strings', "decoding the 2 kHz command topic with its commander's name and "
           'without (a fixed layout)', 'bag_read', ('--seconds', '120'),
           lambda r: f'{_f(r["command_with_string_s"])} / {_f(r["command_fixed_s"])} s for '
                     f'{r["command_messages"]} messages', quick=True),
    Figure('edge-fit', "the edge verification's fit in the tick, SCHED_FIFO, 2 busy loops",
           'edge_fit_timing', (),
           lambda r: f'median {_f(r["median_ms"])} ms, max {_f(r["max_ms"])} ms'),
    Figure('stalls', 'longest wake-up lateness of a 2 kHz deadline loop (20 s per condition)',
           'stalls', (),
           lambda r: ', '.join(f'{k} {_f(v["late_max_ms"])} ms'
                               for k, v in r['conditions'].items())),
    Figure('loop-timing', 'live loop, sim + controller + recorder (60 s, deadline loop)',
           'loop_timing', ('--duration', '60', '--loops', 'deadline'),
           lambda r: f'{_f(r["rate_hz"])} ticks/s, period p99 {_f(r["period_p99_us"])} µs, '
                     f'latency p99 {_f(r["latency_p99_ms"])} ms', readme=True),
    Figure('showcase-free-running', 'the showcase free-running (`bringup --scenario showcase`, '
           "the product's defaults), 10 runs: runs stopped by a timing guard", 'showcase_live',
           ('--runs', '10'),
           lambda r: f'{r["stopped_by_timing_guard"]} of {r["runs"]} stopped by a timing guard '
                     f'({", ".join(f"{k} {v}" for k, v in r["faults_by_code"].items()) or "none"}'
                     f'), {r["clean_runs"]} to their end with 0 faults, {r["other_faults"]} '
                     'other faults', readme=True),
    Figure('lockstep-speed', 'lock step (sim + controller), unpaced, 20 s, shipped UDP profile',
           'loop_timing', ('--duration', '60', '--loops', 'deadline'),
           lambda r: f'{_f(r["lockstep_realtime_x"])}× real time with the full recorder '
                     f'({r["lockstep"]["messages_lost"]} messages lost), '
                     f'{_f(r["lockstep_alone_realtime_x"])}× alone'),
    Figure('loop-modes', 'live loop per mode and recorder (deadline / sync, 60 s each)',
           'loop_timing', ('--duration', '60', '--loops', 'deadline,sync', '--lockstep', '0'),
           lambda r: '; '.join(
               f'{k.replace("/", ", ").replace("_", " ")}: {_f(v["rate_hz"], 6)} Hz, period '
               f'p50/p99/max {_f(v["period_p50_us"], 4)}/{_f(v["period_p99_us"], 4)}/'
               f'{_f(v["period_max_us"], 5)} µs, superseded/reused/late/never received '
               f'{v["samples_superseded"]}/{v["samples_reused"]}/{v["samples_handled_late"]}/'
               f'{v["samples_never_received"]}, latency p50/p99 {_f(v["latency_p50_ms"])}/'
               f'{_f(v["latency_p99_ms"])} ms, status lost {v["status_lost_by_recorder"]}, '
               f'watchdog trips {v["watchdog_trips"]}' for k, v in r['runs'].items())
           + f'; bare timer {_f(r["bare_timer_rate_hz"], 5)} Hz, p99 '
             f'{_f(r["bare_timer_period_p99_us"])} µs'),
    Figure('cia402-timing', 'CiA 402 path free-running on the test bus, 1 ms', 'cia402_timing',
           ('--duration', '30', '--periods-ms', '1'),
           lambda r: f'{100 * r["held"]:.1f} % of SYNC periods held, SYNC jitter p99 '
                     f'{_f(r["sync_jitter_p99_us"])} µs, sensor → command p99 '
                     f'{_f(r["latency_p99_ms"])} ms, {r["contacts"]} contacts, bus load '
                     f'{100 * r["bus_load_1mbit"]:.0f} % at 1 Mbit/s'),
    Figure('conform-sim', "driver conformance kit on the sim node (the product's 5 ms "
           'watchdog)', 'ladrc', ('conform', '--sim', '-o', OUT), _conform),
    Figure('conform-cia402', 'driver conformance kit on the CiA 402 path (driver node, emulated '
           'drive, test bus), 1 ms', 'ladrc', ('conform', '--drive', 'cia402', '-o', OUT),
           _conform),
    Figure('cia402-job', '`plate_holes` on the CiA 402 path in lock step (0.5 ms), unpaced',
           'bringup', ('--drive', 'cia402', '--job', 'plate_holes', '--lockstep', '--unpaced'),
           lambda r: f'{_job_run(r)}; {_f(r.get("realtime_x"))}× real time'),
    Figure('fault-matrix', 'fault-injection matrix (headless, live, CiA 402, LinuxCNC; load '
           'row 10 s, parameter clients 6 s)', 'fault_matrix',
           ('--load-s', '10', '--clients-s', '6'),
           lambda r: f'{r["contacts"]} contacts, {r["node_crashes"]} node crashes, '
                     f'{r["nonfinite_commands"]} non-finite commands, '
                     f'{r["invalid_params_accepted"]} of {r["invalid_params_tried"]} invalid '
                     f'parameters accepted, axis at rest {_f(r["kill_stop_ms"])} ms after a '
                     f'controller SIGKILL ({_f(r.get("canopen_kill_stop_ms"))} ms after a '
                     'CiA 402 driver SIGKILL)', readme=True),
    Figure('fault-matrix-edges', 'fault-injection matrix, edge rows: smallest true gap / target '
           '(the bar: 0.7)', 'fault_matrix', ('--load-s', '10', '--clients-s', '6'),
           lambda r: '; '.join(f'{x["row"]} {_f(x["gap_over_target"])}' for x in r['rows']
                               if x.get('gap_over_target') is not None)),
    Figure('fault-matrix-live', 'fault-injection matrix, live rows: recorder SIGKILL, load (10 s)',
           'fault_matrix', ('--load-s', '10', '--clients-s', '6'),
           lambda r: f'at most {_f(r["recorder_kill_loss_s"])} s of the bag lost before a '
                     f'recorder SIGKILL (worst of 3); {r["spurious_faults_under_load"]} '
                     'spurious faults following under two busy loops'),
    Figure('fault-matrix-canopen', 'fault-injection matrix, CiA 402 rows: contact, least true '
           'gap, last motion after the injection, crashes, the faults reported', 'fault_matrix',
           ('--only', 'canopen'),
           lambda r: '; '.join(
               f'{x["row"].removeprefix("CiA 402: ")}: '
               f'{"CONTACT" if x.get("contact") else "no contact"}, least true gap '
               f'{_f(x.get("min_true_gap_mm"))} mm, last motion {_f(x.get("stop_ms"))} ms after, '
               f'{x.get("crashes")} crashes, follow fault "{(x.get("follow_fault") or "")[:70]}", '
               f'drive fault "{(x.get("drive_fault") or "")[:70]}"' for x in r['rows'])
           + f'; node crashes {r["canopen_node_crashes"]}'),
    Figure('fault-matrix-linuxcnc',
           'fault-injection matrix, LinuxCNC rows: contact, the nozzle after the fault, final '
           'states',
           'fault_matrix', ('--only', 'linuxcnc'),
           _fault_rows_linuxcnc),
    Figure('linuxcnc-jobs', 'shipped jobs under LinuxCNC (bringup --cnc linuxcnc), one run each '
           'with the timing allowance and with the product timing', 'linuxcnc_jobs',
           ('--jobs', 'plate_holes', 'tipping_pair', '--runs', '1'),
           lambda r: '; '.join(
               f'{n}: to the end {e["ran_to_end"].get("allowance", [0, 0])[0]}/'
               f'{e["ran_to_end"].get("allowance", [0, 0])[1]} '
               f'({e["ran_to_end"].get("product", [0, 0])[0]}/'
               f'{e["ran_to_end"].get("product", [0, 0])[1]} product), '
               f'{sum(x.get("contacts") or 0 for rs in e["linuxcnc"].values() for x in rs)} '
               'contacts' for n, e in r['jobs'].items())),
    Figure('linuxcnc-safety',
           'shipped jobs under LinuxCNC: verdict, XY moved before ready, late samples, why runs '
           'stopped',
           'linuxcnc_jobs',
           ('--jobs', 'plate_holes', 'tipping_pair', '--runs', '1'),
           _linuxcnc_safety),
    Figure('linuxcnc-side-by-side',
           'shipped jobs headless / under LinuxCNC (runs to their end): job time, holds, corner '
           'excursion, least gap / target',
           'linuxcnc_jobs',
           ('--jobs', 'plate_holes', 'tipping_pair', '--runs', '1'), _linuxcnc_side),
    Figure('linuxcnc-blend', "a job under LinuxCNC with the post-processor's G64 P0.05 and with "
           'G61 (exact stop)', 'linuxcnc_jobs',
           ('--jobs', 'plate_holes', 'tipping_pair', '--runs', '1'),
           lambda r: f'{r["blend"]["job"]}: G64 P0.05 {_job_run(r["blend"]["g64"])}; G61 '
                     f'{_job_run(r["blend"]["g61"])}'),
    Figure('linuxcnc-foreign', "LinuxCNC's own plasmatest.ngc as it is, under LinuxCNC with the "
           'height controller', 'linuxcnc_jobs',
           ('--jobs', 'plate_holes', 'tipping_pair', '--runs', '1'),
           lambda r: f'{_job_run(r["foreign"])}, {r["foreign"].get("bridge_leapfrogs")} '
                     'leapfrogs, XY moved before ready '
                     f'{r["foreign"].get("bridge_moved_before_ready")}'),
    Figure('view-load', "the live view's cost to the loop (showcase live, 2 rounds without / "
           'with --view)', 'view_load', (),
           lambda r: f'{_f(r["rate_hz_without"], 4)} / {_f(r["rate_hz_with"], 4)} ticks/s, '
                     f'period p99 {_f(r["period_p99_us_without"])} / '
                     f'{_f(r["period_p99_us_with"])} µs; status at {_f(r["status_rate_hz"])} '
                     f'Hz to the client, every fault reason received: '
                     f'{r["all_fault_reasons_received"]}; view CPU {_f(r["view_cpu_pct"])} %'),
    Figure('view-load-runs',
           "the live view's cost per run (without / with --view): loop rate, period p99, max, "
           "watchdog trips, load",
           'view_load', (),
           lambda r: '; '.join(
               f'{"with" if x["view"] else "without"}: {_f(x.get("rate_hz"), 4)} Hz, period '
               f'p99 {_f(x.get("period_p99_us"))} µs, max {_f(x.get("period_max_us"))} µs, '
               f'{x.get("watchdog_trips")} watchdog trips, load {_f(x.get("load_1min"), 2)}'
               + (f', view CPU {_f(x["view_cpu_pct"])} %, status {x["status_received"]} '
                  f'({_f(x["status_rate_hz"])}/s), events {x["events_received"]} of '
                  f'{x["events"]}' if x['view'] else '') for x in r['runs'])),
    Figure('html-report-hour', 'zoomable HTML report of a 1-hour bag', 'html_report', (),
           lambda r: f'{r["html_bytes"] / 1e6:.1f} MB, drawn in {_f(r["chromium_render_s"])} s '
                     f'in headless Chromium; a 50 ms window shows {r["points_in_50ms_window"]}'
                     f' of its {r["samples_in_window"]} samples', readme=True),
    Figure('html-report-cost', '`ladrc report` of a 10-minute bag with / without the HTML, each '
           'in its own process', 'html_report', ('--seconds', '600'),
           lambda r: f'wall {_f(r["write_s"])} / {_f(r["report_no_html_s"])} s, CPU '
                     f'{_f(r["write_cpu_s"])} / {_f(r["report_no_html_cpu_s"])} s, peak RSS '
                     f'{_f(r["write_peak_rss_mib"])} / {_f(r["report_no_html_peak_rss_mib"])} '
                     'MiB'),
    Figure('bag-tools-hour', 'tools on a 15-minute bag, each in its own process', 'bag_scale',
           ('--part', 'tools', '--tool-hours', '0.25'),
           lambda r: f'report {_f(r["report_realtime_x"])}×, replay '
                     f'{_f(r["replay_realtime_x"])}× real time; peak RSS '
                     f'{_f(r["tools_peak_rss_mib"])} MiB', readme=True),
    Figure('bag-writer-shift', "the recorder's writer fed a simulated 15 minutes of the "
           '2 kHz topics', 'bag_scale', ('--part', 'writer', '--hours', '0.25'),
           lambda r: (lambda w: f'{w["messages_written"]} of {w["messages_fed"]} messages '
                      f'read back; periodic work {_f(w["periodic_ms_start"])} → '
                      f'{_f(w["periodic_ms_end"])} ms a call, first → last minute (ratio '
                      f'{_f(w["periodic_end_over_start"])}, target ≤ 1.5), longest '
                      f'{_f(w["periodic_ms_max"])} ms; peak RSS {_f(w["peak_rss_mib"])} MiB; '
                      f'{_f(w["realtime_x"])}× real time')(r['writer'])),
    Figure('bag-live-hour', 'recording the full node set live (120 s, zstd chunks)', 'bag_scale',
           ('--part', 'live', '--live-s', '120'),
           lambda r: (lambda v: f'{v["bytes_per_hour"] / 1e9:.2f} GB per hour; '
                      f'{v["messages_total"]} messages, {v["messages_lost"]} lost, '
                      f'{v["messages_dropped"]} dropped; load average '
                      f'{_f(v["load_avg_1min_mean"])} (max {_f(v["load_avg_1min_max"])}) on '
                      f'{v["cpus"]} cores')(r['live'])),
    Figure('fleet-scaling',
           '`ladrc fleet` on a generated fleet (4 machines × 2 days × 2 bags of 8 s): generate, '
           'read on 1 / 2 workers, per bag, memory',
           'fleet_scaling',
           ('--machines', '4', '--days', '2', '--bags-per-day', '2'),
           lambda r: f'{r["bags"]} bags (seed {r["seed"]}): generated in '
                     f'{_f(r["generate_s_2_workers"])} s on 2 workers; read in '
                     f'{_f(r["wall_s_1_worker"])} s on 1 worker, {_f(r["wall_s_2_workers"])} s on '
                     f'2 ({_f(r["speedup"])}×); per bag {_f(r["per_bag_s"])} s (the fleet task) '
                     f'vs {_f(r["report_per_bag_s"])} s (`ladrc report` in its own process, plots '
                     f'included); worker peak {_f(r["worker_peak_rss_mb"])} MB'),
    Figure('fleet-flags', "`ladrc fleet`'s flags on the generated fleet against its truth file",
           'fleet_scaling', ('--machines', '4', '--days', '2', '--bags-per-day', '2'),
           _fleet_flags),
    Figure('sweep-engine', "`ladrc tune`'s sweep (about 300 points × every batchable scenario) "
           'in one batch on one core vs in parts on a local cluster of 2 workers',
           'sweep_engine', ('--sets', '300'),
           lambda r: f'{r["points"]} points × {r["scenarios"]} scenarios: one core '
                     f'{_f(r["one_core_s"])} s (peak {_f(r["driver_peak_rss_mb"])} MB), the '
                     f'engine {_f(r["engine_s"])} s on {r["workers"]} workers (peak '
                     f'{_f(r["worker_peak_rss_mb"])} MB a worker); scores, verdicts and fronts '
                     f'identical: {r["identical"]}; {r["passed"]} through the gate, {r["front"]} '
                     'on the front'),
    Figure('sweep-engine-large', "`ladrc tune`'s sweep of about 3 000 points × 3 scenarios "
           '(one of each class) on the engine alone', 'sweep_engine',
           ('--sets', '3000', '--engine-only', '--scenarios', 'step,sine_5hz,edge_step_3_1'),
           lambda r: f'{r["points"]} points × {r["scenarios"]} scenarios on {r["workers"]} '
                     f'workers: {_f(r["engine_s"])} s; {r["passed"]} through the gate, '
                     f'{r["front"]} on the front; peak {_f(r["worker_peak_rss_mb"])} MB a worker, '
                     f'{_f(r["driver_peak_rss_mb"])} MB the driver'),
    Figure('identified-plant',
           "the shipped set on the notes' identified plant (§1.2): loop per gain reading, closed "
           "loop, 300 s flat sheet",
           'identified_plant', ('--long-s', '300'),
           lambda r: f'LADRC phase margin {_f(r["ladrc_pm_deg_gain_b0_1"])}° at gain 1/16.75, '
                     f'{_f(r["ladrc_pm_deg_gain_1"])}° at gain 1 (delay margin '
                     f'{_f(r["ladrc_dm_ms_gain_1"])} ms, crossover {_f(r["ladrc_fc_hz_gain_1"])} '
                     f'Hz; gain 0.01: crossover {_f(r["ladrc_fc_hz_gain_0_01"])} Hz); '
                     f'`identified_plant` error RMS LADRC {_f(r["plant_rms_mm_ladrc"])} / PID '
                     f'{_f(r["plant_rms_mm_pid"])} mm (LADRC at gain 1: '
                     f'{_f(r["plant_rms_mm_ladrc_gain_1"])} mm); PID at gain 1: '
                     f'{r["pid_gain_1_collisions"]} collisions; LADRC at gain 1 with 2 ticks of '
                     f'dead time: {r["ladrc_gain_1_dead_2_fault"][:70] or "no fault"}; slowest '
                     f'closed-loop pole {_f(r["slow_pole_rad_s"])} rad/s, plant zero '
                     f'{_f(r["plant_zero_rad_s"])} rad/s; {_f(r["long_s"])} s on a flat sheet: '
                     f'error RMS {_f(r["long_error_rms_mm"])} mm, mean command over the last 10 s '
                     f'{_f(r["long_last10s_mean_command_mm_s"])} mm/s'),
    Figure('identified-plant-interval', "the identified plant at the ends of the notes' ±1σ "
           'interval and its corners: error RMS range per scenario and law', 'identified_plant',
           ('--long-s', '300'),
           _interval),
    Figure('loop-vs-sim', 'loop analysis vs the headless closed loop: largest deviation of the '
           'sheet-to-nozzle response over the sheet sines', 'loop_vs_sim', (),
           lambda r: '; '.join(f'{k}: {_f(v["max_db"], 2)} dB / {_f(v["max_deg"], 2)}°'
                               for k, v in r.items() if k != 'frequencies_hz')
           + f' ({len(r["frequencies_hz"])} sines, {_f(min(r["frequencies_hz"]))}–'
             f'{_f(max(r["frequencies_hz"]))} Hz)'),
)
BY_ID = {f.id: f for f in FIGURES}


def machine() -> str:
    """Return ``2 cores, <CPU model>``."""
    model = platform.processor() or ''
    try:
        for line in Path('/proc/cpuinfo').read_text().splitlines():
            if line.startswith('model name'):
                model = line.split(':', 1)[1].strip()
                break
    except OSError:
        pass
    return f'{os.cpu_count()} cores, {model or "unknown CPU"}'


def commit() -> str:
    """Return the checkout's commit (short), ``+`` when the tree has changes."""
    try:
        head = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=ROOT, check=True,
                              capture_output=True, text=True).stdout.strip()
        dirty = subprocess.run(['git', 'status', '--porcelain', '--untracked-files=no'],
                               cwd=ROOT, capture_output=True, text=True).stdout.strip()
        return head + ('+' if dirty else '')
    except (OSError, subprocess.CalledProcessError):
        return 'unknown'


def run_bench(bench: str, args: tuple[str, ...]) -> dict:
    """Run ``bench/BENCH.py ARGS`` (or the tool ``BENCH``); return its last line of JSON."""
    with tempfile.TemporaryDirectory(prefix='figures-') as tmp:
        argv = [a.replace(OUT, str(Path(tmp) / 'out')) for a in args]
        head = (['-m', TOOLS[bench]] if bench in TOOLS
                else [str(ROOT / 'bench' / f'{bench}.py')])
        proc = subprocess.run([sys.executable, *head, *argv], cwd=ROOT, capture_output=True,
                              text=True, check=False)
    lines = proc.stdout.strip().splitlines()
    if proc.returncode != 0 or not lines:
        tail = (proc.stderr.strip().splitlines() or ['no output'])[-1]
        raise RuntimeError(f'{bench} exited {proc.returncode}: {tail}')
    return json.loads(lines[-1])


def command(f: Figure) -> str:
    """Return the command that prints the figure."""
    head = (('scripts/in-env', f.bench) if f.bench in TOOLS
            else ('scripts/in-env python', f'bench/{f.bench}.py'))
    return ' '.join((*head, *(a.replace(OUT, 'OUT') for a in f.args)))


def _cell(text: str) -> str:
    """Return ``text`` fit for a Markdown table cell (pipes escaped, lines joined)."""
    return ' '.join(text.split('\n')).replace('|', '\\|')


def measured(row: dict) -> str:
    """Return a row's ``date, commit, machine`` (older rows keep them as three keys)."""
    return row.get('measured') or f'{row["date"]}, {row["commit"]}, {row["machine"]}'


def dump(data: dict) -> str:
    """Return figures.json's text: one figure a line (``id: {value, measured, ...}``)."""
    rows = (f' {json.dumps(k)}: {json.dumps(v, ensure_ascii=False)}' for k, v in data.items())
    return '{\n' + ',\n'.join(rows) + '\n}\n'


def render(data: dict) -> str:
    """Render docs/figures.md from the data."""
    out = ['# Figures', '',
           'Generated by `scripts/in-env python bench/figures.py` (`--quick`: the figures of a '
           'few seconds each; the full run takes hours). One row per figure: its value, the '
           'command that prints it, and when, at which commit and on which machine it was '
           'measured. Do not edit by hand: run the bench.', '',
           '| figure | value | command | measured |', '| --- | --- | --- | --- |']
    for f in FIGURES:
        row = data.get(f.id)
        if row is None:
            value, when = 'not measured yet', ''
        else:
            value = row['value']
            when = measured(row)
        out.append(f'| <a id="{f.id}"></a>{_cell(f.label)} | {_cell(value)} | `{command(f)}` | '
                   f'{when} |')
    for rid, row in data.items():  # rows measured by a command that is not a bench's run
        if rid not in BY_ID and 'label' in row and 'command' in row:
            out.append(f'| <a id="{rid}"></a>{_cell(row["label"])} | {_cell(row["value"])} | '
                       f'`{row["command"]}` | {measured(row)} |')
    return '\n'.join(out) + '\n'


def render_readme_table(data: dict) -> str:
    """Render the README's short table (values and links; dates are in docs/figures.md)."""
    rows = ['| figure | value |', '| --- | --- |']
    for f in FIGURES:
        if f.readme:
            value = data.get(f.id, {}).get('value', 'not measured yet')
            rows.append(f'| [{_cell(f.label)}](docs/figures.md#{f.id}) | {_cell(value)} |')
    return '\n'.join(rows)


def update_readme(data: dict) -> bool:
    """Replace the README's table between its markers; False when it has none."""
    begin, end = '<!-- figures:begin -->', '<!-- figures:end -->'
    text = README.read_text(encoding='utf-8')
    if begin not in text or end not in text:
        return False
    head, rest = text.split(begin, 1)
    _, tail = rest.split(end, 1)
    README.write_text(f'{head}{begin}\n{render_readme_table(data)}\n{end}{tail}',
                      encoding='utf-8')
    return True


QUALITY = DOCS / 'quality.md'
QUALITY_VARIANTS = ('variant', '---', 'pid', 'ladrc')
"""The variants (and the header's cells) of docs/quality.md's table."""


def update_quality(out_dir: Path) -> bool:
    """Regenerate docs/quality.md's suite tables (``ladrc suite --law-only``) in place.

    Between ``suite:begin`` and ``suite:end``: the "Notes vs simulation" table of the suite's
    own ``suite.md`` for the PID and the shipped LADRC, its heading one level down. Returns
    False when the suite failed (the table stays as it was).
    """
    folder = out_dir / 'suite'
    proc = subprocess.run([sys.executable, '-m', 'ladrc_tools.cli', 'suite', '-q', '--law-only',
                           '-o', str(folder)], cwd=ROOT, capture_output=True, text=True,
                          check=False)
    md = folder / 'suite.md'
    if proc.returncode != 0 or not md.is_file():
        print(f'figures: ladrc suite failed: {proc.stderr.strip()[-300:]}', file=sys.stderr)
        return False
    text = md.read_text(encoding='utf-8')
    part = text[text.index('## Notes vs simulation'):text.index('## All runs')]
    part = part.replace(str(folder), 'DIR')
    # the PID and the shipped LADRC; the variants' rows are in the suite's own suite.md
    part = '\n'.join(line for line in part.splitlines() if not line.startswith('| ')
                     or line.split('|')[2].strip() in QUALITY_VARIANTS)
    part = re.sub(r'^## ', '### ', part, flags=re.M)
    begin, end = '<!-- suite:begin -->', '<!-- suite:end -->'
    doc = QUALITY.read_text(encoding='utf-8')
    head, rest = doc.split(begin, 1)
    _, tail = rest.split(end, 1)
    QUALITY.write_text(f'{head}{begin}\n{part.rstrip()}\n{end}{tail}', encoding='utf-8')
    return True


def main() -> int:
    """Run the benches of the chosen figures and write the tables."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--quick', action='store_true', help='only the figures of seconds each')
    ap.add_argument('--only', default='', help='comma-separated figure ids')
    ap.add_argument('--list', action='store_true', help='list the figures and exit')
    ap.add_argument('--out', default=str(DOCS),
                    help='folder of figures.json and figures.md [docs]; another folder leaves '
                    'the README as it is')
    ap.add_argument('--dry-run', action='store_true',
                    help='render the tables from docs/figures.json without running benches')
    a = ap.parse_args()
    if a.list:
        for f in FIGURES:
            print(f'{f.id:24} {"quick " if f.quick else "      "}{command(f)}')
        return 0
    ids = [i for i in a.only.split(',') if i]
    unknown = [i for i in ids if i not in BY_ID]
    if unknown:
        print(f'figures.py: unknown figure ids {unknown}; --list shows them', file=sys.stderr)
        return 2
    chosen = ([BY_ID[i] for i in ids] if ids else
              [f for f in FIGURES if f.quick] if a.quick else list(FIGURES))
    # one run of a bench fills every figure it prints (the rows sharing its command)
    runs = {(f.bench, f.args) for f in chosen}
    chosen = [f for f in FIGURES if (f.bench, f.args) in runs]
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    data_file, table_file = out / DATA.name, out / TABLE.name
    data = json.loads(data_file.read_text(encoding='utf-8')) if data_file.is_file() else {}
    t0 = time.monotonic()
    done, failed = [], []
    results: dict[tuple, dict] = {}
    stamp = dt.date.today().isoformat()
    where, rev = machine(), commit()
    for f in [] if a.dry_run else chosen:
        key = (f.bench, f.args)
        try:
            if key not in results:
                print(f'figures: {command(f)}', file=sys.stderr, flush=True)
                results[key] = run_bench(f.bench, f.args)
            value = f.value(results[key])
        except (RuntimeError, KeyError, TypeError, ValueError) as exc:
            print(f'figures: {f.id}: {exc}', file=sys.stderr, flush=True)
            failed.append(f.id)
            continue
        data[f.id] = {'value': value, 'measured': f'{stamp}, {rev}, {where}'}
        done.append(f.id)
    tmp = data_file.with_suffix('.json.part')
    tmp.write_text(dump(data), encoding='utf-8')
    tmp.replace(data_file)
    table_file.write_text(render(data), encoding='utf-8')
    written = [str(data_file), str(table_file)]
    if out.resolve() == DOCS.resolve() and update_readme(data):
        written.append(str(README))
    if out.resolve() == DOCS.resolve() and not a.quick and not ids and not a.dry_run:
        with tempfile.TemporaryDirectory(prefix='figures-') as tmp:
            if update_quality(Path(tmp)):
                written.append(str(QUALITY))
            else:
                failed.append('quality-suite')
    print(json.dumps({'figures': done, 'failed': failed,
                      'wall_s': round(time.monotonic() - t0, 1), 'written': written}))
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
