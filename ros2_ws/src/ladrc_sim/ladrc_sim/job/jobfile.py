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

from dataclasses import MISSING, dataclass, field, fields, replace
import math
from pathlib import Path
from typing import Any

from ladrc_contract.schema import UNKNOWN_KEY, LoadError, load, param, value_problems
from shapely.geometry import box
import yaml

from ..models.axis import check_fields
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
        try:
            return load(cls, {'dxf_units': units, 'layers': [str(x) for x in layers],
                              **{k: data[k] for k in ('join_tolerance_mm', 'open_contours')
                                 if k in data}})
        except LoadError as exc:
            raise JobError(f'{path}: {exc}') from None


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


@dataclass(frozen=True)
class SheetKeys:
    """The job file's ``sheet`` section."""

    width_mm: float = param(MISSING, 'mm', 'sheet width (x)', ge=10.0, le=10000.0)
    height_mm: float = param(MISSING, 'mm', 'sheet height (y)', ge=10.0, le=10000.0)
    surface: SurfaceParams = field(default_factory=SurfaceParams)


@dataclass(frozen=True)
class CutKeys:
    """The job file's ``cut`` section (how the drawing's contours are cut)."""

    kerf_mm: float = param(0.2, 'mm', 'kerf width (the beam cuts half of it either side)',
                           ge=0.0, le=5.0)
    lead_in_mm: float = param(3.0, 'mm', 'lead-in length from the pierce to the contour')
    micro_joint_mm: float = param(0.0, 'mm', 'micro-joint width left uncut (0: none)')
    micro_joints_per_part: int = param(0, '1', 'micro-joints per part (0: none)')


@dataclass(frozen=True, kw_only=True)
class JobFile:
    """The keys of a job file (module docstring), as the contract's loader reads them.

    The drawing keys (:class:`DrawingKeys`) are top-level keys too, read apart.
    """

    name: str = param(MISSING, '', "the job's name")
    description: str = param('', '', 'one line on what the job shows')
    dxf: str | None = param(None, '', 'the part program (DXF), relative to the job file')
    gcode: str | None = param(None, '', "the user's G-code program, instead of dxf")
    sheet: SheetKeys
    cut: CutKeys | None = None
    cnc: CncSettings | None = None
    controller: dict | None = None
    sensor: SensorParams | None = None
    tip_parts: tuple[int, ...] | None = None
    tip_rise_mm: float = 3.0
    start_xy: tuple[float, float] = param((0.0, 0.0), 'mm', 'where the nozzle starts [x, y]')
    start_height_mm: float = 10.0
    dxf_origin_mm: tuple[float, float] = param((0.0, 0.0), 'mm', "where the drawing's (0, 0) "
                                               'lies on the sheet [x, y]')
    seed: int = 1
    limits: dict | None = None
    time_budget_s: float | None = param(None, 's', "the job's time bound", ge=1.0, le=86400.0)
    expect_fault: bool = False
    contact: ContactInjection | None = None


_DRAWING = tuple(f.name for f in fields(DrawingKeys))
_TOP = (*(f.name for f in fields(JobFile)), *_DRAWING)
GCODE_TIME_BUDGET_S = 600.0
"""A G-code job's time bound when its file gives no ``time_budget_s``."""


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
    try:
        keys = load(JobFile, {k: v for k, v in data.items() if k not in _DRAWING})
    except LoadError as exc:
        if exc.kind == UNKNOWN_KEY and '.' not in exc.path:  # the drawing keys are allowed
            raise JobError(f'{path}: {exc.path}: unknown key {exc.path!r} (allowed: '
                           f'{", ".join(_TOP)})') from None
        raise JobError(f'{path}: {exc}') from None
    if (keys.dxf is None) == (keys.gcode is None):
        raise JobError(f'{path}: dxf or gcode: the program, one of them '
                       + ('(both given)' if keys.dxf is not None else '(neither given)'))
    key = 'dxf' if keys.dxf is not None else 'gcode'
    source = path.parent / (keys.dxf if keys.dxf is not None else keys.gcode)
    if not source.is_file():
        raise JobError(f'{path}: {key}: {source} does not exist')
    dxf, gcode = (source, None) if key == 'dxf' else (None, source)
    drawing = DrawingKeys.read(data, path)
    sensor = keys.sensor or SensorParams()
    cnc = keys.cnc or CncSettings()
    if cnc.small_contour_mm < 0.0:  # the default: the nozzle face (the field beyond it)
        cnc = replace(cnc, small_contour_mm=sensor.nozzle_diameter_mm)
    cut = keys.cut or CutKeys()
    return Job(path=path, name=keys.name, description=keys.description,
               dxf=dxf, width_mm=keys.sheet.width_mm, height_mm=keys.sheet.height_mm,
               surface=keys.sheet.surface, kerf_mm=cut.kerf_mm, lead_in_mm=cut.lead_in_mm,
               micro_joint_mm=cut.micro_joint_mm,
               micro_joints_per_part=cut.micro_joints_per_part,
               cnc=cnc, controller=dict(keys.controller or {}), sensor=sensor,
               tip_parts=keys.tip_parts or (), tip_rise_mm=keys.tip_rise_mm,
               start_xy=keys.start_xy, dxf_origin_mm=keys.dxf_origin_mm,
               start_height_mm=keys.start_height_mm, seed=keys.seed,
               limits=dict(keys.limits or {}), drawing=drawing, gcode=gcode,
               time_budget=keys.time_budget_s, expect_fault=keys.expect_fault,
               contact=keys.contact)


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
