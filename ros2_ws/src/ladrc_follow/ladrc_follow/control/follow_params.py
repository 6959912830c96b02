"""Parameters of the follow state machine (the ``follow`` section of ControllerParams).

Kept apart from :mod:`.follow` so that :mod:`.params` can type its ``follow`` section with
:class:`FollowParams` without an import cycle. The checks that relate these values to each
other and to the rest of the set are in :func:`.params.validate`.
"""

from __future__ import annotations

from dataclasses import dataclass

from ladrc_contract.schema import Section, param

_SM = 'notes §3.5 Follow_OnStep'


@dataclass(frozen=True)
class FollowParams(Section):
    """Parameters of the follow state machine (``ControllerParams.follow``).

    The approach move uses ``ControllerParams.interp`` (v, a); "followed" uses
    ``pid.followed_tol_mm`` / ``pid.followed_hold_s`` (the seed's ``FollowPID_HasFollowed``);
    the output limits are ``ControllerParams.limits``.
    """

    PREFIX = 'follow.'

    controller: str = param('ladrc', '', "'ladrc': LADRC once followed; 'pid': PID only",
                            choices=('ladrc', 'pid'), seed=_SM)
    ladrc_while_machining: bool = param(False, '', 'run the LADRC while machining too '
                                        '(the seed runs it only when not machining)', seed=_SM)
    min_target_gap_mm: float = param(0.3, 'mm', 'smallest accepted follow gap (incl. '
                                     'compensation)', gt=0.0, le=20.0)
    max_target_gap_mm: float = param(20.0, 'mm', 'largest accepted follow gap (incl. '
                                     'compensation)', gt=0.0, le=100.0)
    max_compensation_mm: float = param(5.0, 'mm', 'largest |height compensation offset|',
                                       ge=0.0, le=20.0, seed='notes §3.5 UpdateCompHeightQueue')
    retarget_threshold_mm: float = param(1.0, 'mm', 'a target change above this '
                                         're-interpolates', gt=0.0, le=100.0, seed=_SM)
    reinterpolate: bool = param(True, '', 'a target change above retarget_threshold_mm goes '
                                'through the interpolated approach; false: straight to the '
                                'PID/LADRC and its TD, as in the seed (its re-interpolation '
                                "is commented out): for the notes' step experiments",
                                seed='notes §3.5 FS_PID_CONTROL')
    handover_window_mm: float = param(1.0, 'mm', '|error| within which the approach hands '
                                      'over to the PID', gt=0.0, le=20.0, seed=_SM)
    approach_lag_compensation: bool = param(True, '', 'subtract the planned travel the '
                                            'encoder still lags behind from the approach move')
    followed_widen_s: float = param(3.0, 's', 'not followed after this: the tolerance widens',
                                    gt=0.0, le=60.0)
    followed_wide_tol_mm: float = param(0.2, 'mm', 'the widened in-position tolerance',
                                        gt=0.0, le=5.0)
    followed_timeout_s: float = param(5.0, 's', 'not followed after this: FAULT (alarm)',
                                      gt=0.0, le=60.0)
    locking_timeout_s: float = param(1.0, 's', 'LOCKING waits this long for usable inputs',
                                     gt=0.0, le=60.0, seed='Locking_OnStep')
    stale_timeout_s: float = param(0.01, 's', 'input age limit (20 ticks at 2 kHz)',
                                   gt=0.0, le=0.1)
    invalid_timeout_s: float = param(0.005, 's', 'invalid reading (not miss-panel) tolerated '
                                     'this long', gt=0.0, le=0.1)
    invalid_rate_max: float = param(0.25, '1', 'largest share of invalid samples (low-passed '
                                    'over invalid_rate_tau_s) before FAULT, even when valid '
                                    'ones interleave', gt=0.0, le=1.0)
    invalid_rate_tau_s: float = param(0.05, 's', 'time constant of the invalid-sample share',
                                      gt=0.0, le=10.0)
    miss_panel_s: float = param(0.005, 's', 'out-of-range reading this long: miss-panel FAULT',
                                gt=0.0, le=0.1)
    collision_gap_mm: float = param(0.2, 'mm', 'a reading at or below this is a collision',
                                    gt=0.0, le=5.0)
    retract_distance_mm: float = param(2.0, 'mm', 'collision retract: distance up',
                                       gt=0.0, le=50.0)
    retract_velocity_mm_s: float = param(50.0, 'mm/s', 'collision retract: speed (capped by '
                                         'limits.v_max_mm_s)', gt=0.0, le=1000.0)
    jump_mm: float = param(0.3, 'mm', 'a new reading wider than the encoder-predicted gap by '
                           'more than this is not followed down (a sheet does not fall away that '
                           'fast in one sample)', gt=0.0, le=20.0)
    jump_confirm_s: float = param(0.01, 's', 'a jumped level that persists this long is taken '
                                  'as a real step of the sheet', gt=0.0, le=0.1)
    frozen_ticks: int = param(10, 'ticks', 'this many bit-identical readings in a row while '
                              'the encoder moved more than frozen_travel_mm: a frozen sensor',
                              ge=2, le=1000)
    frozen_travel_mm: float = param(0.02, 'mm', 'encoder travel that a frozen reading must '
                                    'have ignored to count as frozen', gt=0.0, le=5.0)
