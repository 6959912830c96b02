"""The simulated axis, sheet, sensor, jobs and CNC; the headless runner; the sim and CNC nodes.

The public names below are what other packages use; the nodes are the ``sim_node`` and
``cnc_node`` executables.
"""

from __future__ import annotations

from ladrc_contract.lazy_api import lazy_api

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
__getattr__, __dir__ = lazy_api(__name__, _EXPORTS)
