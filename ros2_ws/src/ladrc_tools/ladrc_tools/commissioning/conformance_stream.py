"""The conformance rules on the driver's streams: topics, QoS, rate, jitter, seq, stamps.

Each rule takes the :class:`~.conformance_recording.Recording` and the tolerances and returns a
:class:`~.conformance_result.RuleResult` with its measured figure and a one-line reason.
"""

from __future__ import annotations

import math

import numpy as np

from .conformance_recording import (
    COMMAND_TOPIC,
    CONTRACT_TYPES,
    FEEDBACK_TOPIC,
    GAP_TOPIC,
    PASSIVE,
    Endpoint,
    Recording,
    Samples,
)
from .conformance_result import RuleResult, fmt_ms, rule_failure, rule_result
from .conformance_tolerances import Tolerances


def compatible(writer: Endpoint, reader: Endpoint) -> tuple[bool, str]:
    """Return whether ``reader`` receives from ``writer``: DDS request-vs-offered matching.

    A BEST_EFFORT reader matches any writer; a RELIABLE reader only a RELIABLE writer. A
    VOLATILE reader matches any writer; a TRANSIENT_LOCAL reader only a TRANSIENT_LOCAL one.
    """
    rel_rank = {'BEST_EFFORT': 0, 'RELIABLE': 1}
    dur_rank = {'VOLATILE': 0, 'TRANSIENT_LOCAL': 1}
    why = []
    if rel_rank.get(reader.reliability, 1) > rel_rank.get(writer.reliability, 0):
        why.append(f'a {reader.reliability} reader does not match a {writer.reliability} '
                   'writer')
    if dur_rank.get(reader.durability, 1) > dur_rank.get(writer.durability, 0):
        why.append(f'a {reader.durability} reader does not match a {writer.durability} writer')
    return not why, '; '.join(why)


# The contract's endpoints (docs/interfaces.md, QoS; ladrc_contract/qos.py).
CONTRACT_READER = Endpoint('controller', '', 'BEST_EFFORT', 'VOLATILE')


CONTRACT_WRITER = Endpoint('controller', '', 'BEST_EFFORT', 'VOLATILE')


def _topics(rec: Recording) -> list[tuple[str, Samples]]:
    """Return both sample topics from the passive window on (the stream rules' data).

    The first deliveries after the reader matched carry whatever the middleware had queued
    (seen: a stale sample, then a 333 ms gap and a jump of 411 in seq); they say nothing about
    the driver, so the stream is judged from the passive window on (the prober starts it once
    the stream is steady).
    """
    seg = rec.segment(PASSIVE)
    if seg is None:
        return [(GAP_TOPIC, rec.gap), (FEEDBACK_TOPIC, rec.feedback)]
    return [(GAP_TOPIC, rec.gap.since(seg.start_ns)),
            (FEEDBACK_TOPIC, rec.feedback.since(seg.start_ns))]


# ---- the rules ------------------------------------------------------------------------------
def rule_topics_types(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that the driver publishes both sample topics and subscribes the command."""
    problems = []
    for topic, kind, eps in ((GAP_TOPIC, 'publisher', rec.graph.publishers.get(GAP_TOPIC, [])),
                             (FEEDBACK_TOPIC, 'publisher',
                              rec.graph.publishers.get(FEEDBACK_TOPIC, [])),
                             (COMMAND_TOPIC, 'subscription',
                              rec.graph.subscriptions.get(COMMAND_TOPIC, []))):
        want = CONTRACT_TYPES[topic]
        if not eps:
            problems.append(f'no {kind} on {topic}')
            continue
        wrong = sorted({e.type_name for e in eps if e.type_name != want})
        if wrong:
            problems.append(f'{topic} has type {", ".join(wrong)} (contract: {want})')
        if kind == 'publisher' and len(eps) > 1:
            problems.append(f'{len(eps)} publishers on {topic} '
                            f'({", ".join(e.node for e in eps)}): their samples interleave')
    others = rec.graph.publishers.get(COMMAND_TOPIC, [])
    if others:
        problems.append(f'another node publishes {COMMAND_TOPIC} '
                        f'({", ".join(e.node for e in others)}): stop it before the tests')
    ok = not problems
    return rule_result('topics_types', ok, len(problems), 'problems',
                       'both sample topics published and the command subscribed with the contract '
                       'types' if ok else '; '.join(problems))


def rule_qos_publishers(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that the sample publishers are BEST_EFFORT, VOLATILE as the contract's."""
    bad = []
    n = 0
    for topic in (GAP_TOPIC, FEEDBACK_TOPIC):
        for e in rec.graph.publishers.get(topic, []):
            n += 1
            ok, why = compatible(e, CONTRACT_READER)
            if not ok:
                bad.append(f'{topic} ({e.node}): the controller never receives it: {why}')
            elif e.reliability != 'BEST_EFFORT':
                bad.append(f'{topic} ({e.node}) is {e.reliability}: the contract is '
                           'BEST_EFFORT (reliable writers at 2 kHz lost 7-50 % to the '
                           'recorder on a loaded machine, docs/interfaces.md)')
            elif e.durability != 'VOLATILE':
                bad.append(f'{topic} ({e.node}) is {e.durability}: the contract is VOLATILE '
                           '(a late reader must not get stale samples)')
    if n == 0:
        return rule_failure('qos_publishers', 'publishers',
                            'no publisher of the sample topics found')
    return rule_result('qos_publishers', not bad, len(bad), 'publishers off-contract',
                       f'{n} publisher(s) BEST_EFFORT, VOLATILE as the contract' if not bad
                       else '; '.join(bad))


def rule_qos_command_input(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that the driver's command subscription receives best-effort commands."""
    subs = rec.graph.subscriptions.get(COMMAND_TOPIC, [])
    if not subs:
        return rule_failure('qos_command_input', 'subscriptions',
                            f'no subscription on {COMMAND_TOPIC}')
    bad = []
    for e in subs:
        ok, why = compatible(CONTRACT_WRITER, e)
        if not ok:
            bad.append(f"{e.node}: the controller's BEST_EFFORT, VOLATILE commands never "
                       f'arrive ({why})')
    return rule_result('qos_command_input', not bad, len(bad), 'subscriptions incompatible',
                       f'{len(subs)} subscription(s) match a BEST_EFFORT, VOLATILE writer'
                       if not bad else '; '.join(bad))


def _rate(s: Samples) -> tuple[float, int]:
    """Return (samples per second the driver wrote, samples lost on the way)."""
    if len(s) < 2 or s.recv_ns[-1] <= s.recv_ns[0]:
        return 0.0, 0
    span_s = (s.recv_ns[-1] - s.recv_ns[0]) * 1e-9
    if s.pub_seq is not None:
        written = int(s.pub_seq[-1] - s.pub_seq[0])
        return written / span_s, max(0, written + 1 - len(s))
    return (len(s) - 1) / span_s, 0


def rule_rate(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that each sample topic arrives at 2 kHz (writes over the reception span)."""
    parts, worst, ok = [], math.nan, True
    for topic, s in _topics(rec):
        rate, lost = _rate(s)
        dev = abs(rate - tol.rate_hz) / tol.rate_hz
        if not dev <= tol.rate_rel:
            ok = False
        if math.isnan(worst) or dev > abs(worst - tol.rate_hz) / tol.rate_hz:
            worst = rate
        parts.append(f'{topic} {rate:.0f} Hz ({len(s)} received, {lost} lost in transport)')
    return rule_result('rate', ok, worst, 'Hz', '; '.join(parts))


def rule_jitter(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check the arrival period (what the controller sees): p99 <= 3 sample periods."""
    parts, worst, ok = [], 0.0, True
    for topic, s in _topics(rec):
        if len(s) < 100:
            ok = False
            parts.append(f'{topic}: {len(s)} samples, too few to judge')
            continue
        d = np.diff(s.recv_ns) * 1e-9
        p99 = float(np.percentile(d, 99))
        st = np.diff(s.stamp_ns) * 1e-9
        worst = max(worst, p99)
        ok = ok and p99 <= tol.period_p99_s
        parts.append(f'{topic} arrival p99 {fmt_ms(p99)} (max {fmt_ms(float(d.max()))}; '
                     'stamps p99 '
                     f'{fmt_ms(float(np.percentile(st, 99)))})')
    return rule_result('jitter', ok, worst * 1e3, 'ms', '; '.join(parts))


def rule_seq_increments(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that ``seq`` grows by one per sample written: no skipped or repeated numbers."""
    parts, total, ok = [], 0, True
    for topic, s in _topics(rec):
        if len(s) < 2:
            ok = False
            parts.append(f'{topic}: nothing to judge ({len(s)} samples)')
            continue
        ds = np.diff(s.seq)
        if s.pub_seq is not None:
            expected = np.diff(s.pub_seq)
            how = 'vs the DDS writer sequence'
        else:
            expected = np.ones_like(ds)
            how = 'no DDS sequence: transport loss counts too'
        wrong = np.flatnonzero(ds != expected)
        total += len(wrong)
        ok = ok and not len(wrong)
        example = (f'; first {int(s.seq[wrong[0]])} -> {int(s.seq[wrong[0] + 1])}'
                   if len(wrong) else '')
        parts.append(f'{topic}: {len(wrong)} of {len(ds)} steps wrong ({how}{example})')
    return rule_result('seq_increments', ok, total, 'wrong steps', '; '.join(parts))


def rule_stamps_monotonic(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that header stamps strictly increase, sample after sample."""
    parts, total, ok = [], 0, True
    for topic, s in _topics(rec):
        if len(s) < 2:
            ok = False
            parts.append(f'{topic}: nothing to judge')
            continue
        bad = int(np.count_nonzero(np.diff(s.stamp_ns) <= 0))
        total += bad
        ok = ok and bad == 0
        parts.append(f'{topic}: {bad} non-increasing of {len(s) - 1}')
    return rule_result('stamps_monotonic', ok, total, 'steps', '; '.join(parts))


def rule_stamps_not_future(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that no stamp lies after its own reception (beyond a clock-offset allowance)."""
    parts, worst, ok = [], -math.inf, True
    for topic, s in _topics(rec):
        if not len(s):
            ok = False
            parts.append(f'{topic}: nothing received')
            continue
        lead = float(np.max(s.stamp_ns - s.recv_ns)) * 1e-9
        n = int(np.count_nonzero((s.stamp_ns - s.recv_ns) * 1e-9 > tol.future_s))
        worst = max(worst, lead)
        ok = ok and lead <= tol.future_s
        parts.append(f'{topic}: stamp - reception max {fmt_ms(lead)} ({n} samples beyond)')
    return rule_result('stamps_not_future', ok,
                       worst * 1e3 if math.isfinite(worst) else None, 'ms',
                       '; '.join(parts))


def rule_stamp_age(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check reception minus stamp (latch to arrival): median, and the share too old to use.

    The median is the driver's systematic latency (it adds to the loop's dead time); the
    share older than the controller's ``stamp_tolerance_s`` (10 ms) is what it would throw
    away. A stall of the host delivers a backlog at once (a loaded host stalls for hundreds of
    milliseconds now and then), so a high percentile is no fair test of a short run.
    """
    parts, worst, ok = [], 0.0, True
    for topic, s in _topics(rec):
        if not len(s):
            ok = False
            parts.append(f'{topic}: nothing received')
            continue
        age = (s.recv_ns - s.stamp_ns) * 1e-9
        med = float(np.median(age))
        late = float(np.mean(age > tol.age_limit_s))
        worst = max(worst, med)
        ok = ok and med <= tol.age_median_s and late <= tol.age_late_share
        p99 = float(np.percentile(age, 99))
        parts.append(f'{topic}: age median {fmt_ms(med)}, p99 {fmt_ms(p99)}'
                     f', {late * 100:.3g} % older than {fmt_ms(tol.age_limit_s)}')
    return rule_result('stamp_age', ok, worst * 1e3, 'ms', '; '.join(parts))
