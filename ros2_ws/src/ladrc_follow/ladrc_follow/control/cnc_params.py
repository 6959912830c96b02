"""Parameters of the CNC interface (the ``cnc`` section of ControllerParams).

Kept apart from :mod:`.follow.cnc` (the partner that uses them) so that :mod:`.params` can type
its ``cnc`` section without an import cycle, as :mod:`.follow_params`.
"""

from __future__ import annotations

from dataclasses import dataclass

from ladrc_contract.schema import Section, param

_PLASMAC = 'LinuxCNC plasmac.comp'


@dataclass(frozen=True)
class CncParams(Section):
    """The CNC interface (``ControllerParams.cnc``)."""

    PREFIX = 'cnc.'

    corner_lock: bool = param(True, '', 'hold the height while the actual feed lags the '
                              'commanded one (corners, short segments)', seed=_PLASMAC)
    corner_lock_ratio: float = param(0.8, '1', 'corner lock: hold while actual / commanded feed '
                                     'is below this', gt=0.0, le=0.99, seed=_PLASMAC)
    corner_unlock_ratio: float = param(0.9, '1', 'corner lock: release once the ratio is at or '
                                       'above this (hysteresis; >= corner_lock_ratio)',
                                       gt=0.0, le=1.0, seed=_PLASMAC)
    corner_min_feed_mm_s: float = param(1.0, 'mm/s', 'a commanded cutting feed below this '
                                        'holds as a corner (no ratio to judge)', gt=0.0,
                                        le=1000.0)
    edge_ahead_hold_mm: float = param(10.0, 'mm', 'hold while cutting with the outline or a '
                                      'kerf this close ahead (about the sensor footprint '
                                      'radius); 0 = off', ge=0.0, le=100.0)
    edge_release_mm: float = param(10.0, 'mm', 'after the edge, stay held for this much path '
                                   '(the footprint still sees it)', ge=0.0, le=100.0)
    stale_timeout_s: float = param(0.02, 's', 'a CNC motion sample older than this, once one '
                                   'came, holds the height', gt=0.0, le=1.0)
    stale_lift_s: float = param(0.5, 's', 'a CNC silent this long while following (its last '
                                'motion sample this old): the CNC is gone, the head is lifted '
                                'by stale_lift_mm and held there; 0 = off (hold only)',
                                ge=0.0, le=60.0)
    stale_lift_mm: float = param(5.0, 'mm', 'the lift when the CNC has gone silent '
                                 '(stale_lift_s)', gt=0.0, le=50.0)
    moving_feed_mm_s: float = param(0.5, 'mm/s', 'XY counts as moving above this actual path '
                                    'speed (a CNC that does not wait)', gt=0.0, le=100.0)
    lift_velocity_mm_s: float = param(50.0, 'mm/s', 'lift speed when a lift gives none '
                                      '(capped by limits.v_max_mm_s)', gt=0.0, le=1000.0)
    leapfrog_velocity_mm_s: float = param(100.0, 'mm/s', 'leapfrog: Z speed limit of its moves '
                                          '(capped by limits.v_max_mm_s)', gt=0.0, le=1000.0,
                                          seed='Beckhoff TF5290')
    leapfrog_accel_mm_s2: float = param(2000.0, 'mm/s²', 'leapfrog: Z acceleration limit of its '
                                        'moves (capped by limits.a_max_mm_s2)', gt=0.0,
                                        le=1e6, seed='Beckhoff TF5290')
    leapfrog_settle_s: float = param(0.03, 's', 'leapfrog: time constant of the final approach '
                                     'to the arrival level (at least 4x the drive velocity '
                                     "loop's lag, or the lag carries the axis below it)",
                                     ge=0.005, le=1.0)
    feed_override_min: float = param(1.0, '1', 'adaptive feed: the lowest fraction of the '
                                     'programmed feed asked for while the gap is too close '
                                     '(feed_override_request); 1 = off (off by default: no '
                                     'gain measured, docs/job-world.md)', ge=0.05, le=1.0,
                                     seed=_PLASMAC)
    feed_override_error: float = param(0.1, '1', 'adaptive feed: a gap this fraction of the '
                                       'target below it asks for less feed, down to '
                                       'feed_override_min at twice it', gt=0.0, le=1.0)
    feed_override_recover_s: float = param(0.2, 's', 'adaptive feed: once the error is small '
                                           'the request returns from feed_override_min to 1 '
                                           'in this time (down: at once)', gt=0.0, le=10.0)
    max_lift_mm: float = param(50.0, 'mm', 'largest lift (by distance, or height above the '
                               'reading)', gt=0.0, le=500.0)


def cnc_problems(p) -> list[str]:
    """Cross checks of the ``cnc`` section against the rest of the set (params.CROSS_CHECKS)."""
    c = p.cnc
    out = []
    if c.corner_unlock_ratio < c.corner_lock_ratio:
        out.append(f'cnc.corner_unlock_ratio ({c.corner_unlock_ratio:g}) below '
                   f'cnc.corner_lock_ratio ({c.corner_lock_ratio:g}): the lock would chatter')
    if 0.0 < c.stale_lift_s < c.stale_timeout_s:
        out.append(f'cnc.stale_lift_s ({c.stale_lift_s:g}) below cnc.stale_timeout_s '
                   f'({c.stale_timeout_s:g}): the head would lift before it is held')
    if c.stale_lift_mm > c.max_lift_mm:
        out.append(f'cnc.stale_lift_mm ({c.stale_lift_mm:g}) above cnc.max_lift_mm '
                   f'({c.max_lift_mm:g})')
    return out
