"""What makes a machine stand out from its fleet: rules on the machine-day figures.

Each rule compares a machine's day figure with the fleet's median of the same day (machines
run the same jobs, so the fleet is the reference, not a fixed number); a machine-day that
breaks a rule is flagged with the rule, its value and the fleet's. The limits were set on one
generated fleet (``ladrc fleet-gen --seed 1``: healthy machines' spread 0.9-1.1 in T1 and 0.8-1.2
in noise, ±1 % in gain, and the estimators' own scatter) between the healthy spread and the
smallest degradation, and are judged on fleets of other seeds (tests/test_fleet.py,
bench/fleet_scaling.py); docs/fleet.md gives the figures.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Rule:
    """``figure`` against the day's fleet median: ``ratio`` above, or ``offset`` away from it."""

    name: str
    figure: str
    why: str
    ratio: float = 0.0    # flag when value > ratio x median (0: not this test)
    offset: float = 0.0   # flag when |value - median| > offset (0: not this test)
    floor: float = 0.0    # ... and value > floor (the median may be ~0: faults per hour)


RULES = (
    Rule('sensor_gain', 'sensor_gain', 'the reading against the encoder differs from the '
         "fleet's by more than 5 % (a calibration drifting)", offset=0.05),
    Rule('sensor_noise', 'sensor_noise_mm', "sensor noise above 2 x the fleet's", ratio=2.0),
    Rule('slow_axis', 'axis_t1_ms', "velocity-loop time constant above 2 x the fleet's",
         ratio=2.0),
    Rule('error_rms', 'error_rms_mm', "follow error RMS above 2 x the fleet's", ratio=2.0),
    Rule('faults', 'faults_per_h', "faults per hour above 3 x the fleet's and above 2 / h",
         ratio=3.0, floor=2.0),
    Rule('overruns', 'overruns', "loop overruns above 3 x the fleet's and above 10 a day",
         ratio=3.0, floor=10.0),
)
"""The rules, in the order the report lists them."""


def flags(days: list[dict[str, Any]], rules: tuple[Rule, ...] = RULES) -> list[dict[str, Any]]:
    """Return one flag per machine-day and broken rule, with the values behind it."""
    out = []
    for day in sorted({d['day'] for d in days}):
        ds = [d for d in days if d['day'] == day]
        if len(ds) < 3:
            continue  # no fleet to stand out from
        for rule in rules:
            vals = np.array([np.nan if d.get(rule.figure) is None else float(d[rule.figure])
                             for d in ds])
            finite = vals[np.isfinite(vals)]
            if finite.size < 3:
                continue
            med = float(np.median(finite))
            for d, v in zip(ds, vals, strict=True):
                if not np.isfinite(v):
                    continue
                hit = ((rule.ratio and v > rule.ratio * med and v > rule.floor)
                       or (rule.offset and abs(v - med) > rule.offset))
                if hit:
                    out.append({'machine_id': d['machine_id'], 'day': day, 'rule': rule.name,
                                'figure': rule.figure, 'value': float(v), 'fleet_median': med,
                                'why': rule.why})
    return out


def param_changes(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Return each parameter-set change per machine: error RMS and faults/h before and after.

    A change is a new ``param_hash`` in a machine's bags in time order; before: its bags with
    the old set, after: with the new one (time-weighted error RMS).
    """
    out = []
    ok = sorted((r for r in rows if r['status'] == 'ok' and r['param_hash']),
                key=lambda r: (r['machine_id'], r['start_utc'] or '', r['bag']))
    for machine in sorted({r['machine_id'] for r in ok}):
        rs = [r for r in ok if r['machine_id'] == machine]
        runs: list[list[dict[str, Any]]] = []
        for r in rs:
            if runs and runs[-1][0]['param_hash'] == r['param_hash']:
                runs[-1].append(r)
            else:
                runs.append([r])
        for before, after in zip(runs, runs[1:], strict=False):
            b, a = _figures(before), _figures(after)
            out.append({'machine_id': machine, 'from_hash': before[0]['param_hash'],
                        'to_hash': after[0]['param_hash'], 'at': after[0]['start_utc'],
                        'bags_before': len(before), 'bags_after': len(after),
                        'error_rms_before_mm': b[0], 'error_rms_after_mm': a[0],
                        'faults_per_h_before': b[1], 'faults_per_h_after': a[1]})
    return out


def _figures(rs: list[dict[str, Any]]) -> tuple[float | None, float | None]:
    dur = np.array([r['duration_s'] or 0.0 for r in rs])
    rms = np.array([np.nan if r['error_rms_mm'] is None else r['error_rms_mm'] for r in rs])
    m = np.isfinite(rms) & (dur > 0)
    err = float(np.sqrt((rms[m] ** 2 * dur[m]).sum() / dur[m].sum())) if m.any() else None
    hours = dur.sum() / 3600.0
    faults = sum(r['faults'] or 0 for r in rs)
    return err, (faults / hours if hours > 0 else None)
