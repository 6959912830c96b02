"""The conformance rules: their tolerances, their table, and :func:`evaluate`.

Pure (no rclpy): :func:`evaluate` judges a :class:`~.conformance_recording.Recording` rule by rule
against the contract (docs/interfaces.md) with the documented tolerances of
:class:`Tolerances`. Every rule gives its measured figure and a one-line reason;
docs/conformance.md lists the rules. The rules themselves: :mod:`.conformance_stream` and
:mod:`.conformance_motion`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from .conformance_motion import (
    rule_drive_ready,
    rule_enable_false_holds,
    rule_gap_tracks_encoder,
    rule_motion_bag,
    rule_motion_direction,
    rule_motion_speed,
    rule_one_commander,
    rule_velocity_feedback,
    rule_watchdog_fault,
    rule_watchdog_stop,
)
from .conformance_recording import Plan, Recording
from .conformance_result import ConformanceResult, RuleResult, rule_failure
from .conformance_stream import (
    rule_jitter,
    rule_qos_command_input,
    rule_qos_publishers,
    rule_rate,
    rule_seq_increments,
    rule_stamp_age,
    rule_stamps_monotonic,
    rule_stamps_not_future,
    rule_topics_types,
)
from .conformance_tolerances import Tolerances


@dataclass(frozen=True)
class Rule:
    """One rule: name, what it checks, its tolerance (text from the tolerances), why."""

    name: str
    check: Callable[[Recording, Tolerances], RuleResult]
    what: str
    tolerance: Callable[[Tolerances, Plan], str]
    why: str


RULES: tuple[Rule, ...] = (
    Rule('topics_types', rule_topics_types,
         'the driver publishes axis/capacitive_height and axis/feedback and subscribes '
         'axis/velocity_command, with the contract types; one publisher each; no other node '
         'publishes commands',
         lambda t, p: 'exact',
         'the controller subscribes by name and type; two publishers interleave two seq streams'),
    Rule('qos_publishers', rule_qos_publishers,
         "the sample publishers' QoS: BEST_EFFORT, VOLATILE (the contract's), matching the "
         "controller's BEST_EFFORT keep-last-1 reader",
         lambda t, p: 'exact',
         'a control loop wants the freshest sample; reliable writers at 2 kHz cost the protocol '
         'traffic that made writers overflow (docs/interfaces.md)'),
    Rule('qos_command_input', rule_qos_command_input,
         "the driver's command subscription matches the controller's BEST_EFFORT, VOLATILE "
         'writer (a RELIABLE or TRANSIENT_LOCAL reader does not)',
         lambda t, p: 'exact',
         'an unmatched subscription never receives a command: the drive would only ever see '
         'its watchdog'),
    Rule('rate', rule_rate,
         'samples written per second on each topic (DDS writer sequence over the reception '
         'span)',
         lambda t, p: f'{t.rate_hz:g} Hz ± {t.rate_rel * 100:g} %',
         'the controller ticks at 2 kHz on the freshest sample'),
    Rule('jitter', rule_jitter,
         'p99 of the arrival period of each topic (as the controller receives it)',
         lambda t, p: f'≤ {t.period_p99_s * 1e3:g} ms',
         'a late sample is a tick on the encoder prediction; 10 ms is stale (follow.'
         'stale_timeout_s)'),
    Rule('seq_increments', rule_seq_increments,
         'seq grows by exactly one per sample written (compared with the DDS writer sequence, '
         'so transport loss is not counted against the driver)',
         lambda t, p: '0 wrong steps',
         'loss and latency are measured from seq (controller, recorder, report)'),
    Rule('stamps_monotonic', rule_stamps_monotonic,
         'header stamps strictly increase',
         lambda t, p: '0 non-increasing',
         'stamps order the samples in bags and replay'),
    Rule('stamps_not_future', rule_stamps_not_future,
         'no header stamp later than its own reception',
         lambda t, p: f'≤ {t.future_s * 1e3:g} ms',
         'the controller invalidates a sample stamped in the future (docs/safety.md); the '
         'allowance is the clock offset of a driver on another host'),
    Rule('stamp_age', rule_stamp_age,
         'reception minus stamp (latch to arrival): median, and the share older than the '
         "controller's stamp tolerance",
         lambda t, p: f'median ≤ {t.age_median_s * 1e3:g} ms, ≤ {t.age_late_share * 100:g} % '
                      f'older than {t.age_limit_s * 1e3:g} ms',
         "latency adds to the loop's dead time (delay margin 12 ms); the controller rejects "
         'samples older than 10 ms (stamp_tolerance_s)'),
    Rule('drive_ready', rule_drive_ready,
         'before any command: drive_enabled, no drive_fault, valid readings, gap above the '
         'minimum',
         lambda t, p: f'gap ≥ {p.min_gap_mm:g} mm',
         'the motion tests start only at a safe height on a ready drive'),
    Rule('enable_false_holds', rule_enable_false_holds,
         'an upward velocity with enable=false: the encoder does not move',
         lambda t, p: f'travel ≤ {t.enable_travel_mm:g} mm',
         'VelocityCommand.enable=false means hold zero whatever velocity_mm_s says'),
    Rule('motion_direction', rule_motion_direction,
         'commanded up then down: the encoder moves up then down',
         lambda t, p: 'same sign',
         'Z positive up, command positive up: a wrong sign drives the nozzle into the sheet'),
    Rule('motion_speed', rule_motion_speed,
         '|encoder speed| over |commanded speed| in the steady part of each half',
         lambda t, p: f'1 ± {t.speed_rel:g}',
         'the controller assumes b0 = 1 (mm/s per mm/s); identification refines it'),
    Rule('velocity_feedback', rule_velocity_feedback,
         'AxisFeedback.velocity_mm_s against the slope of position_mm',
         lambda t, p: f'1 ± {t.velocity_rel:g}',
         'the velocity field must be mm/s, positive up'),
    Rule('gap_tracks_encoder', rule_gap_tracks_encoder,
         'gap reading against encoder position over the up/down test (flat resting sheet)',
         lambda t, p: f'slope 1 ± {t.gap_slope_rel:g}',
         'gap in mm, growing as the axis rises; µm or a wrong table show up here'),
    Rule('watchdog_fault', rule_watchdog_fault,
         'commands stop: drive_fault with a fault_reason, latency in drive cycles',
         lambda t, p: f'≤ {(t.watchdog_timeout_s + t.watchdog_allowance_s) * 1e3:g} ms '
                      f'({t.watchdog_timeout_s * 1e3:g} ms timeout + '
                      f'{t.watchdog_allowance_s * 1e3:g} ms)',
         'a silent controller must not leave the axis moving (docs/safety.md: 5 ms)'),
    Rule('watchdog_stop', rule_watchdog_stop,
         'commands stop: the axis comes to rest (within rest_mm)',
         lambda t, p: f'≤ {(t.watchdog_timeout_s + t.stop_allowance_s) * 1e3:g} ms, rest '
                      f'within {t.rest_mm * 1e3:g} µm',
         'quick stop at the maximum deceleration after the watchdog'),
    Rule('one_commander', rule_one_commander,
         "a second commander's (upward) commands while the prober commands: not executed, "
         'drive_fault naming both, held until the reset service, ready after it',
         lambda t, p: f'fault ≤ {t.commander_fault_s * 1e3:g} ms, travel ≤ '
                      f'{t.rest_mm * 1e3:g} µm',
         'a second publisher at 1 kHz drove the nozzle 0.49 mm into the sheet; the drive is '
         'where a command is executed, so it is where one commander is enforced'),
    Rule('motion_bag', rule_motion_bag,
         'the bag of everything seen and sent, read back: every message there, the excitation '
         'segment included',
         lambda t, p: 'all messages',
         'the bag is the input of ladrc identify'),
)


RULE_NAMES = tuple(r.name for r in RULES)


def evaluate(rec: Recording, tol: Tolerances | None = None) -> ConformanceResult:
    """Judge a recording against every rule; a rule that raises is a failure with the error."""
    tol = tol or Tolerances()
    out = []
    for rule in RULES:
        try:
            r = rule.check(rec, tol)
        except Exception as exc:  # noqa: BLE001 - one broken figure must not hide the rest
            r = rule_failure(rule.name, '', f'could not be evaluated: {type(exc).__name__}: {exc}')
        r.tolerance = rule.tolerance(tol, rec.plan)
        out.append(r)
    return ConformanceResult(out, rec.aborted, rec.not_run, list(rec.notes))
