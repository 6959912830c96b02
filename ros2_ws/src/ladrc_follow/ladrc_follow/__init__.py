"""The height-follow controller: the control core (plain Python + numpy), analysis, the node.

The public names below are what other packages use; the node is the ``follow_node``
executable (:mod:`.node.follow_node`).
"""

from __future__ import annotations

from ladrc_contract.lazy_api import lazy_api

# the public API (name: module), imported on first use: importing the package
# loads nothing else
_EXPORTS = {
    'AxisModel': 'analysis.loop',
    'CapTable': 'control.cap_table',
    'CncParams': 'control.cnc_params',
    'ControllerParams': 'control.params',
    'FollowController': 'control.follow',
    'INTERNALS_KEYS': 'control.follow',
    'LADRC': 'control.ladrc',
    'LinearESO': 'analysis.observers',
    'LoopAnalysis': 'analysis.loop',
    'ObserverAnalysis': 'analysis.loop',
    'ParameterError': 'control.params',
    'RawToGap': 'control.cap_table',
    'STATUS_COLLISION': 'control.cap_table',
    'STATUS_FAULT': 'control.cap_table',
    'STATUS_OK': 'control.cap_table',
    'StateSpace': 'analysis.loop',
    'TableLimits': 'control.cap_table',
    'analyse': 'analysis.loop',
    'analyse_observer': 'analysis.loop',
    'analyse_params': 'analysis.loop',
    'bandwidth_gains': 'control.eso',
    'check': 'control.params',
    'check_gate': 'analysis.gate',
    'continuous_matrices': 'control.eso',
    'controller_ss': 'analysis.loop',
    'dotted': 'control.params',
    'dump_params': 'control.params',
    'fal_alphas': 'control.eso',
    'frequency_grid': 'analysis.loop',
    'load_params': 'control.params',
    'parameter_file': 'control.params',
    'params_from_dict': 'control.params',
    'params_to_dict': 'control.params',
    'sim_time_s': 'node.samples',
    'stability_reasons': 'analysis.gate',
    'table_yaml': 'control.cap_table',
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_api(__name__, _EXPORTS)
