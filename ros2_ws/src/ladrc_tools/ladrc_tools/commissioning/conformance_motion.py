"""The conformance rules on the driver's motion and its safety functions.

Enable, direction, speed, velocity feedback, the reading against the encoder, the watchdog,
one commander, the bag of the motion tests: each takes the recording and the tolerances and
returns a :class:`~.conformance_result.RuleResult`.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from .conformance_recording import (
    AFTER_RESET,
    COMMAND_TOPIC,
    DOWN,
    ENABLE,
    EXCITATION,
    FAULT_HOLDS,
    FEEDBACK_TOPIC,
    GAP_TOPIC,
    PASSIVE,
    RESET_CALL,
    RESET_SERVICE,
    SECOND_COMMANDER,
    SILENCE,
    STATUS_OK,
    UP,
    WATCHDOG,
    Recording,
    Segment,
    fit_slope,
    median_period_s,
)
from .conformance_result import RuleResult, fmt_ms, rule_failure, rule_result
from .conformance_tolerances import Tolerances


def rule_drive_ready(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check, before any command: drive enabled, no fault, valid readings above the minimum."""
    seg = rec.segment(PASSIVE)
    if seg is None:
        return rule_failure('drive_ready', 'mm', rec.not_run or 'no passive window recorded')
    fb, gp = rec.feedback, rec.gap
    mf, mg = fb.window(seg.start_ns, seg.end_ns), gp.window(seg.start_ns, seg.end_ns)
    if not mf.any() or not mg.any():
        return rule_failure('drive_ready', 'mm', 'no samples in the passive window '
                            f'({int(mf.sum())} feedback, {int(mg.sum())} gap)')
    problems = []
    if not fb.drive_enabled[mf].all():
        problems.append('drive_enabled false')
    if fb.drive_fault[mf].any():
        i = int(np.flatnonzero(mf & fb.drive_fault)[0])
        problems.append(f'drive_fault true ({fb.fault_reason[i] or "no reason given"})')
    reasons = [fb.fault_reason[i] for i in np.flatnonzero(mf & ~fb.drive_fault)]
    if any(reasons):
        problems.append(f'fault_reason {next(r for r in reasons if r)!r} without drive_fault')
    g = gp.gap_mm[mg]
    if not (gp.valid[mg].all() and (gp.status[mg] == STATUS_OK).all()):
        problems.append(f'{int((~gp.valid[mg]).sum())} invalid readings (status '
                        f'{sorted(set(gp.status[mg].tolist()))})')
    gmin = float(np.min(g)) if np.isfinite(g).all() else math.nan
    if not gmin >= rec.plan.min_gap_mm:
        problems.append(f'gap {gmin:.3g} mm below the minimum {rec.plan.min_gap_mm:g} mm')
    return rule_result('drive_ready', not problems, gmin, 'mm',
                       f'enabled, no fault, gap {gmin:.4g} mm >= {rec.plan.min_gap_mm:g} mm'
                       if not problems else '; '.join(problems))


def rule_enable_false_holds(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that commands with enable=false (an upward velocity) do not move the axis."""
    seg = rec.segment(ENABLE)
    if seg is None:
        return rule_failure('enable_false_holds', 'mm', rec.why_missing(ENABLE))
    fb = rec.feedback
    m = fb.window(seg.start_ns, seg.end_ns + int(0.02e9))
    if m.sum() < 10:
        return rule_failure('enable_false_holds', 'mm', 'too few feedback samples in the test')
    p = fb.position_mm[m]
    travel = float(np.max(np.abs(p - p[0])))
    ok = travel <= tol.enable_travel_mm
    return rule_result('enable_false_holds', ok, travel, 'mm',
                       f'travel {travel:.4g} mm while {seg.velocity_mm_s:g} mm/s was '
                       'commanded with '
                       f'enable=false for {(seg.end_ns - seg.start_ns) * 1e-9:.3g} s'
                       + ('' if ok else ' (the drive must hold zero whatever velocity_mm_s says)'))


def _halves(rec: Recording) -> list[tuple[Segment, np.ndarray]] | str:
    """Return the up and down halves with the feedback mask of their steady part."""
    out = []
    for name in (UP, DOWN):
        seg = rec.segment(name)
        if seg is None:
            return rec.why_missing(UP, DOWN)
        # the steady part: skip the first 30 % (the velocity loop's lag, the dead time)
        start = seg.start_ns + int(0.3 * (seg.end_ns - seg.start_ns))
        m = rec.feedback.window(start, seg.end_ns)
        if m.sum() < 20:
            return f'too few feedback samples in the {name} half ({int(m.sum())})'
        out.append((seg, m))
    return out


def rule_motion_direction(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that, commanded up then down, the encoder moves up then down (Z up)."""
    halves = _halves(rec)
    if isinstance(halves, str):
        return rule_failure('motion_direction', 'ratio', halves)
    fb = rec.feedback
    parts, worst, ok = [], math.inf, True
    for seg, m in halves:
        slope = fit_slope(fb.recv_ns[m], fb.position_mm[m])
        ratio = slope / seg.velocity_mm_s
        worst = min(worst, ratio)
        # moved, and the way it was told (a tenth of the commanded speed at least)
        good = ratio >= 0.1
        ok = ok and good
        word = 'up' if slope > 0 else 'down'
        parts.append(f'{seg.name}: commanded {seg.velocity_mm_s:+g} mm/s, encoder moved {word} '
                     f'at {slope:+.3g} mm/s' + ('' if good else ' (WRONG)' if ratio < -0.1
                                                else ' (did not move)'))
    return rule_result('motion_direction', ok, worst, 'ratio', '; '.join(parts))


def rule_motion_speed(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that the encoder's speed equals the commanded speed (b0 = 1) within ±10 %."""
    halves = _halves(rec)
    if isinstance(halves, str):
        return rule_failure('motion_speed', 'ratio', halves)
    fb = rec.feedback
    parts, worst, ok = [], 1.0, True
    for seg, m in halves:
        ratio = abs(fit_slope(fb.recv_ns[m], fb.position_mm[m]) / seg.velocity_mm_s)
        if not abs(ratio - 1.0) <= abs(worst - 1.0):
            worst = ratio
        ok = ok and abs(ratio - 1.0) <= tol.speed_rel
        parts.append(f'{seg.name}: |encoder speed| / |command| = {ratio:.4g}')
    return rule_result('motion_speed', ok, worst, 'ratio', '; '.join(parts))


def rule_velocity_feedback(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check ``AxisFeedback.velocity_mm_s`` against the encoder's own slope (mm/s, sign)."""
    halves = _halves(rec)
    if isinstance(halves, str):
        return rule_failure('velocity_feedback', 'ratio', halves)
    fb = rec.feedback
    parts, worst, ok = [], 1.0, True
    for seg, m in halves:
        slope = fit_slope(fb.recv_ns[m], fb.position_mm[m])
        reported = float(np.mean(fb.velocity_mm_s[m]))
        ratio = reported / slope if slope != 0 and math.isfinite(slope) else math.nan
        if not abs(ratio - 1.0) <= abs(worst - 1.0):
            worst = ratio
        ok = ok and abs(ratio - 1.0) <= tol.velocity_rel
        parts.append(f'{seg.name}: reported {reported:+.4g} mm/s, encoder {slope:+.4g} mm/s')
    return rule_result('velocity_feedback', ok, worst, 'ratio', '; '.join(parts))


def rule_gap_tracks_encoder(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that over the flat sheet the gap reading changes as the encoder: d(gap)/dz = 1."""
    up, down = rec.segment(UP), rec.segment(DOWN)
    if up is None or down is None:
        return rule_failure('gap_tracks_encoder', 'mm/mm', rec.why_missing(UP, DOWN))
    fb, gp = rec.feedback, rec.gap
    mg = gp.window(up.start_ns, down.end_ns) & gp.valid & np.isfinite(gp.gap_mm)
    order = np.argsort(fb.recv_ns, kind='stable')
    if mg.sum() < 20 or len(fb) < 2:
        return rule_failure('gap_tracks_encoder', 'mm/mm',
                            f'too few valid gap readings ({int(mg.sum())})')
    z = np.interp(gp.recv_ns[mg], fb.recv_ns[order], fb.position_mm[order])
    if np.ptp(z) < 0.2 * rec.plan.test_travel_mm:
        return rule_failure('gap_tracks_encoder', 'mm/mm',
                            f'the encoder moved only {np.ptp(z):.3g} mm: '
                            'nothing to compare the reading with')
    fit = stats.linregress(z, gp.gap_mm[mg])
    slope = float(fit.slope)
    ok = abs(slope - 1.0) <= tol.gap_slope_rel
    hint = ''
    if not ok:
        if slope < 0:
            hint = ' (the reading falls as the axis rises: sign)'
        elif 500 < slope < 2000:
            hint = ' (x1000: the reading is in µm, not mm)'
        else:
            hint = ' (units, calibration table, or not a flat resting sheet)'
    return rule_result('gap_tracks_encoder', ok, slope, 'mm/mm',
                       f'gap reading vs encoder over {np.ptp(z):.3g} mm of travel: '
                       f'slope {slope:.4g}, residual '
                       f'{float(np.std(gp.gap_mm[mg] - fit.intercept - slope * z)):.2g} mm'
                       + hint)


def _watch(rec: Recording) -> tuple[Segment, Segment, np.ndarray] | str:
    run, silence = rec.segment(WATCHDOG), rec.segment(SILENCE)
    if run is None or silence is None:
        return rec.why_missing(WATCHDOG, SILENCE)
    fb = rec.feedback
    # The samples the drive published after the last command: reception minus the median
    # latch-to-arrival age (when positive: a stamp in the future says nothing about transport).
    age_ns = int(max(0.0, float(np.median(fb.recv_ns - fb.stamp_ns)))) if len(fb) else 0
    idx = np.flatnonzero(fb.window(silence.start_ns + 1 + age_ns, silence.end_ns))
    if len(idx) < 5:
        return f'too few feedback samples after the last command ({len(idx)})'
    return run, silence, idx


def rule_watchdog_fault(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that when commands stop, ``drive_fault`` comes with a reason within the timeout.

    Latency in the drive's own cycles (samples by ``seq`` from the first one it published
    after the last command: reception minus the median latch-to-arrival age), times its median
    period: the watchdog counts cycles, as the sim's and a fieldbus drive's do, so a stall of
    the prober's machine does not count against it.
    """
    w = _watch(rec)
    if isinstance(w, str):
        return rule_failure('watchdog_fault', 'ms', w)
    run, silence, idx = w
    fb = rec.feedback
    before = fb.window(run.start_ns, run.end_ns) & fb.drive_fault
    if before.any():
        i = int(np.flatnonzero(before)[0])
        return rule_failure('watchdog_fault', 'ms', 'drive fault while commands were still coming '
                            f'({fb.fault_reason[i] or "no reason"})')
    faulted = idx[fb.drive_fault[idx]]
    bar = tol.watchdog_timeout_s + tol.watchdog_allowance_s
    if not len(faulted):
        span = (fb.recv_ns[idx[-1]] - silence.start_ns) * 1e-9
        return rule_failure('watchdog_fault', 'ms',
                            f'no drive_fault in the {fmt_ms(span)} after the last '
                            'command (no watchdog?)')
    i = int(faulted[0])
    cycles = int(fb.seq[i] - fb.seq[idx[0]]) + 1
    latency = cycles * median_period_s(fb)
    wall = (fb.recv_ns[i] - silence.start_ns) * 1e-9
    reason = fb.fault_reason[i]
    ok = latency <= bar and bool(reason)
    return rule_result('watchdog_fault', ok, latency * 1e3, 'ms',
                       f'drive_fault {cycles} drive cycles ({fmt_ms(latency)}; '
                       f'{fmt_ms(wall)} by reception) '
                       f'after the last command, reason {reason!r}'
                       + ('' if reason else ' (EMPTY: a fault must say why)')
                       + ('' if latency <= bar else f' (later than {fmt_ms(bar)})'))


def rule_watchdog_stop(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that when commands stop, the axis brakes to rest within the timeout + allowance."""
    w = _watch(rec)
    if isinstance(w, str):
        return rule_failure('watchdog_stop', 'ms', w)
    _, silence, idx = w
    fb = rec.feedback
    p = fb.position_mm[idx]
    t = fb.recv_ns[idx]
    tail = t >= t[-1] - int(0.02e9)
    final = float(np.median(p[tail]))
    if np.ptp(p[tail]) > tol.rest_mm:
        since = fmt_ms((t[-1] - silence.start_ns) * 1e-9)
        return rule_failure('watchdog_stop', 'ms', f'still moving {since} after the last command '
                            f'({np.ptp(p[tail]) * 1e3:.3g} µm in its last 20 ms, '
                            f'{p[-1] - p[0]:+.3g} mm since): no stop')
    away = np.flatnonzero(np.abs(p - final) > tol.rest_mm)
    k = int(away[-1]) + 1 if len(away) else 0   # first sample of the final rest
    k = min(k, len(idx) - 1)
    cycles = int(fb.seq[idx[k]] - fb.seq[idx[0]]) + 1
    latency = cycles * median_period_s(fb)
    bar = tol.watchdog_timeout_s + tol.stop_allowance_s
    ok = latency <= bar
    return rule_result('watchdog_stop', ok, latency * 1e3, 'ms',
                       f'settled within ±{tol.rest_mm * 1e3:g} µm of its rest position {cycles} '
                       f'drive cycles ({fmt_ms(latency)}) after the last command, '
                       f'{(final - p[0]) * 1e3:+.3g} µm travelled after it'
                       + ('' if ok else f' (later than {fmt_ms(bar)})'))


def rule_motion_bag(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that the bag of the motion tests is written, complete, with its excitation."""
    b = rec.bag
    if b is None:
        return rule_failure('motion_bag', 'messages', 'no bag written')
    if not b.readable:
        return rule_failure('motion_bag', 'messages', f'{b.path}: not readable: {b.error}')
    missing = [f'{t} {b.counts.get(t, 0)} of {n}' for t, n in b.expected.items()
               if b.counts.get(t, 0) != n]
    problems = []
    if missing:
        problems.append('messages missing: ' + ', '.join(missing))
    if b.dropped:
        problems.append(f'{b.dropped} dropped by the writer')
    for t in ('/' + COMMAND_TOPIC, '/' + FEEDBACK_TOPIC, '/' + GAP_TOPIC):
        if not b.counts.get(t):
            problems.append(f'no {t}')
    if rec.plan.excitation is not None and rec.segment(EXCITATION) is None:
        problems.append('no excitation segment: ' + rec.why_missing(EXCITATION))
    total = sum(b.counts.values())
    return rule_result('motion_bag', not problems, total, 'messages',
                       f'{b.path}: {total} messages '
                       f'({b.counts.get("/" + COMMAND_TOPIC, 0)} commands)'
                       if not problems else '; '.join(problems))


def rule_one_commander(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check the drive executes one commander: a second one is refused, faults, until reset.

    While the prober commands zero (enabled), a second publisher sends upward commands under
    another commander name. The drive must not move, must fault within
    ``commander_fault_s`` (in its own cycles, from the first sample it latched after the
    first foreign send, as the watchdog rule counts), with a reason naming both commanders;
    the fault must hold while the prober alone commands again (no self-clearing), and clear
    after the reset service is called.
    """
    names = (SECOND_COMMANDER, FAULT_HOLDS, RESET_CALL, AFTER_RESET)
    missing = rec.why_missing(*names)
    if missing:
        return rule_failure('one_commander', 'ms', missing)
    foreign, holds, _, after = (rec.segment(n) for n in names)
    fb = rec.feedback
    if not len(rec.second_send_ns) or not len(fb):
        return rule_failure('one_commander', 'ms', 'no second commander sent, or no feedback')
    first = int(rec.second_send_ns[0])
    age_ns = int(max(0.0, float(np.median(fb.recv_ns - fb.stamp_ns))))
    idx = np.flatnonzero(fb.window(first + 1 + age_ns, holds.end_ns))
    if len(idx) < 5:
        return rule_failure('one_commander', 'ms', f'too few feedback samples after the second '
                            f'commander ({len(idx)})')
    problems = []
    p = fb.position_mm[np.flatnonzero(fb.window(foreign.start_ns, holds.end_ns))]
    moved = float(np.ptp(p)) if len(p) else 0.0
    if moved > tol.rest_mm:
        problems.append(f"the axis moved {moved * 1e3:.3g} µm on the second commander's "
                        'upward commands (executed)')
    faulted = idx[fb.drive_fault[idx]]
    latency = math.nan
    if not len(faulted):
        problems.append("no drive_fault after the second commander's commands")
    else:
        i = int(faulted[0])
        cycles = int(fb.seq[i] - fb.seq[idx[0]]) + 1
        latency = cycles * median_period_s(fb)
        reason = fb.fault_reason[i]
        if latency > tol.commander_fault_s:
            problems.append(f'drive_fault {cycles} drive cycles ({fmt_ms(latency)}) after the '
                            f'first foreign command (later than {fmt_ms(tol.commander_fault_s)})')
        absent = [n for n in (rec.commander, rec.second_commander) if n not in reason]
        if absent:
            problems.append(f'the fault reason {reason!r} does not name '
                            + ' and '.join(repr(n) for n in absent))
        held = np.flatnonzero(fb.window(max(holds.start_ns + age_ns, int(fb.recv_ns[i]) + 1),
                                        holds.end_ns))
        cleared = held[~fb.drive_fault[held]]
        if len(cleared):
            since = fmt_ms((fb.recv_ns[cleared[0]] - first) * 1e-9)
            problems.append(f'the fault cleared by itself {since} after the second commander '
                            'while only the prober commanded (it must hold until the reset)')
    if not rec.reset_answer.startswith('accepted'):
        problems.append(f'the reset service {RESET_SERVICE}: {rec.reset_answer or "not called"}')
    else:
        tail = np.flatnonzero(fb.window(after.end_ns - int(0.05e9), after.end_ns))
        if not len(tail) or fb.drive_fault[tail].any():
            problems.append('still faulted 50 ms before the end of the '
                            f'{fmt_ms((after.end_ns - after.start_ns) * 1e-9)} after the reset')
    if problems:
        return RuleResult('one_commander', False, latency * 1e3 if math.isfinite(latency)
                          else None, 'ms', ' '.join('; '.join(problems).split()))
    return rule_result('one_commander', True, latency * 1e3, 'ms',
                       f'second commander {rec.second_commander!r} refused: drive_fault after '
                       f'{fmt_ms(latency)}, no motion ({moved * 1e3:.3g} µm), held until the '
                       'reset, ready after it')
