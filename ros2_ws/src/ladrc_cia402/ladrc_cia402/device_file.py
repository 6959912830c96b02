"""The device file of a CiA 402 drive and the plan made from it and the drive's EDS, before power.

A device file (YAML, close to one node entry of ros2_canopen's ``bus.yml``) names the drive's
node id and its EDS/DCF (``dcf``, relative to the device file) and binds the objects the driver
needs by role (``objects``: controlword, statusword, modes of operation and its display, target
velocity, velocity actual, position actual, error code; ``gap``: where the capacitive reading
is). Every object's data type is read from the EDS, never assumed. It may add the vendor's own
SDO writes at boot (``sdo``: ``{index, sub_index, value}``, in order), the units (``units``),
the watchdog (``watchdog``: auto, rpdo_event_timer, heartbeat, node_guarding or none) and an
explicit PDO layout (``rpdo`` / ``tpdo``: ``{N: {transmission, mapping: [...]}}``, the drive's
side as in bus.yml); without one the layout is derived from the roles and the EDS's limits.

:func:`make_plan` checks all of it against the EDS (python-canopen reads it) and returns a
:class:`Plan`: the SDO writes in order, the PDO layouts, the watchdog, the bus load; or raises
:class:`PlanError` with ONE line naming the node, the object (its name from the EDS), what the
driver needed it for and what to write in the device file. Plain Python, no bus, no ROS.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import canopen
from canopen.objectdictionary import ODArray, ODRecord, ODVariable
from ladrc_contract.schema import LoadError, Section, load, param
import yaml

from . import mapping
from .units import AnalogScale, DriveUnits

WATCHDOGS = ('auto', 'rpdo_event_timer', 'heartbeat', 'node_guarding', 'none')
GAP_SOURCES = ('drive', 'node', 'topic')
HEARTBEAT_CONSUMER, HEARTBEAT_PRODUCER = 0x1016, 0x1017
GUARD_TIME, LIFE_TIME_FACTOR = 0x100C, 0x100D
COMM_CYCLE, ABORT_CONNECTION, ABORT_QUICK_STOP = 0x1006, 0x6007, 3
SUPPORTED_MODES = 0x6502
SUPPORTS_PV, SUPPORTS_CSV = 1 << 2, 1 << 8
_INT_TYPES = {canopen.objectdictionary.INTEGER8: (8, True),
              canopen.objectdictionary.INTEGER16: (16, True),
              canopen.objectdictionary.INTEGER32: (32, True),
              canopen.objectdictionary.UNSIGNED8: (8, False),
              canopen.objectdictionary.UNSIGNED16: (16, False),
              canopen.objectdictionary.UNSIGNED32: (32, False)}
RX_ROLES = ('controlword', 'target_velocity')  # master -> drive, every cycle
TX_ROLES = ('statusword', 'position_actual', 'velocity_actual')  # drive -> master, every SYNC
NEED = {'controlword': 'the power state machine (CiA 402 controlword)',
        'statusword': 'the drive state (CiA 402 statusword)',
        'modes_of_operation': 'the velocity mode (CSV or profile velocity)',
        'modes_of_operation_display': 'the check of the velocity mode',
        'target_velocity': 'the velocity command',
        'velocity_actual': 'the axis velocity',
        'position_actual': 'the encoder position',
        'error_code': 'the fault text',
        'gap': 'the capacitive gap reading'}


class PlanError(ValueError):
    """The device file or the EDS cannot run the axis: one line (node, object, need, fix)."""


@dataclass(frozen=True)
class Objects(Section):
    """The drive's objects by role, ``'INDEX:SUB'`` (hex); their types come from the EDS."""

    controlword: str = param('0x6040:00', '', 'controlword (RPDO)')
    statusword: str = param('0x6041:00', '', 'statusword (TPDO)')
    modes_of_operation: str = param('0x6060:00', '', 'modes of operation (SDO at start)')
    modes_of_operation_display: str = param('0x6061:00', '', 'its display (SDO at start)')
    target_velocity: str = param('0x60FF:00', '', 'target velocity (RPDO)')
    velocity_actual: str = param('0x606C:00', '', 'velocity actual value (TPDO)')
    position_actual: str = param('0x6064:00', '', 'position actual value (TPDO)')
    error_code: str = param('0x603F:00', '', 'error code (SDO, EMCY)')
    velocity_actual_signed: bool = param(False, '', 'read velocity actual as signed even where '
                                         "the EDS types it unsigned (two's complement)")


@dataclass(frozen=True)
class Units(Section):
    """The drive's integer units per mm and per mm/s."""

    increments_per_mm: float = param(1000.0, 'inc/mm', 'position actual increments per mm',
                                     gt=0.0, le=1e9)
    velocity_units_per_mm_s: float = param(1000.0, '1/(mm/s)', 'velocity units per mm/s '
                                           '(target and actual)', gt=0.0, le=1e9)


@dataclass(frozen=True)
class Gap(Section):
    """Where the capacitive reading is and how its counts read as mm."""

    source: str = param('drive', '', "'drive': an object of the drive; 'node': a CiA 401 I/O "
                        "node's TPDO on the same SYNC; 'topic': not on the bus (the sensor's "
                        'node publishes axis/capacitive_height)', choices=GAP_SOURCES)
    object: str = param('0x6401:01', '', 'the analog input, INDEX:SUB (of the drive or the '
                        'I/O node)')
    counts_per_mm: float = param(1000.0, 'counts/mm', 'counts per mm of gap', gt=0.0, le=1e6)
    offset_counts: float = param(0.0, 'counts', 'the count at gap 0', ge=-1e9, le=1e9)
    invalid_count: int = param(0x7FFF, '1', "the amplifier's out-of-range count",
                               ge=-(1 << 31), le=(1 << 32) - 1)
    contact_count: int = param(-0x8000, '1', "the amplifier's short-circuit (contact) count",
                               ge=-(1 << 31), le=(1 << 32) - 1)
    node_id: int = param(0, '1', "source 'node': the I/O node's id", ge=0, le=127)
    dcf: str = param('', '', "source 'node': the I/O node's EDS/DCF (relative to this file)")
    tpdo: int = param(1, '1', "source 'node': its TPDO that carries the input", ge=1, le=4)


@dataclass(frozen=True)
class DeviceFile(Section):
    """One drive's device file (module docstring): declared once, read by :func:`load_device`."""

    node_id: int = param(5, '1', "the drive's node id", ge=1, le=127)
    dcf: str = param('', '', "the drive's EDS/DCF, relative to the device file")
    bitrate: int = param(1000000, 'bit/s', 'the bus bitrate (for the bus load)',
                         ge=10000, le=1000000)
    master_node_id: int = param(127, '1', "the driver's own node id (its heartbeat)",
                                ge=1, le=127)
    watchdog: str = param('auto', '', 'how the drive watches its master: auto (the RPDO '
                          'event timer where the EDS has it, else heartbeat consumer, else '
                          'node guarding), or one of them, or none', choices=WATCHDOGS)
    rpdo_event_timer_ms: int = param(0, 'ms', "RPDO event timer (0: the driver's "
                                     'rpdo_deadline_ms)', ge=0, le=65535)
    heartbeat_producer_ms: int = param(20, 'ms', "the driver's heartbeat period (it is the "
                                       'producer)', ge=1, le=65535)
    heartbeat_consumer_ms: int = param(100, 'ms', "the drive's consumer time for it (0x1016)",
                                       ge=1, le=65535)
    guard_time_ms: int = param(20, 'ms', 'node guarding: guard time (0x100C)', ge=1,
                               le=65535)
    life_time_factor: int = param(5, '1', 'node guarding: life time factor (0x100D)', ge=1,
                                  le=255)
    transmission: int = param(1, '1', 'transmission type of the derived PDOs (1: every SYNC)',
                              ge=1, le=240)
    objects: Objects = field(default_factory=Objects)
    units: Units = field(default_factory=Units)
    gap: Gap = field(default_factory=Gap)
    sdo: tuple = ()  # ({'index':, 'sub_index':, 'value':}, ...) the vendor's writes at boot
    rpdo: dict = field(default_factory=dict)  # explicit layout {n: {transmission, mapping}}
    tpdo: dict = field(default_factory=dict)
    path: str = ''  # the file read (for relative paths); '' = built in code


def load_device(path: str | Path) -> DeviceFile:
    """Read and check a device file; :class:`PlanError` (one line) if it cannot be used."""
    path = Path(path)
    try:
        d = yaml.safe_load(path.read_text(encoding='utf-8'))
    except OSError as exc:
        raise PlanError(f'{path}: cannot read the device file ({exc.strerror})') from None
    except yaml.YAMLError as exc:
        raise PlanError(f'{path}: not YAML ({" ".join(str(exc).split())})') from None
    if not isinstance(d, dict):
        raise PlanError(f'{path}: a device file is a mapping (node_id, dcf, objects, ...)')
    try:
        dev = load(DeviceFile, d, skip=('path',), convert=_index_text)
    except LoadError as exc:
        raise PlanError(f'{path}: {exc}') from None
    return replace(dev, path=str(path.resolve()))


def _index_text(tp: Any, v: Any) -> Any:
    """Return an object written as a YAML number (0x6041) as its declared 'INDEX:SUB' text."""
    if tp is str and isinstance(v, int) and not isinstance(v, bool):
        return f'0x{v:04X}'
    return v


# ---- the plan ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Write:
    """One SDO download of the plan: node, index, sub, value, and why."""

    node_id: int
    index: int
    subindex: int
    value: int
    text: str


@dataclass(frozen=True)
class Plan:
    """What the driver does with one drive (module docstring); printed by :func:`plan_text`."""

    device: DeviceFile
    eds_path: str
    node_id: int
    roles: dict  # role -> mapping.Entry (name = role), the EDS's types
    rpdos: tuple  # mapping.Pdo of the drive (master -> drive)
    tpdos: tuple  # mapping.Pdo of the drive (drive -> master)
    io_node_id: int  # 0: no I/O node
    io_tpdos: tuple  # mapping.Pdo of the I/O node
    writes: tuple  # Write, in order
    watchdog: str
    watchdog_text: str
    mode_text: str
    gap_source: str
    units: DriveUnits
    analog: AnalogScale
    period_s: float
    bus_load: float  # fraction of the bitrate
    names: dict  # (index, sub) -> EDS name
    heartbeat_producer_ms: int = 0  # the driver sends heartbeats at this period (0: none)
    guard_time_ms: int = 0  # the driver guards the drive at this period (0: none)
    deadline_ms: int = 0  # the RPDO event timer written (watchdog rpdo_event_timer)
    has_abort_connection: bool = False
    has_comm_cycle: bool = False
    io_od: Any = None

    def tpdo_cobs(self) -> tuple[int, ...]:
        """Return the COB-IDs of every TPDO a cycle waits for (the drive's and the I/O node's)."""
        return tuple(p.cob_id(self.node_id) for p in self.tpdos) + tuple(
            p.cob_id(self.io_node_id) for p in self.io_tpdos)


def parse_object(text: str) -> tuple[int, int]:
    """``'0x6064:01'`` -> (0x6064, 1); ValueError for another form."""
    s = str(text).replace(' ', '')
    index, _, sub = s.partition(':')
    return int(index, 16), int(sub or '0', 16)


def _where(index: int, sub: int) -> str:
    return f'0x{index:04X}:{sub:02X}'


def _resolve_path(dev: DeviceFile, rel: str) -> Path:
    p = Path(rel)
    if not p.is_absolute() and dev.path:
        p = Path(dev.path).parent / p
    return p


def read_od(path: Path, node_id: int, who: str) -> Any:
    """Read an EDS/DCF with python-canopen; PlanError (one line) if it cannot be read."""
    if not path.is_file():
        raise PlanError(f'{who}: {path}: no such EDS/DCF file; write dcf: the EDS path '
                        'relative to the device file')
    try:
        return canopen.import_od(str(path), node_id)
    except Exception as exc:  # noqa: BLE001 -- a malformed file: one line
        raise PlanError(f'{who}: {path}: not a readable EDS/DCF ({exc})') from None


def _var(od: Any, index: int, sub: int) -> Any:
    if index not in od:
        return None
    obj = od[index]
    if isinstance(obj, ODVariable):
        return obj if sub == 0 else None
    return obj[sub] if sub in obj else None


def _name(od: Any, index: int, sub: int) -> str:
    v = _var(od, index, sub)
    if v is None:
        return od[index].name if index in od else ''
    if isinstance(od[index], ODVariable):
        return v.name
    parent = od[index].name
    if not v.name or v.name in parent:
        return parent
    return v.name if v.name.startswith(parent) else f'{parent} {v.name}'


def _role_entry(od: Any, node: str, role: str, text: str, rx: bool, mapped: bool,
                signed_override: bool = False) -> mapping.Entry:
    key = 'gap.object' if role == 'gap' else f'objects.{role}'
    try:
        index, sub = parse_object(text)
    except ValueError:
        raise PlanError(f"{node}: {key} = {text!r}: write it as 'INDEX:SUB' in hex "
                        "('0x606C:00')") from None
    need = NEED[role]
    if index not in od:
        raise PlanError(f"{node}: {_where(index, sub)} ({role}): not in the EDS ({need}); "
                        f"write {key}: 'INDEX:SUB' of the drive's object for it")
    obj = od[index]
    if role == 'target_velocity' and isinstance(obj, (ODArray, ODRecord)):
        raise PlanError(f'{node}: 0x{index:04X} {obj.name}: an ARRAY in the EDS (one '
                        f'sub-index per motor); {need} is a single value on a single-axis '
                        'drive: this driver commands single-axis CiA 402 drives only')
    var = _var(od, index, sub)
    if var is None:
        subs = '' if isinstance(obj, ODVariable) else ', '.join(
            f'{s:02X}' for s in obj.subindices if s)
        raise PlanError(f"{node}: {_where(index, sub)} {obj.name}: no such sub-index in the "
                        f"EDS ({need}); write {key}: '0x{index:04X}:SUB'"
                        + (f' with SUB one of {subs}' if subs else ' with SUB 00'))
    if var.data_type not in _INT_TYPES:
        raise PlanError(f'{node}: {_where(index, sub)} {_name(od, index, sub)}: data type '
                        f'0x{var.data_type:04X} in the EDS, not an integer of 8, 16 or 32 bits '
                        f"({need}); write {key}: the drive's integer object for it")
    bits, signed = _INT_TYPES[var.data_type]
    if role == 'target_velocity' and not signed:
        raise PlanError(f'{node}: {_where(index, sub)} {_name(od, index, sub)}: '
                        f'UNSIGNED{bits} in the EDS ({need} runs both ways); write '
                        "objects.target_velocity: the drive's signed velocity target")
    if role == 'velocity_actual' and not signed:
        if not signed_override:
            raise PlanError(f'{node}: {_where(index, sub)} {_name(od, index, sub)}: '
                            f'UNSIGNED{bits} in the EDS ({need} has a sign); write '
                            "objects.velocity_actual_signed: true if the drive sends two's "
                            'complement, else bind another object')
        signed = True
    if mapped and not var.pdo_mappable:
        raise PlanError(f'{node}: {_where(index, sub)} {_name(od, index, sub)}: not '
                        f'PDO-mappable in the EDS ({need}, every cycle); write {key}: a '
                        'mappable object')
    if rx and not var.writable:
        raise PlanError(f'{node}: {_where(index, sub)} {_name(od, index, sub)}: access '
                        f'{var.access_type} in the EDS, not writable ({need})')
    return mapping.Entry(index, sub, bits, signed, role)


def _pdo_slots(od: Any, kind: str) -> list[tuple[int, int]]:
    """Return ``(number, entries capacity)`` of each PDO the EDS has (comm and map objects)."""
    comm, mp = (mapping.RPDO_COMM, mapping.RPDO_MAP) if kind == 'rpdo' else (
        mapping.TPDO_COMM, mapping.TPDO_MAP)
    out = []
    for k in range(4):
        if comm + k in od and mp + k in od and not isinstance(od[mp + k], ODVariable):
            cap = len([s for s in od[mp + k].subindices if s])
            if cap and 1 in od[comm + k] and 2 in od[comm + k]:
                out.append((k + 1, min(cap, 8)))
    return out


def _derive(node: str, kind: str, entries: list, slots: list[tuple[int, int]],
            tt: int) -> list[mapping.Pdo]:
    """First fit of ``entries`` (in role order) into the EDS's PDOs: 8 bytes, its capacity."""
    base = 0x200 if kind == 'rpdo' else 0x180
    out: list[tuple[int, int, list]] = []
    free = list(slots)
    for e in entries:
        for item in out:
            n, cap, have = item
            if len(have) < cap and sum(x.bits for x in have) + e.bits <= 64:
                have.append(e)
                break
        else:
            if not free:
                used = ', '.join(f'{kind.upper()}{n}' for n, _c, _h in out) or 'none'
                comm = (mapping.RPDO_COMM if kind == 'rpdo' else mapping.TPDO_COMM)
                raise PlanError(f'{node}: {_where(comm, 1)} {kind.upper()}s: the EDS has no '
                                f'{kind.upper()} left for {_where(e.index, e.subindex)} '
                                f'({e.name}; used: {used}); write {kind}: an explicit layout '
                                'or bind smaller objects')
            n, cap = free.pop(0)
            out.append((n, cap, [e]))
    return [mapping.Pdo(kind, n, base + 0x100 * (n - 1), tt, tuple(have))
            for n, _cap, have in out]


def _explicit(node: str, kind: str, spec: dict, od: Any, by_obj: dict, slots: list,
              tt_default: int) -> list[mapping.Pdo]:
    base = 0x200 if kind == 'rpdo' else 0x180
    have = dict(slots)
    out = []
    for n, p in spec.items():
        if not isinstance(n, int) or n not in have:
            raise PlanError(f'{node}: {kind} {n}: the EDS has {kind.upper()}s '
                            f'{", ".join(str(s) for s in have) or "none"}; write {kind}: '
                            'one of them')
        p = p or {}
        entries = []
        for m in p.get('mapping', []):
            try:
                key = (int(m['index']), int(m.get('sub_index', 0))) if isinstance(m, dict) \
                    else parse_object(m)
            except (KeyError, TypeError, ValueError):
                raise PlanError(f'{node}: {kind} {n} mapping {m!r}: write '
                                "{index: 0x6040, sub_index: 0} or '0x6040:00'") from None
            if key not in by_obj:
                raise PlanError(f'{node}: {kind} {n} maps {_where(*key)} '
                                f'{_name(od, *key)}: not an object of a role the driver '
                                "exchanges by PDO; map only the roles' objects")
            entries.append(by_obj[key])
        if len(entries) > have[n]:
            raise PlanError(f'{node}: {kind.upper()}{n}: {len(entries)} entries, the EDS '
                            f'allows {have[n]}')
        try:
            out.append(mapping.Pdo(kind, n, base + 0x100 * (n - 1),
                                   int(p.get('transmission', tt_default)), tuple(entries)))
        except ValueError as exc:
            raise PlanError(f'{node}: {exc}') from None
    return out


def _frame_bits(n: int) -> int:
    """Worst-case bits of a CAN 2.0A frame of ``n`` data bytes (stuffing, 3 bits space)."""
    return 47 + 8 * n + (34 + 8 * n - 1) // 4


def _pdo_writes(node_id: int, pdo: mapping.Pdo, od: Any, event_timer_ms: int | None,
                prefix: str) -> list[Write]:
    c, m = pdo.comm_index, pdo.map_index
    cob = pdo.cob_id(node_id)
    name = f'{prefix}{pdo.kind.upper()}{pdo.number}'
    w = [Write(node_id, c, 1, cob | mapping.COB_ID_INVALID, f'{name} COB-ID: disabled'),
         Write(node_id, m, 0, 0, f'{name} mapping: cleared')]
    w += [Write(node_id, m, i, e.word, f'{name} entry {i}: {_where(e.index, e.subindex)} '
                f'{e.name} ({"INTEGER" if e.signed else "UNSIGNED"}{e.bits})')
          for i, e in enumerate(pdo.entries, start=1)]
    w += [Write(node_id, m, 0, len(pdo.entries), f'{name} mapping: {len(pdo.entries)} entries'),
          Write(node_id, c, 2, pdo.transmission_type,
                f'{name} transmission type {pdo.transmission_type}')]
    if event_timer_ms is not None and 5 in od[c]:
        w.append(Write(node_id, c, 5, event_timer_ms,
                       f'{name} event timer {event_timer_ms} ms'
                       + (' (the watchdog)' if event_timer_ms else '')))
    w.append(Write(node_id, c, 1, cob, f'{name} COB-ID 0x{cob:03X}: enabled'))
    return w


def make_plan(dev: DeviceFile, period_s: float = 0.0005, rpdo_deadline_ms: int = 10,
              od: Any = None) -> Plan:
    """Check ``dev`` against its EDS and return the plan; :class:`PlanError` (one line) if not.

    ``period_s``: the SYNC period (0x1006 where the drive has it, the bus load);
    ``rpdo_deadline_ms``: the RPDO event timer when the file leaves it 0; ``od``: the drive's
    object dictionary if already read (else read from ``dev.dcf``).
    """
    n = dev.node_id
    node = f'node {n}'
    if not dev.dcf and od is None:
        raise PlanError(f"{node}: no EDS: write dcf: the drive's EDS/DCF path (relative to "
                        'the device file)')
    eds_path = _resolve_path(dev, dev.dcf) if dev.dcf else Path('')
    if od is None:
        od = read_od(eds_path, n, node)
    o = dev.objects
    roles: dict[str, mapping.Entry] = {}
    for role in ('controlword', 'target_velocity'):
        roles[role] = _role_entry(od, node, role, getattr(o, role), rx=True, mapped=True)
    for role in TX_ROLES:
        roles[role] = _role_entry(od, node, role, getattr(o, role), rx=False, mapped=True,
                                  signed_override=o.velocity_actual_signed)
    sdo_roles = {}
    for role in ('modes_of_operation', 'modes_of_operation_display', 'error_code'):
        sdo_roles[role] = _role_entry(od, node, role, getattr(o, role),
                                      rx=role == 'modes_of_operation', mapped=False)
    g = dev.gap
    io_id, io_od, io_tpdos = 0, None, ()
    tx = [roles[r] for r in TX_ROLES]
    if g.source == 'drive':
        roles['gap'] = _role_entry(od, node, 'gap', g.object, rx=False, mapped=True)
        tx.append(roles['gap'])
    elif g.source == 'node':
        if not g.node_id or g.node_id == n:
            raise PlanError(f"{node}: gap.source 'node': write gap.node_id: the I/O node's id "
                            "(not the drive's)")
        io_id = g.node_id
        io = f'node {io_id}'
        if not g.dcf:
            raise PlanError(f"{io}: gap.source 'node': write gap.dcf: the I/O node's EDS")
        io_od = read_od(_resolve_path(dev, g.dcf), io_id, io)
        e = _role_entry(io_od, io, 'gap', g.object, rx=False, mapped=True)
        roles['gap'] = e
        slots = dict(_pdo_slots(io_od, 'tpdo'))
        if g.tpdo not in slots:
            raise PlanError(f'{io}: {_where(mapping.TPDO_COMM + g.tpdo - 1, 1)} TPDO{g.tpdo}: '
                            f'not in the EDS (the gap on the SYNC); write gap.tpdo: one of '
                            f'{", ".join(map(str, slots)) or "none"}')
        io_tpdos = (mapping.Pdo('tpdo', g.tpdo, 0x180 + 0x100 * (g.tpdo - 1),
                                dev.transmission, (e,)),)
    by_obj = {(e.index, e.subindex): e for r, e in roles.items()
              if not (r == 'gap' and g.source != 'drive')}
    rslots, tslots = _pdo_slots(od, 'rpdo'), _pdo_slots(od, 'tpdo')
    if dev.rpdo:
        rpdos = _explicit(node, 'rpdo', dev.rpdo, od, by_obj, rslots, dev.transmission)
    else:
        rpdos = _derive(node, 'rpdo', [roles[r] for r in RX_ROLES], rslots, dev.transmission)
    if dev.tpdo:
        tpdos = _explicit(node, 'tpdo', dev.tpdo, od, by_obj, tslots, dev.transmission)
    else:
        tpdos = _derive(node, 'tpdo', tx, tslots, dev.transmission)
    for role, e in roles.items():
        if role == 'gap' and g.source != 'drive':
            continue
        if not any(e in p.entries for p in (*rpdos, *tpdos)):
            raise PlanError(f'{node}: {_where(e.index, e.subindex)} ({role}): in no PDO of '
                            f'the layout ({NEED[role]}, every cycle); add it to '
                            f'{"rpdo" if role in RX_ROLES else "tpdo"}')
    # the watchdog
    has_timer = bool(rpdos) and 5 in od[rpdos[0].comm_index]
    has_hb = HEARTBEAT_CONSUMER in od and 1 in od[HEARTBEAT_CONSUMER] \
        if HEARTBEAT_CONSUMER in od and not isinstance(od[HEARTBEAT_CONSUMER], ODVariable) \
        else False
    has_guard = GUARD_TIME in od and LIFE_TIME_FACTOR in od
    kind = dev.watchdog
    r1 = rpdos[0] if rpdos else None
    timer_where = _where(r1.comm_index if r1 else mapping.RPDO_COMM, 5)
    if kind == 'auto':
        kind = ('rpdo_event_timer' if has_timer else 'heartbeat' if has_hb
                else 'node_guarding' if has_guard else '')
        if not kind:
            raise PlanError(f'{node}: {timer_where} RPDO1 event timer, 0x1016 consumer '
                            'heartbeat time, 0x100C guard time: none in the EDS (the drive '
                            'must stop when the driver is lost); write watchdog: none only '
                            'if the machine stops the drive otherwise')
    missing = {'rpdo_event_timer': (not has_timer, timer_where, 'RPDO1 event timer'),
               'heartbeat': (not has_hb, _where(HEARTBEAT_CONSUMER, 1),
                             'Consumer heartbeat time'),
               'node_guarding': (not has_guard, _where(GUARD_TIME, 0), 'Guard time')}
    if kind in missing and missing[kind][0]:
        _m, where, what = missing[kind]
        alt = [k for k, v in missing.items() if not v[0]]
        raise PlanError(f'{node}: {where} {what}: not in the EDS (watchdog: {kind}); write '
                        f'watchdog: {alt[0] if alt else "none"}'
                        + ('' if alt else ' (the EDS offers no watchdog)'))
    deadline = dev.rpdo_event_timer_ms or rpdo_deadline_ms
    writes: list[Write] = []
    for i, s in enumerate(dev.sdo):
        try:
            index, sub, value = int(s['index']), int(s.get('sub_index', 0)), int(s['value'])
        except (KeyError, TypeError, ValueError, AttributeError):
            raise PlanError(f'{node}: sdo[{i}] = {s!r}: write {{index: 0x6083, sub_index: 0, '
                            'value: 1000}') from None
        var = _var(od, index, sub)
        if var is None:
            raise PlanError(f'{node}: sdo[{i}] {_where(index, sub)}: not in the EDS; remove it '
                            'or correct the index')
        if not var.writable:
            raise PlanError(f'{node}: sdo[{i}] {_where(index, sub)} {_name(od, index, sub)}: '
                            f'access {var.access_type}, not writable')
        writes.append(Write(n, index, sub, value, f'{_name(od, index, sub)} (device file)'))
    used = {(p.kind, p.number) for p in (*rpdos, *tpdos)}
    for kind_, slots in (('rpdo', rslots), ('tpdo', tslots)):
        base = mapping.RPDO_COMM if kind_ == 'rpdo' else mapping.TPDO_COMM
        cob0 = 0x200 if kind_ == 'rpdo' else 0x180
        for num, _cap in slots:
            if (kind_, num) not in used:
                writes.append(Write(n, base + num - 1, 1,
                                    (cob0 + 0x100 * (num - 1) + n) | mapping.COB_ID_INVALID,
                                    f'{kind_.upper()}{num} COB-ID: disabled (unused)'))
    for p in rpdos:
        writes += _pdo_writes(n, p, od, deadline if kind == 'rpdo_event_timer' and p is r1
                              else (0 if 5 in od[p.comm_index] else None), '')
    for p in tpdos:
        writes += _pdo_writes(n, p, od, 0 if 5 in od[p.comm_index] else None, '')
    hb_ms = guard_ms = 0
    if kind == 'rpdo_event_timer':
        text = f'RPDO1 event timer {deadline} ms ({timer_where})'
    elif kind == 'heartbeat':
        hb_ms = dev.heartbeat_producer_ms
        if dev.heartbeat_consumer_ms <= hb_ms:
            raise PlanError(f'{node}: 0x1016:01 Consumer heartbeat time: '
                            f"{dev.heartbeat_consumer_ms} ms is not above the driver's "
                            f'heartbeat period {hb_ms} ms; write heartbeat_consumer_ms: at '
                            f'least {2 * hb_ms}')
        value = dev.master_node_id << 16 | dev.heartbeat_consumer_ms
        writes.append(Write(n, HEARTBEAT_CONSUMER, 1, value,
                            f'{_name(od, HEARTBEAT_CONSUMER, 1)}: node {dev.master_node_id}, '
                            f'{dev.heartbeat_consumer_ms} ms'))
        text = (f'heartbeat consumer 0x1016:01: the driver (node {dev.master_node_id}) '
                f'produces every {hb_ms} ms, the drive stops after {dev.heartbeat_consumer_ms}'
                ' ms without one')
    elif kind == 'node_guarding':
        guard_ms = dev.guard_time_ms
        writes.append(Write(n, GUARD_TIME, 0, guard_ms, f'{_name(od, GUARD_TIME, 0)}'))
        writes.append(Write(n, LIFE_TIME_FACTOR, 0, dev.life_time_factor,
                            f'{_name(od, LIFE_TIME_FACTOR, 0)}'))
        text = (f'node guarding 0x100C/0x100D: the driver guards every {guard_ms} ms, the '
                f'drive stops after {guard_ms * dev.life_time_factor} ms without a guard')
    else:
        text = 'none (watchdog: none in the device file: the machine stops the drive otherwise)'
    has_abort = ABORT_CONNECTION in od
    if has_abort and kind != 'none':
        writes.append(Write(n, ABORT_CONNECTION, 0, ABORT_QUICK_STOP,
                            f'{_name(od, ABORT_CONNECTION, 0)}: quick stop'))
        text += '; on loss: quick stop (0x6007 = 3)'
    has_cycle = COMM_CYCLE in od
    cycle_us = int(round(period_s * 1e6))
    if has_cycle:
        writes.append(Write(n, COMM_CYCLE, 0, cycle_us, f'{_name(od, COMM_CYCLE, 0)} '
                            f'{cycle_us} us'))
    for p in io_tpdos:
        io_slots = _pdo_slots(io_od, 'tpdo')
        for num, _cap in io_slots:
            if num != p.number:
                writes.append(Write(io_id, mapping.TPDO_COMM + num - 1, 1,
                                    (0x180 + 0x100 * (num - 1) + io_id)
                                    | mapping.COB_ID_INVALID,
                                    f'TPDO{num} COB-ID: disabled (unused)'))
        writes += _pdo_writes(io_id, p, io_od, 0 if 5 in io_od[p.comm_index] else None,
                              f'node {io_id} ')
    # the velocity mode: 0x6502 is read by SDO from the drive (never trusted from the EDS)
    mode_text = ('0x6060 = 9 (CSV) where 0x6502 read from the drive has bit 8, else 3 '
                 '(profile velocity, bit 2); 0x6061 checked')
    if SUPPORTED_MODES in od:
        dflt = od[SUPPORTED_MODES].default if isinstance(od[SUPPORTED_MODES], ODVariable) \
            else None
        if isinstance(dflt, int) and dflt and not dflt & (SUPPORTS_CSV | SUPPORTS_PV):
            raise PlanError(f'{node}: 0x6502:00 {od[SUPPORTED_MODES].name} = 0x{dflt:08X} in '
                            'the EDS: neither cyclic synchronous velocity nor profile velocity '
                            '(the velocity command); this driver needs one of them')
        if isinstance(dflt, int) and dflt and not dflt & SUPPORTS_CSV:
            mode_text = '0x6060 = 3 (profile velocity: no CSV in 0x6502); 0x6061 checked'
    else:
        mode_text = '0x6060 = 9 (CSV; no 0x6502 in the EDS), checked by 0x6061'
    # bus load
    frames = [0] + [mapping.size(p.entries) for p in (*rpdos, *tpdos, *io_tpdos)]
    bits = sum(_frame_bits(b) for b in frames) / period_s
    if hb_ms:
        bits += _frame_bits(1) / (hb_ms * 1e-3)
    if guard_ms:
        bits += (_frame_bits(0) + _frame_bits(1)) / (guard_ms * 1e-3)
    load = bits / dev.bitrate
    if load > 1.0:
        raise PlanError(f'{node}: bus load {load * 100:.0f} % at SYNC {period_s * 1e3:g} ms and '
                        f'{dev.bitrate / 1e3:g} kbit/s (the cyclic PDOs); write bitrate: the '
                        "bus's, or run a longer period")
    u = dev.units
    units = DriveUnits(u.increments_per_mm, u.velocity_units_per_mm_s)
    gap_e = roles.get('gap')
    lo, hi = _range(gap_e) if gap_e is not None else (-(1 << 31), (1 << 31) - 1)
    for name, c in (('invalid_count', g.invalid_count), ('contact_count', g.contact_count)):
        if gap_e is not None and not lo <= c <= hi:
            raise PlanError(f'{node}: gap.{name} = {c}: outside the range {lo}..{hi} of '
                            f'{_where(gap_e.index, gap_e.subindex)} '
                            f'({"INTEGER" if gap_e.signed else "UNSIGNED"}{gap_e.bits})')
    analog = AnalogScale(g.counts_per_mm, g.invalid_count, g.contact_count,
                         offset=g.offset_counts, lo=lo, hi=hi)
    names = {}
    for e in roles.values():
        names[(e.index, e.subindex)] = _name(io_od if (e.name == 'gap' and io_id) else od,
                                             e.index, e.subindex)
    return Plan(device=dev, eds_path=str(eds_path), node_id=n,
                roles={**roles, **sdo_roles}, rpdos=tuple(rpdos), tpdos=tuple(tpdos),
                io_node_id=io_id, io_tpdos=tuple(io_tpdos), writes=tuple(writes),
                watchdog=kind, watchdog_text=text, mode_text=mode_text,
                gap_source=g.source, units=units, analog=analog, period_s=period_s,
                bus_load=load, names=names, heartbeat_producer_ms=hb_ms,
                guard_time_ms=guard_ms, has_abort_connection=has_abort,
                deadline_ms=deadline if kind == 'rpdo_event_timer' else 0,
                has_comm_cycle=has_cycle, io_od=io_od)


def _range(e: mapping.Entry) -> tuple[int, int]:
    if e.signed:
        return -(1 << (e.bits - 1)), (1 << (e.bits - 1)) - 1
    return 0, (1 << e.bits) - 1


def entry_range(e: mapping.Entry) -> tuple[int, int]:
    """Return the integer range of a mapped object's data type."""
    return _range(e)


def plan_text(plan: Plan) -> str:
    """Return the plan as lines: SDO writes in order, PDO layouts, watchdog, mode, bus load."""
    dev = plan.device
    lines = [f'device {dev.path or "(built in)"}: node {plan.node_id}, EDS {plan.eds_path}']
    lines.append(f'gap: {plan.gap_source}'
                 + (f' {_where(plan.roles["gap"].index, plan.roles["gap"].subindex)} '
                    f'{plan.names.get((plan.roles["gap"].index, plan.roles["gap"].subindex), "")}'
                    if 'gap' in plan.roles else ' (axis/capacitive_height from its own node)')
                 + (f' of node {plan.io_node_id} (TPDO on the same SYNC)' if plan.io_node_id
                    else ''))
    lines.append(f'watchdog: {plan.watchdog}: {plan.watchdog_text}')
    lines.append(f'mode: {plan.mode_text}')
    for p in (*plan.rpdos, *plan.tpdos):
        lines.append(_pdo_line(p, plan.node_id))
    for p in plan.io_tpdos:
        lines.append(f'node {plan.io_node_id} ' + _pdo_line(p, plan.io_node_id))
    lines.append(f'SDO writes ({len(plan.writes)}, in order):')
    for w in plan.writes:
        lines.append(f'  node {w.node_id} {_where(w.index, w.subindex)} = 0x{w.value:X}  '
                     f'{w.text}')
    lines.append(f'then: 0x6502 read, {plan.mode_text.split(";")[0]}; NMT start'
                 + (f' node {plan.io_node_id},' if plan.io_node_id else '')
                 + f' node {plan.node_id}'
                 + (f'; the driver sends its heartbeat every {plan.heartbeat_producer_ms} ms'
                    if plan.heartbeat_producer_ms else '')
                 + (f'; the driver guards the drive every {plan.guard_time_ms} ms'
                    if plan.guard_time_ms else ''))
    lines.append(f'bus load: {plan.bus_load * 100:.1f} % at SYNC {plan.period_s * 1e3:g} ms, '
                 f'{dev.bitrate / 1e3:g} kbit/s (worst-case stuffing)')
    return '\n'.join(lines)


def _pdo_line(p: mapping.Pdo, node_id: int) -> str:
    ents = ', '.join(f'{_where(e.index, e.subindex)} {e.name} '
                     f'{"i" if e.signed else "u"}{e.bits}' for e in p.entries)
    return (f'{p.kind.upper()}{p.number} COB-ID 0x{p.cob_id(node_id):03X} transmission '
            f'{p.transmission_type}: {ents} ({mapping.size(p.entries)} bytes)')


def default_device(eds: str, node_id: int = 5) -> DeviceFile:
    """Return the device of a drive given only by its EDS (standard CiA 402/401 objects)."""
    return DeviceFile(node_id=node_id, dcf=str(Path(eds).resolve()))


