"""Driver conformance: recorded samples in, pass/fail + figure out.

The kit's front, split by concern: :mod:`.conformance_recording` (what the live prober recorded
of a driver, no rclpy), :mod:`.conformance_rules` (tolerances, the rule table,
:func:`evaluate`) with the rules in :mod:`.conformance_stream` and :mod:`.conformance_motion`,
:mod:`.conformance_result` (the verdict and its report); and here the scenario under which the
sim node is a plain drive. docs/conformance.md lists the rules.
"""

from __future__ import annotations

from .conformance_recording import (
    AFTER_RESET,
    COMMAND_TOPIC,
    CONTRACT_TYPES,
    DOWN,
    ENABLE,
    EXCITATION,
    FAULT_HOLDS,
    FEEDBACK_TOPIC,
    GAP_TOPIC,
    H_S,
    PASSIVE,
    RESET_CALL,
    RESET_SERVICE,
    SECOND_COMMANDER,
    SILENCE,
    STATUS_COLLISION,
    STATUS_FAULT,
    STATUS_OK,
    STATUS_OUT_OF_RANGE,
    UP,
    WATCHDOG,
    BagCheck,
    Endpoint,
    FeedbackSamples,
    GapSamples,
    Graph,
    Plan,
    Recording,
    Segment,
)
from .conformance_result import (
    ConformanceResult,
    markdown,
)
from .conformance_rules import (
    RULE_NAMES,
    RULES,
    evaluate,
)
from .conformance_stream import (
    CONTRACT_WRITER,
    compatible,
)
from .conformance_tolerances import Tolerances

__all__ = [
    'AFTER_RESET',
    'BagCheck',
    'COMMAND_TOPIC',
    'CONTRACT_TYPES',
    'CONTRACT_WRITER',
    'ConformanceResult',
    'DOWN',
    'ENABLE',
    'EXCITATION',
    'Endpoint',
    'FAULT_HOLDS',
    'FEEDBACK_TOPIC',
    'FeedbackSamples',
    'GAP_TOPIC',
    'GapSamples',
    'Graph',
    'H_S',
    'PASSIVE',
    'Plan',
    'RESET_CALL',
    'RESET_SERVICE',
    'RULES',
    'RULE_NAMES',
    'Recording',
    'SECOND_COMMANDER',
    'SILENCE',
    'STATUS_COLLISION',
    'STATUS_FAULT',
    'STATUS_OK',
    'STATUS_OUT_OF_RANGE',
    'Segment',
    'Tolerances',
    'UP',
    'WATCHDOG',
    'compatible',
    'evaluate',
    'markdown',
    'sim_scenario_yaml',
]


# ---- the sim node as a drive ------------------------------------------------------------------
def sim_scenario_yaml(start_gap_mm: float = 5.0, duration_s: float = 120.0) -> str:
    """Return the scenario under which the sim node is a plain drive (``ladrc conform --sim``).

    A flat resting sheet (no profile), no follow commands (the sim node then waits for no
    controller and only executes ``axis/velocity_command``), the nozzle parked
    ``start_gap_mm`` above the sheet, the showcase's sensor (5 µm noise, 1 µm steps, 0.2 ms
    lag) and the default axis (T1 = 8 ms, b0 = 1, 5 ms watchdog in the node). The run lasts
    ``duration_s`` unless the prober stops the node first (it does, by PID).
    """
    return (
        'name: conform_drive\n'
        'description: >-\n'
        '  The sim node as a plain drive for ladrc conform --sim: flat resting sheet, no follow\n'
        f'  commands, nozzle parked {start_gap_mm:g} mm above the sheet.\n'
        f'duration_s: {duration_s:g}\n'
        'seed: 7\n'
        f'initial_gap_mm: {start_gap_mm:g}\n'
        'sensor: {noise_std_mm: 0.005, quant_mm: 0.001, lag_s: 0.0002}\n'
        'timeline: []\n')


