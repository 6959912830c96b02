"""A job file: the sheet, the part program (DXF), the feeds and heights, the machine's limits.

YAML, one mapping (docs/job-world.md has the keys): ``name``, ``description``, ``dxf`` (relative
to the job file), ``sheet`` (``width_mm``, ``height_mm``, ``surface``: models/sheet_xy.py
``SurfaceParams``), ``cut`` (``kerf_mm``, ``lead_in_mm``, ``micro_joint_mm``,
``micro_joints_per_part``), ``cnc`` (job/cnc.py ``CncSettings``), ``controller`` (parameter
overrides of the follow controller, ``name: value``), ``sensor`` (models/sensor.py
``SensorParams``), ``tip_parts`` and ``tip_rise_mm`` (parts that tip up when cut free),
``start_xy`` and ``start_height_mm``, ``dxf_origin_mm`` (where the drawing's (0, 0) lies on
the sheet: the CNC's work offset), ``seed``, and ``limits`` (where the job's geometry makes
the safety bar impossible: the bound that proves it, docs/job-world.md); how the DXF is read,
declared once in :class:`DrawingKeys`: ``dxf_units``, ``layers``, ``join_tolerance_mm`` and
``open_contours``. Every problem is one
line naming the file and the key (:class:`JobError`).

``gcode`` instead of ``dxf`` (relative to the job file): the job's program is a G-code file of
the user's, read by LinuxCNC's own interpreter (``bringup --cnc linuxcnc``, docs/linuxcnc.md),
never by a parser here: such a job has the sheet, the heights and the feeds of its file but no
part program (no contours: the world lays the kerfs where the CNC's samples say the beam cut,
and no part drops out); ``time_budget_s`` bounds its run (default 600 s for a G-code job).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
import math
from pathlib import Path
import typing
from typing import Any

from ladrc_contract.schema import param, value_problems
from shapely.geometry import box
import yaml

from ..models.axis import ParamError, check_fields
from ..models.sensor import SensorParams
from ..models.sheet_xy import SurfaceParams
from .cnc import CncSettings
from .program import (
    JOIN_TOLERANCE_MM,
    OPEN_CONTOURS,
    UNIT_MM,
    Program,
    ProgramError,
    load_program,
)


class JobError(ValueError):
    """A job file is malformed; the message is one line naming the file and the key."""


@dataclass(frozen=True)
class ContactInjection:
    """A collision injected at a known point of the job (the job file's ``contact`` section).

    When the CNC has cut its ``nth_cut``-th contour (1: the first it cuts) for ``after_s``, the
    material in a ``size_mm`` square around the nozzle rises by ``rise_mm`` (as a part tipping
    up there): the nozzle meets it, whatever the timing of the CNC (simulated or LinuxCNC).
    """

    nth_cut: int = param(1, '1', 'the contour cut when the material rises: 1 the first the '
                         'CNC cuts, 2 the second, ...', ge=1)
    after_s: float = param(0.3, 's', 'cutting time into that contour', ge=0.0, le=600.0)
    rise_mm: float = param(4.0, 'mm', 'how far the material rises under the nozzle', gt=0.0,
                           le=20.0)
    size_mm: float = param(40.0, 'mm', 'side of the square that rises, centred on the nozzle',
                           gt=1.0, le=500.0)

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class DrawingKeys:
    """The job file's keys on how its DXF is read (top-level keys; job/program.py)."""

    dxf_units: str | None = param(
        None, '', "the drawing's units where the DXF does not say them (an R12 file, no "
        '$INSUNITS or $INSUNITS=0); where it does, they must agree', choices=tuple(UNIT_MM))
    layers: tuple[str, ...] = param(
        (), '', 'the DXF layers read, by name, case-insensitive (empty: all)')
    join_tolerance_mm: float = param(
        JOIN_TOLERANCE_MM, 'mm', 'ends nearer than this are joined into one contour (the gap '
        'closed by a straight step); entities shorter are dropped', gt=0.0, le=5.0)
    open_contours: str = param(
        'cut_closed', '', 'a chain that does not close within join_tolerance_mm: cut_closed '
        '(every closed contour is cut, each open one listed in the log and the figures) or '
        'refuse (the drawing is refused, naming the entity)', choices=OPEN_CONTOURS)

    @classmethod
    def read(cls, data: dict, path: Path) -> DrawingKeys:
        """Return the keys of job file ``data``: one line naming the key if one is bad."""
        units = data.get('dxf_units')
        if units is not None:
            spec = next(f for f in fields(cls) if f.name == 'dxf_units').metadata['spec']
            bad = value_problems('dxf_units', str, units, spec)
            if bad:
                raise JobError(f'{path}: dxf_units: {units!r}: one of {spec.range_text()} '
                               "(the drawing's units where the DXF does not say them)")
        layers = data.get('layers')
        if layers is None:
            layers = []
        if isinstance(layers, str):
            layers = [layers]
        if not isinstance(layers, list) or any(
                isinstance(x, (bool, dict, list)) or x is None or str(x) == '' for x in layers):
            raise JobError(f'{path}: layers: a list of DXF layer names, got {layers!r}')
        values = {}
        for key in ('join_tolerance_mm', 'open_contours'):
            if key not in data:
                continue
            f = next(f for f in fields(cls) if f.name == key)
            spec = f.metadata['spec']
            kind = float if key == 'join_tolerance_mm' else str
            v = data[key]
            if kind is float and isinstance(v, int) and not isinstance(v, bool):
                v = float(v)
            bad = value_problems(key, kind, v, spec)
            if bad:
                raise JobError(f'{path}: {bad[0]}')
            values[key] = v
        return cls(dxf_units=units, layers=tuple(str(x) for x in layers), **values)


@dataclass(frozen=True)
class Job:
    """A loaded job file."""

    path: Path
    name: str
    description: str
    dxf: Path | None  # None: a G-code job (``gcode``)
    width_mm: float
    height_mm: float
    surface: SurfaceParams
    kerf_mm: float
    lead_in_mm: float
    micro_joint_mm: float
    micro_joints_per_part: int
    cnc: CncSettings
    controller: dict[str, Any]
    sensor: SensorParams
    tip_parts: tuple[int, ...] = ()
    tip_rise_mm: float = 3.0
    start_xy: tuple[float, float] = (0.0, 0.0)
    start_height_mm: float = 10.0
    dxf_origin_mm: tuple[float, float] = (0.0, 0.0)
    seed: int = 1
    limits: dict[str, Any] = field(default_factory=dict)
    drawing: DrawingKeys = DrawingKeys()
    gcode: Path | None = None  # the user's G-code program (LinuxCNC reads it), instead of dxf
    time_budget: float | None = None  # the job file's time_budget_s, if it gives one
    expect_fault: bool = False  # the run may end in FAULT (a job that provokes one)
    contact: ContactInjection | None = None  # a collision injected at a known point

    def plate(self):
        """Return the plate's outline (a rectangle from the origin)."""
        return box(0.0, 0.0, self.width_mm, self.height_mm)

    def program(self) -> Program:
        """Return the job's part program (read from its DXF once per job object)."""
        cached = self.__dict__.get('_program')
        if cached is not None:
            return cached
        if self.gcode is not None:  # LinuxCNC reads the program: no contours here
            program = Program(str(self.gcode), 'mm', 1.0, (), (),
                              (0.0, 0.0, self.width_mm, self.height_mm), (), 'G-code')
            object.__setattr__(self, '_program', program)
            return program
        try:
            program = load_program(self.dxf, kerf_mm=self.kerf_mm, lead_in_mm=self.lead_in_mm,
                                   micro_joint_mm=self.micro_joint_mm,
                                   micro_joints_per_part=self.micro_joints_per_part,
                                   sheet_mm=(self.width_mm, self.height_mm),
                                   origin_mm=self.dxf_origin_mm,
                                   units=self.drawing.dxf_units,
                                   layers=self.drawing.layers or None,
                                   join_tolerance_mm=self.drawing.join_tolerance_mm,
                                   open_contours=self.drawing.open_contours,
                                   small_contour_mm=self.cnc.small_contour_mm)
        except ProgramError as exc:
            raise JobError(f'{self.path}: {exc}') from None
        object.__setattr__(self, '_program', program)  # a frozen job: its program, once
        return program

    def time_budget_s(self, program: Program) -> float:
        """Return a generous bound of the job's time (its run stops there, unfinished)."""
        if self.time_budget is not None:
            return self.time_budget
        if self.gcode is not None:
            return GCODE_TIME_BUDGET_S
        c = self.cnc
        cut = sum(k.length_mm + 50.0 for k in program.contours) / c.feed_mm_s
        pierce = len(program.contours) * (sum(c.pierce_dwell_s) + c.thc_delay_s + 2.0)
        rapid = len(program.contours) * (math.hypot(self.width_mm, self.height_mm)
                                         / c.rapid_mm_s + 1.0)
        return 2.0 * (cut + pierce + rapid) + 10.0

    def with_changes(self, cnc: dict[str, Any] | None = None,
                     controller: dict[str, Any] | None = None) -> Job:
        """Return the job with CNC settings or controller parameters changed (a feature off)."""
        return replace(self, cnc=replace(self.cnc, **(cnc or {})),
                       controller={**self.controller, **(controller or {})})


def _section(cls: type, data: Any, where: str) -> Any:
    """Build dataclass ``cls`` from a mapping: unknown keys, types and ranges are one line."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise JobError(f'{where}: must be a mapping')
    names = {f.name for f in fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise JobError(f'{where}.{unknown[0]}: unknown key (allowed: {", ".join(sorted(names))})')
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for k, v in data.items():
        tp = hints[k]
        origin = typing.get_origin(tp)
        if origin is tuple:
            if not isinstance(v, list) or any(isinstance(x, bool) or not isinstance(
                    x, (int, float)) for x in v):
                raise JobError(f'{where}.{k}: expected a list of numbers, got {v!r}')
            v = tuple(float(x) for x in v)
        elif tp is float:
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise JobError(f'{where}.{k}: expected a number, got {v!r}')
            v = float(v)
        elif tp is int and (isinstance(v, bool) or not isinstance(v, int)):
            raise JobError(f'{where}.{k}: expected an integer, got {v!r}')
        elif tp is bool and not isinstance(v, bool):
            raise JobError(f'{where}.{k}: expected true or false, got {v!r}')
        kwargs[k] = v
    try:
        return cls(**kwargs)
    except ParamError as exc:
        raise JobError(f'{where}.{exc.key}: {exc.reason}') from None
    except (TypeError, ValueError) as exc:
        raise JobError(f'{where}: {exc}') from None


_TOP = ('name', 'description', 'dxf', 'sheet', 'cut', 'cnc', 'controller', 'sensor',
        'tip_parts', 'tip_rise_mm', 'start_xy', 'start_height_mm', 'dxf_origin_mm', 'seed',
        'limits', *(f.name for f in fields(DrawingKeys)), 'gcode', 'time_budget_s',
        'expect_fault', 'contact')
GCODE_TIME_BUDGET_S = 600.0
"""A G-code job's time bound when its file gives no ``time_budget_s``."""


def _xy(data: dict, key: str, path: Path) -> tuple[float, float]:
    """Return ``data[key]`` as a point [x, y] in mm (default the origin); one line if not."""
    v = data.get(key, [0.0, 0.0])
    if not (isinstance(v, list) and len(v) == 2 and all(
            not isinstance(x, bool) and isinstance(x, (int, float)) and math.isfinite(x)
            for x in v)):
        raise JobError(f'{path}: {key}: [x, y] in mm, got {v!r}')
    return float(v[0]), float(v[1])


def load_job(path: str | Path) -> Job:
    """Read and check a job file; raise :class:`JobError` (one line) if it is unusable."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text(encoding='utf-8'))
    except OSError as exc:
        raise JobError(f'{path}: cannot read: {exc.strerror or exc}') from None
    except yaml.YAMLError as exc:
        raise JobError(f'{path}: not YAML: {" ".join(str(exc).split())[:120]}') from None
    if not isinstance(data, dict):
        raise JobError(f'{path}: a job file is a mapping of keys')
    unknown = sorted(set(data) - set(_TOP))
    if unknown:
        raise JobError(f'{path}: {unknown[0]}: unknown key (allowed: {", ".join(_TOP)})')
    for req in ('name', 'sheet'):
        if req not in data:
            raise JobError(f'{path}: {req}: missing')
    if ('dxf' in data) == ('gcode' in data):
        raise JobError(f'{path}: dxf or gcode: the program, one of them '
                       + ('(both given)' if 'dxf' in data else '(neither given)'))
    expect_fault = data.get('expect_fault', False)
    if not isinstance(expect_fault, bool):
        raise JobError(f'{path}: expect_fault: true or false, got {expect_fault!r}')
    budget = data.get('time_budget_s')
    if budget is not None and (isinstance(budget, bool) or not isinstance(budget, (int, float))
                               or not 1.0 <= budget <= 86400.0):
        raise JobError(f'{path}: time_budget_s: a number of 1..86400 s, got {budget!r}')
    sheet = data['sheet']
    if not isinstance(sheet, dict):
        raise JobError(f'{path}: sheet: must be a mapping')
    w, h = sheet.get('width_mm'), sheet.get('height_mm')
    for k, v in (('width_mm', w), ('height_mm', h)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 10.0 <= v <= 10000.0:
            raise JobError(f'{path}: sheet.{k}: a number of 10..10000 mm, got {v!r}')
    extra = sorted(set(sheet) - {'width_mm', 'height_mm', 'surface'})
    if extra:
        raise JobError(f'{path}: sheet.{extra[0]}: unknown key')
    cut = data.get('cut') or {}
    if not isinstance(cut, dict):
        raise JobError(f'{path}: cut: must be a mapping')
    kerf = cut.get('kerf_mm', 0.2)
    if isinstance(kerf, bool) or not isinstance(kerf, (int, float)) or not 0.0 <= kerf <= 5.0:
        raise JobError(f'{path}: cut.kerf_mm: a number of 0..5 mm, got {kerf!r}')
    extra = sorted(set(cut) - {'kerf_mm', 'lead_in_mm', 'micro_joint_mm',
                               'micro_joints_per_part'})
    if extra:
        raise JobError(f'{path}: cut.{extra[0]}: unknown key')
    controller = data.get('controller') or {}
    if not isinstance(controller, dict):
        raise JobError(f'{path}: controller: a mapping of parameter: value')
    key = 'dxf' if 'dxf' in data else 'gcode'
    source = path.parent / str(data[key])
    if not source.is_file():
        raise JobError(f'{path}: {key}: {source} does not exist')
    dxf, gcode = (source, None) if key == 'dxf' else (None, source)
    tips = data.get('tip_parts') or []
    if not isinstance(tips, list) or any(isinstance(x, bool) or not isinstance(x, int)
                                         for x in tips):
        raise JobError(f'{path}: tip_parts: a list of part indices')
    start = _xy(data, 'start_xy', path)
    origin = _xy(data, 'dxf_origin_mm', path)
    drawing = DrawingKeys.read(data, path)
    sensor = _section(SensorParams, data.get('sensor'), f'{path}: sensor')
    cnc = _section(CncSettings, data.get('cnc'), f'{path}: cnc')
    if cnc.small_contour_mm < 0.0:  # the default: the nozzle face (the field beyond it)
        cnc = replace(cnc, small_contour_mm=sensor.nozzle_diameter_mm)
    return Job(path=path, name=str(data['name']), description=str(data.get('description', '')),
               dxf=dxf, width_mm=float(w), height_mm=float(h),
               surface=_section(SurfaceParams, sheet.get('surface'), f'{path}: sheet.surface'),
               kerf_mm=float(kerf), lead_in_mm=float(cut.get('lead_in_mm', 3.0)),
               micro_joint_mm=float(cut.get('micro_joint_mm', 0.0)),
               micro_joints_per_part=int(cut.get('micro_joints_per_part', 0)),
               cnc=cnc, controller=dict(controller), sensor=sensor,
               tip_parts=tuple(tips), tip_rise_mm=float(data.get('tip_rise_mm', 3.0)),
               start_xy=start, dxf_origin_mm=origin,
               start_height_mm=float(data.get('start_height_mm', 10.0)),
               seed=int(data.get('seed', 1)), limits=dict(data.get('limits') or {}),
               drawing=drawing, gcode=gcode,
               time_budget=float(budget) if budget is not None else None,
               expect_fault=expect_fault,
               contact=(_section(ContactInjection, data['contact'], f'{path}: contact')
                        if data.get('contact') is not None else None))


JOBS_DIR = Path(__file__).resolve().parent / 'jobs'
"""The shipped job library (``ladrc job NAME``, ``bringup --job NAME``)."""


def shipped_jobs() -> dict[str, Path]:
    """Return the shipped job files by name."""
    return {p.stem: p for p in sorted(JOBS_DIR.glob('*.yaml'))}


def find_job(name: str | Path) -> Job:
    """Return the job of a path or a shipped job's name, its program read; JobError (one line)."""
    path = Path(name)
    if not path.exists():
        shipped = shipped_jobs()
        if str(name) not in shipped:
            raise JobError(f'{name}: no such job file or shipped job '
                           f'(shipped: {", ".join(shipped) or "none"})')
        path = shipped[str(name)]
    job = load_job(path)
    job.program()
    return job


def run_text(job: Job) -> str:
    """Return the job's ``run/scenario`` text: its job file and its DXF, as written."""
    if job.gcode is not None:  # a G-code job: its program, as written
        return yaml.safe_dump({'job': job.path.read_text(encoding='utf-8'),
                               'gcode': job.gcode.read_text(encoding='utf-8', errors='replace')})
    return yaml.safe_dump({'job': job.path.read_text(encoding='utf-8'),
                           'dxf': job.dxf.read_text(encoding='utf-8', errors='replace')})
