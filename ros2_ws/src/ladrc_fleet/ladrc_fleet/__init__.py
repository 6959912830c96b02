"""The fleet tools: many machines' bags on a Dask cluster into tables, flags and a report.

:mod:`.discover` (the bags under folders and globs), :mod:`.bag_task` (one bag's row of
figures, on a worker), :mod:`.cache` (rows of bags already read), :mod:`.tables` (machine-day
and machine tables, Parquet), :mod:`.rules` (the machines and days that stand out, the
parameter-set changes), :mod:`.fleet_report` (fleet.md and its plots), :mod:`.run` (all of it:
``ladrc fleet``), :mod:`.generate` (a simulated fleet: ``ladrc fleet-gen``), :mod:`.cli` (the
two subcommands, registered with ``ladrc``). The Dask engine is ladrc_tools' (``offline.engine``,
shared with ``ladrc tune``). No rclpy.
"""

from __future__ import annotations

from .bag_task import ROW_FIELDS, bag_row
from .discover import Found, find_bags
from .generate import FleetPlan, FleetSpec, plan, write_bag, write_truth
from .rules import RULES, Rule, flags, param_changes
from .run import FleetResult, run_fleet
from .tables import machine_days, machines, write_parquet

__all__ = ['RULES', 'ROW_FIELDS', 'FleetPlan', 'FleetResult', 'FleetSpec', 'Found', 'Rule',
           'bag_row', 'find_bags', 'flags', 'machine_days', 'machines', 'param_changes', 'plan',
           'run_fleet', 'write_bag', 'write_parquet', 'write_truth']
