"""``ladrc job``: run a cutting job headless (the job world), print its figures, draw it.

``ladrc job JOB`` runs a job file (or a shipped job's name) with the simulated CNC and the
follow controller; ``--off FEATURE`` switches a CNC-partner feature off, ``--compare FEATURE``
runs the job with it on and off and reports the difference (docs/job-world.md). ``-o DIR``
writes ``job.json``, ``job.png`` (the sheet with the path coloured by gap error and by the
controller's state, pierce points, every fault and hold marked) and ``bag/``: the run in the
live layout (``ladrc replay`` reproduces it bit for bit; ``run/scenario`` holds the job file
and its DXF).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import sys
from typing import Any

from ladrc_contract.run_log import verdict

from .cli_common import CliError

FEATURES: dict[str, tuple[dict[str, Any], dict[str, Any]]] = {
    # feature -> (CNC settings, controller parameters) that switch it off
    'corner_lock': ({}, {'cnc.corner_lock': False}),
    'edge_ahead': ({}, {'cnc.edge_ahead_hold_mm': 0.0}),
    'leapfrog': ({'leapfrog': False}, {}),
    # small contours pierced and cut followed like the others (no locked pierce)
    'small_contours': ({'small_contour_mm': 0.0}, {}),
    'feed_override': ({'honour_override': False}, {}),
    # the void lock's two judgements at their widest (a jump of 20 mm, a fall of 10 m/s): the
    # edge guard's verification and the far drop stay
    'void_lock': ({}, {'follow.jump_mm': 20.0, 'edge.fall_mm_s': 10000.0}),
}


def _add_job(p: argparse.ArgumentParser) -> None:
    p.add_argument('job', help='job file (YAML) or the name of a shipped job')
    p.add_argument('--off', action='append', default=[], choices=sorted(FEATURES),
                   help='switch a CNC-partner feature off (repeatable)')
    p.add_argument('--compare', choices=sorted(FEATURES),
                   help='run with the feature on and off; report both and the difference')
    p.add_argument('--separate-cnc', action='store_true',
                   help='the CNC apart from the world, as with the CNC node (bringup --job '
                   '--separate-cnc): the sheet sees XY only from its motion samples')
    p.add_argument('-o', '--output', help='folder for job.json, job.png and bag/ (must not exist)')


def load(name: str) -> Any:
    """Return the job of a path or a shipped name; CliError (one line) when unusable."""
    from ladrc_sim import JobError, find_job

    try:
        return find_job(name)
    except JobError as exc:
        raise CliError(str(exc)) from None


def contour_progress(label: str) -> Any:
    """Return a ``progress(cut, contours)`` callback: ``label: contour k/n`` on a terminal.

    One line on stderr, rewritten, ended when the run ends (:func:`run` calls it with 0, 0);
    piped or logged, stderr carries nothing but the one line of an error.
    """
    shown = [False]

    def show(cut: int, contours: int) -> None:
        if not sys.stderr.isatty():
            return
        if contours == 0:  # the end
            if shown[0]:
                print(file=sys.stderr, flush=True)
            return
        shown[0] = True
        print(f'\r{label}: contour {cut}/{contours} cut', end='', file=sys.stderr, flush=True)
    return show


def run(job: Any, off: list[str], record_internals: bool = False,
        progress: Any = None, separate_cnc: bool = False) -> Any:
    """Run ``job`` with the features in ``off`` switched off; return its JobResult.

    ``separate_cnc``: as with the CNC node (``run_job``'s ``separate_cnc``).
    """
    from ladrc_follow import FollowController, ParameterError, check_gate, params_from_dict
    from ladrc_sim import run_job

    cnc: dict[str, Any] = {}
    controller: dict[str, Any] = {}
    for f in off:
        cnc.update(FEATURES[f][0])
        controller.update(FEATURES[f][1])
    job = job.with_changes(cnc, controller)
    try:
        params = check_gate(params_from_dict(dict(job.controller)))
    except ParameterError as exc:
        raise CliError(f'{job.path}: controller: {" ".join(str(exc).split())}') from None
    try:
        result = run_job(job, FollowController(params), record_internals=record_internals,
                         progress=progress, separate_cnc=separate_cnc)
    finally:
        if progress is not None:
            progress(0, 0)
    result.params = params
    return result


def write_bag(job: Any, result: Any, path: Path) -> None:
    """Write a job run as a bag: the live layout, the job file and its DXF in run/scenario."""
    from ladrc_bags import write_run_bag
    from ladrc_follow import dump_params
    from ladrc_sim import run_text

    write_run_bag(result.as_run(), path, dump_params(result.params), run_text(job))


def _add_post(p: argparse.ArgumentParser) -> None:
    p.add_argument('job', help='job file (YAML) or the name of a shipped job')
    p.add_argument('-o', '--output', required=True,
                   help='the G-code file to write (.ngc; must not exist)')
    p.add_argument('--blend-mm', type=float, default=None,
                   help='G64 P tolerance [0.05]; 0 writes G61 (exact stop)')
    p.add_argument('--no-holds', action='store_true',
                   help='no M62/M63 P2 around the edge-ahead stretches')


def _run_post(a: argparse.Namespace) -> int:
    """``ladrc post``: the job's part program as LinuxCNC G-code (ladrc_tools/cam)."""
    from .cam.postprocess import PostSettings, postprocess

    job = load(a.job)
    if job.gcode is not None:
        raise CliError(f'{job.path}: a G-code job already is G-code ({job.gcode})')
    out = Path(a.output)
    if out.exists():
        raise CliError(f'{out} exists already: nothing is overwritten')
    kw: dict[str, Any] = {'holds': not a.no_holds}
    if a.blend_mm is not None:
        kw['blend_mm'] = a.blend_mm
    settings = PostSettings(**kw)
    bad = settings.problems()
    if bad:
        raise CliError(bad[0])
    result = postprocess(job, settings)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CliError(f'{out.parent}: cannot create: {exc.strerror or exc}') from None
    tmp = out.with_name(out.name + '.part')
    tmp.write_text(result.text, encoding='utf-8')
    tmp.replace(out)
    print(json.dumps({'job': job.name, 'gcode': str(out), 'lines': result.lines,
                      'contours': len(result.contour_lines),
                      'hold_stretches': sum(len(h) for h in result.holds_mm),
                      **result.settings}))
    return 0


def _run_job(a: argparse.Namespace) -> int:
    job = load(a.job)
    if job.gcode is not None:
        raise CliError(f'{job.path}: a G-code job (gcode: {job.gcode.name}) runs under LinuxCNC '
                       f'only, which reads its program: bringup --cnc linuxcnc --job {a.job}')
    out_dir = Path(a.output) if a.output else None
    if out_dir is not None and out_dir.exists():
        raise CliError(f'{out_dir} exists already: nothing is overwritten')
    for o in (job.program().reading or {}).get('open_contours', ()):
        (ax, ay), (bx, by) = o['ends_mm']
        print(f'{job.name}: open contour not cut: {o["entity"]} on layer {o["layer"]!r}, ends '
              f'({ax:g}, {ay:g}) and ({bx:g}, {by:g}) mm, {o["length_mm"]:g} mm long')
    result = run(job, a.off, record_internals=out_dir is not None,
                 progress=contour_progress(f'ladrc job {job.name}'), separate_cnc=a.separate_cnc)
    out: dict[str, Any] = {'job': job.name, 'off': a.off,
                           **({'separate_cnc': True} if a.separate_cnc else {}), **result.figures,
                           'wall_s': round(result.wall_s, 2), 'realtime_x': realtime_x(result)}
    if a.compare:
        other = run(job, a.off + [a.compare],
                    progress=contour_progress(f'ladrc job {job.name}, {a.compare} off'),
                    separate_cnc=a.separate_cnc)
        out = {'job': job.name, 'feature': a.compare, 'on': result.figures,
               'off': other.figures, 'difference': compare(a.compare, result, other)}
    if out_dir is not None:
        out_dir.mkdir(parents=True)
        (out_dir / 'job.json').write_text(json.dumps(out, indent=1, default=str) + '\n',
                                          encoding='utf-8')
        from .offline.job_report import draw_job

        draw_job(job, result, out_dir / 'job.png')
        write_bag(job, result, out_dir / 'bag')
    ok, text = verdict(result.run, job.expect_fault)
    print(f'ladrc job {job.name}: {"ok" if ok else "FAILED"}: {text}', file=sys.stderr)
    print(json.dumps({**out, 'run': result.run, 'ok': ok}, default=str))
    return 0 if ok else 1


def realtime_x(result: Any) -> float:
    """Return the job time over the wall time of its tick loop.

    The sheet's raster fill before the loop is not counted; the geometry of every tick is.
    """
    return round(result.figures['job_time_s'] / max(result.wall_s, 1e-9), 2)


def compare(feature: str, on: Any, off: Any) -> dict[str, Any]:
    """Return the figures a feature is judged by, on and off (docs/job-world.md)."""
    if feature == 'leapfrog':
        saved = off.figures['job_time_s'] - on.figures['job_time_s']
        return {'job_time_s_saved': round(saved, 4),
                'job_time_s_saved_pct': round(100.0 * saved / off.figures['job_time_s'], 2)}
    if feature == 'corner_lock':
        return {'corner_max_down_mm_on': on.figures['corner_max_down_mm'],
                'corner_max_down_mm_off': off.figures['corner_max_down_mm']}
    return {'min_gap_over_target_on': on.figures['min_gap_over_target_cutting'],
            'min_gap_over_target_off': off.figures['min_gap_over_target_cutting']}
