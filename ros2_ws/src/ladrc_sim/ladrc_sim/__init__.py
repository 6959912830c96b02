"""The simulated axis, sheet, sensor, jobs and CNC; the headless runner; the sim and CNC nodes.

The public names below are what other packages use; the nodes are the ``sim_node`` and
``cnc_node`` executables.
"""

from __future__ import annotations

from importlib import import_module

# the public API (name: module), imported on first use: importing the package
# loads nothing else
_EXPORTS = {
    'BatchUnsupported': 'headless.batch',
    'Event': 'headless.scenario',
    'JobError': 'job.jobfile',
    'KerfLayer': 'job.world',
    'ScenarioError': 'headless.scenario',
    'SheetXY': 'models.sheet_xy',
    'batchable_scenarios': 'headless.batch',
    'check_batchable': 'headless.batch',
    'default_device': 'cia402.can_drive',
    'find_job': 'job.jobfile',
    'job_figures': 'job.runner',
    'list_scenarios': 'headless.scenario',
    'load_job': 'job.jobfile',
    'load_scenario': 'headless.scenario',
    'oscillator_hz': 'models.sensor',
    'run': 'headless.runner',
    'run_batch': 'headless.batch',
    'run_job': 'job.runner',
    'run_text': 'job.jobfile',
    'scenario_from_dict': 'headless.scenario',
    'start_bus_server': 'cia402.bus',
    'summary': 'headless.runner',
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    """Import a public name from its module on first use."""
    try:
        module = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}') from None
    value = getattr(import_module(f'{__name__}.{module}'), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
