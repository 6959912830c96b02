"""The CiA 402 master's cyclic core: plain Python, no ROS, testable against a fake bus.

The driver node (``node/driver_node.py``) is thin: it turns messages into the plain values of
:class:`Command`, calls :meth:`Master.cycle` once per period and turns the returned
:class:`Sample` into ``axis/feedback`` and ``axis/capacitive_height``. Everything CANopen is
here:

* **Configuration** (:func:`configure`, by SDO, may wait: not cyclic): 0x1000 must name device
  profile 402 (else one line: :class:`ConfigError`), the PDO mapping of
  :mod:`.mapping` with the RPDO deadline as RPDO1's event timer (0x1400 sub 5), 0x6060 = 9
  (cyclic synchronous velocity) checked by 0x6061, 0x1006 = the period; then NMT start.
* **One cycle** (:meth:`Master.cycle`): RPDO1 (controlword from
  :func:`.ds402.next_controlword` toward the goal, target velocity by :mod:`.units`), then
  SYNC, then the TPDOs of that SYNC are awaited (``wait_s``): statusword and position in TPDO1,
  velocity and the analog input in TPDO2.
* **Goal**: Operation enabled while a commander commands the axis (the driver's commander lock
  admitted a command) and nothing is faulted; Switch on disabled without a commander; quick
  stop on any fault. The target is non-zero only in Operation enabled, unfaulted, with the
  commander's command admitted and ``enable`` true; it is rounded toward zero
  (:meth:`.units.DriveUnits.velocity_command`), so a downward command never comes out larger.
* **Faults** (latched until :meth:`Master.request_reset`): the drive in Fault / Fault reaction
  active / Quick stop active, an EMCY (its text from :mod:`.emcy`), a TPDO missing for
  ``missing_tpdo_cycles`` cycles, a statusword of no state, a bus error or any exception in
  the cycle: the exception path sends a quick-stop controlword with a zero target and reports
  the reason; no later cycle sends a non-zero target until the reset.
* **Reset**: the fault reset (controlword bit 7, one rising edge every second cycle until the
  drive leaves Fault) and the master's latched faults cleared.

Frames come in on another thread (python-can's notifier): :meth:`Master.on_frame` stores them
under a lock and wakes the waiting cycle.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
import threading
import time
from typing import Any, Callable

from ladrc_contract.schema import Section, param

from . import ds402, emcy, mapping
from .ds402 import Goal, State

try:
    from canopen.objectdictionary import ODVariable as _ODVar
except ImportError:  # pragma: no cover
    _ODVar = object

DEVICE_TYPE = 0x1000
COMM_CYCLE = 0x1006
DEVICE_PROFILE_402 = 402
ABORT_CONNECTION, ABORT_QUICK_STOP = 0x6007, 3  # the drive's reaction to a lost master
SUPPORTED_MODES = 0x6502
SUPPORTS_PV, SUPPORTS_CSV = 1 << 2, 1 << 8  # 0x6502 bits: profile velocity, CSV
BUS_INTERFACES = ('remote', 'socketcan')


@dataclass(frozen=True)
class DriverParams(Section):
    """The driver node's parameters, declared once (``ladrc_contract.schema``)."""

    bus_interface: str = param('remote', '', "python-can interface: 'remote' (python-can-remote "
                               "over 127.0.0.1) or 'socketcan'", choices=BUS_INTERFACES,
                               runtime=False)
    bus_channel: str = param('ws://127.0.0.1:54701/', '', 'python-can channel: ws://HOST:PORT/ '
                             '(remote) or can0 (socketcan)', runtime=False)
    device: str = param('', '', "the drive's device file (YAML: node id, EDS, objects by "
                        'role, units, gap source, watchdog; docs/cia402.md)', runtime=False)
    eds: str = param('', '', "without a device file: the drive's EDS or DCF, its standard "
                     'CiA 402 objects and the analog input 0x6401:01', runtime=False)
    node_id: int = param(5, '1', "without a device file: the drive's CANopen node id",
                         ge=1, le=127, runtime=False)
    period_s: float = param(0.0005, 's', 'the SYNC period (0x1006) = the controller period h_s',
                            ge=0.0001, le=0.1, runtime=False)
    rpdo_deadline_ms: int = param(10, 'ms', "the drive's RPDO deadline (0x1400 sub 5): no "
                                  'RPDO for this long -> the drive faults and brakes', ge=1,
                                  le=65535, runtime=False)
    missing_tpdo_cycles: int = param(6, '1', 'free-running: this many cycles in a row '
                                     'without both TPDOs of their SYNC is a drive fault (6: '
                                     "3 ms at 0.5 ms, 6 ms at 1 ms, within the controller's "
                                     '10 ms stale-input limit)', ge=1, le=1000, runtime=False)
    raw_only: bool = param(False, '', 'publish the analog count as the raw value (raw_hz) and '
                           'no gap (gap_mm NaN): the controller converts it with its '
                           'calibration table (docs/calibration.md); the count is in raw_hz '
                           'either way', runtime=False)
    power_at_start: bool = param(True, '', 'power the drive (Operation enabled, zero target) '
                                 'once it is configured, as a machine powers its axes at '
                                 'machine-on; false: only while a commander commands',
                                 runtime=False)
    watchdog_timeout_s: float = param(0.005, 's', 'no velocity command for this long (counted '
                                      "in the driver's cycles) -> quick stop and drive_fault",
                                      gt=0.0, le=1.0, runtime=False)
    watchdog_recover_s: float = param(0.1, 's', 'after a watchdog stop: commands back for this '
                                      'long clear it', gt=0.0, le=60.0, runtime=False)
    lockstep: bool = param(False, '', 'lock step: publish step k (sim/lockstep), send the next '
                           'SYNC only once the command answering k arrived', runtime=False)
    lockstep_timeout_s: float = param(10.0, 's', 'lock step: wall-clock wait for a TPDO or the '
                                      "controller's answer before giving up (a dead peer)",
                                      gt=0.0, le=600.0, runtime=False)
    sdo_timeout_s: float = param(30.0, 's', 'at start: wait this long for the drive to answer '
                                 'SDO (it may still be booting)', gt=0.0, le=600.0,
                                 runtime=False)
    wait_for_controller_s: float = param(60.0, 's', 'lock step: wait this long for a '
                                         'controller in lock step before the first step',
                                         gt=0.0, le=600.0, runtime=False)
    frame_id: str = param('z_axis', '', 'header.frame_id of the samples', runtime=False)
    thread_priority: int = param(50, '1', 'SCHED_FIFO priority of the cycle thread (the CAN '
                                 'receive and middleware threads one above); 0 = the normal '
                                 'scheduler (a refusal is a warning)', ge=0, le=98,
                                 runtime=False)
    lock_memory: bool = param(True, '', 'mlockall: no page faults in the cycle',
                              runtime=False)

    def device_file(self):
        """Return the device file (its path, or the default device of ``eds``)."""
        from .device_file import default_device, load_device
        if self.device:
            return load_device(self.device)
        if not self.eds:
            raise ConfigError("no device file: give the drive's with -p device:=FILE "
                              '(docs/cia402.md)')
        return default_device(self.eds, self.node_id)

    def plan(self, od: Any = None):
        """Return the plan of the drive (:func:`.device_file.make_plan`); PlanError in one line."""
        from .device_file import make_plan
        return make_plan(self.device_file(), self.period_s, self.rpdo_deadline_ms, od)


class ConfigError(RuntimeError):
    """The drive cannot be configured as a CSV axis (one line, for the node's exit)."""


@dataclass(frozen=True)
class Command:
    """The latest command of a cycle, as plain values (the node's commander lock decided)."""

    velocity_mm_s: float = 0.0
    enable: bool = False
    admitted: bool = False  # the commander lock admitted it (False: hold zero)
    commanded: bool = False  # a commander owns the axis (goal Operation enabled)
    quick_stop: bool = False  # the driver's own guards stop the axis (watchdog, commander lock)


@dataclass(frozen=True)
class Sample:
    """What one cycle's TPDOs said, in the contract's units (``fresh`` False: none came)."""

    fresh: bool
    position_mm: float
    velocity_mm_s: float
    enabled: bool
    fault: bool
    fault_reason: str
    gap_mm: float
    gap_valid: bool
    gap_status: int
    analog_counts: int
    state: State | None
    controlword: int
    target: int


def configure(sdo: Any, nmt: Any, p: DriverParams, sleep: Callable[[float], None] = time.sleep,
              plan: Any = None, io: Any = None) -> str:
    """Configure the drive by SDO as ``plan`` says (module docstring), then NMT start.

    ``sdo`` is a canopen ``SdoClient`` (``sdo[index][sub].raw``, ``sdo[index].raw``), ``nmt``
    its node's NMT (``state = 'OPERATIONAL'``); ``io``: the I/O node's ``(sdo, nmt)`` where
    the gap is on one. ``plan``: :meth:`DriverParams.plan` (made here if None). The first read
    is retried until ``p.sdo_timeout_s`` (a drive still booting); any later refusal raises
    :class:`ConfigError` (one line). Returns one info line.
    """
    from .device_file import PlanError
    if plan is None:
        try:
            plan = p.plan()
        except PlanError as exc:
            raise ConfigError(str(exc)) from None
    n = plan.node_id
    limit = time.monotonic() + p.sdo_timeout_s
    while True:
        try:
            device_type = int(sdo[DEVICE_TYPE].raw)
            break
        except Exception as exc:  # noqa: BLE001 -- a timeout while the drive boots
            if time.monotonic() > limit:
                raise ConfigError(f'node {n}: no SDO answer for 0x1000 within '
                                  f'{p.sdo_timeout_s:g} s ({exc})') from None
            sleep(0.2)
    if device_type & 0xFFFF != DEVICE_PROFILE_402:
        raise ConfigError(f'node {n}: device type 0x{device_type:08X} is profile '
                          f'{device_type & 0xFFFF}, not a CiA 402 drive')
    w = None
    try:
        for w in plan.writes:
            _write(sdo if w.node_id == n else io[0], w.index, w.subindex, w.value)
        w = None
        if plan.watchdog == 'rpdo_event_timer':
            r1 = plan.rpdos[0]
            if int(sdo[r1.comm_index][5].raw) == 0:
                raise ConfigError(f'node {n}: 0x{r1.comm_index:04X}:05 RPDO1 event timer '
                                  'not taken (reads 0)')
        roles = plan.roles
        mode = _velocity_mode(sdo, n)
        mo, md = roles['modes_of_operation'], roles['modes_of_operation_display']
        _obj(sdo, mo).raw = mode
        shown = int(_obj(sdo, md).raw)
        if shown != mode:
            raise ConfigError(f'node {n}: 0x{md.index:04X} shows mode {shown} after '
                              f'0x{mo.index:04X} = {mode} ({ds402.MODE_NAMES[mode]})')
        if plan.has_abort_connection and plan.watchdog != 'none':
            if int(sdo[ABORT_CONNECTION].raw) != ABORT_QUICK_STOP:
                raise ConfigError(f'node {n}: 0x6007 (abort connection) not quick stop')
        cycle_us = int(round(p.period_s * 1e6))
        if plan.has_comm_cycle and int(sdo[COMM_CYCLE].raw) != cycle_us:
            raise ConfigError(f'node {n}: 0x1006 not {cycle_us} us')
    except ConfigError:
        raise
    except Exception as exc:  # noqa: BLE001 -- an SDO abort: one line
        at = (f' at node {w.node_id} 0x{w.index:04X}:{w.subindex:02X} ({w.text})'
              if w is not None else '')
        raise ConfigError(f'node {n}: configuration refused{at}: {exc}') from None
    if io is not None:
        io[1].state = 'OPERATIONAL'
    nmt.state = 'OPERATIONAL'
    name = 'CSV' if mode == ds402.MODE_CYCLIC_SYNC_VELOCITY else 'profile velocity'
    wd = {'rpdo_event_timer': f'RPDO deadline {plan.deadline_ms} ms',
          'heartbeat': f'heartbeat consumer {plan.device.heartbeat_consumer_ms} ms',
          'node_guarding': f'node guarding {plan.guard_time_ms} ms x '
                           f'{plan.device.life_time_factor}',
          'none': 'no watchdog'}[plan.watchdog]
    return (f'node {n}: CiA 402 (0x{device_type:08X}), gap {plan.gap_source}, {name}, '
            f'SYNC {cycle_us} us, {wd}, operational')


def _obj(sdo: Any, e: Any) -> Any:
    """Return the SDO variable of a role's entry (a variable or a sub of an array/record)."""
    od = getattr(sdo, 'od', None)
    if od is not None and e.index in od and isinstance(od[e.index], _ODVar):
        return sdo[e.index]
    return sdo[e.index][e.subindex]


def _write(sdo: Any, index: int, sub: int, value: int) -> None:
    """One SDO download (a variable object by its index, else index and sub)."""
    od = getattr(sdo, 'od', None)
    if od is not None and index in od and isinstance(od[index], _ODVar):
        sdo[index].raw = value
    else:
        sdo[index][sub].raw = value


def _has(sdo: Any, index: int) -> bool:
    """Whether the drive's object dictionary (its EDS) has ``index``."""
    try:
        return index in sdo.od
    except (AttributeError, TypeError):
        return False


def _velocity_mode(sdo: Any, node_id: int) -> int:
    """Cyclic synchronous velocity where the drive has it, else profile velocity (0x6502).

    0x6502 is read by SDO from the drive (an EDS often has no value for it). Without 0x6502
    in the EDS the drive is taken to have CSV (0x6060 = 9 is then checked by 0x6061). Neither
    mode: one line.
    """
    if not _has(sdo, SUPPORTED_MODES):
        return ds402.MODE_CYCLIC_SYNC_VELOCITY
    bits = int(sdo[SUPPORTED_MODES].raw)
    if bits & SUPPORTS_CSV:
        return ds402.MODE_CYCLIC_SYNC_VELOCITY
    if bits & SUPPORTS_PV:
        return ds402.MODE_PROFILE_VELOCITY
    raise ConfigError(f'node {node_id}: 0x6502 = 0x{bits:08X}: neither cyclic synchronous '
                      'velocity nor profile velocity')


class Master:
    """The cyclic master (module docstring); :meth:`cycle` once per period."""

    def __init__(self, p: DriverParams, send: Callable[[int, bytes], None],
                 plan: Any = None) -> None:
        """``send(cob_id, data)``: put one frame on the bus (raises on a bus error).

        ``plan``: the drive's plan (:meth:`DriverParams.plan`; made here if None): its PDO
        layouts, units and gap scale.
        """
        self.p = p
        self.send = send
        self.plan = plan if plan is not None else p.plan()
        self.units = self.plan.units
        self.analog = self.plan.analog
        n = self.plan.node_id
        self.node_id = n
        self.rpdos = [(pdo.cob_id(n), pdo.entries) for pdo in self.plan.rpdos]
        self.cob_rpdo = self.rpdos[0][0]
        tv = self.plan.roles['target_velocity']
        self.target_lo, self.target_hi = ((-(1 << (tv.bits - 1)), (1 << (tv.bits - 1)) - 1)
                                          if tv.signed else (0, (1 << tv.bits) - 1))
        self.tpdos = dict(zip(self.plan.tpdo_cobs(), (*[p_.entries for p_ in self.plan.tpdos],
                                                      *[p_.entries for p_ in
                                                        self.plan.io_tpdos]), strict=True))
        self.has_gap = 'gap' in self.plan.roles
        self.cob_emcy = emcy.EMCY_COB_BASE + n
        self._cv = threading.Condition()
        self._rx: dict[int, bytes] = {}
        self._emcy: list[tuple[int, int, bytes]] = []
        self.statusword = 0
        self.position = 0
        self.velocity = 0
        self.counts = self.analog.invalid
        self.state: State | None = None
        self.controlword = 0
        self.fault_reason = ''  # the master's latched fault ('' = none)
        self.emcy_reason = ''  # the last EMCY's text, latched until the reset
        self.missing = 0  # cycles in a row without every TPDO
        self.cycles = 0
        self.missed_total = 0
        self.late_total = 0  # cycles whose TPDOs came after the wait (taken by take_late)
        self._last_fresh = True
        self._last_cw_target = (0, 0)
        self.emcy_count = 0
        self._reset = False

    # ---- frames in (another thread) ---------------------------------------------------
    def on_frame(self, can_id: int, data: bytes) -> None:
        """Store a TPDO or an EMCY of our nodes (python-can's notifier thread)."""
        with self._cv:
            if can_id in self.tpdos:
                self._rx[can_id] = bytes(data)
            elif can_id == self.cob_emcy:
                self._emcy.append(emcy.unpack_emcy(bytes(data)))
            else:
                return
            self._cv.notify_all()

    @property
    def frame_ids(self) -> tuple[int, ...]:
        """The COB-IDs :meth:`on_frame` wants."""
        return (*self.tpdos, self.cob_emcy)

    def send_rpdos(self, cw: int, target: int) -> None:
        """Send every RPDO of the layout with ``cw`` and ``target`` (one frame each)."""
        values = {'controlword': cw, 'target_velocity': target}
        for cob, entries in self.rpdos:
            self.send(cob, mapping.pack(entries, tuple(values[e.name] for e in entries)))

    # ---- the operator's reset ----------------------------------------------------------
    def request_reset(self) -> None:
        """Fault reset: the drive's (bit 7 edges until it leaves Fault) and the master's."""
        with self._cv:
            self._reset = True
            self.fault_reason = ''
            self.emcy_reason = ''
            self.missing = 0

    # ---- one cycle ----------------------------------------------------------------------
    def faulted(self) -> bool:
        """Whether the master or the drive reports a fault now."""
        return bool(self.fault_reason or self.emcy_reason) or self.state in (
            State.FAULT, State.FAULT_REACTION_ACTIVE, State.QUICK_STOP_ACTIVE)

    def _goal(self, cmd: Command) -> Goal:
        if self.fault_reason or self.emcy_reason or cmd.quick_stop:
            return Goal.QUICK_STOP
        if self.state in (State.FAULT, State.FAULT_REACTION_ACTIVE):
            return Goal.QUICK_STOP
        return Goal.OPERATION_ENABLED if cmd.commanded else Goal.SWITCH_ON_DISABLED

    def _rpdo(self, cmd: Command) -> tuple[int, int]:
        state = self.state if self.state is not None else State.NOT_READY_TO_SWITCH_ON
        goal = self._goal(cmd)
        cw = ds402.next_controlword(state, goal, self._reset, self.controlword)
        target = 0
        if (goal is Goal.OPERATION_ENABLED and state is State.OPERATION_ENABLED
                and cw == ds402.CW_ENABLE_OPERATION and cmd.admitted and cmd.enable
                and math.isfinite(cmd.velocity_mm_s)):
            target = self.units.velocity_command(cmd.velocity_mm_s)
            # the object's range (toward zero: a smaller magnitude, never a larger one)
            target = max(self.target_lo, min(self.target_hi, target))
        return cw, target

    def cycle(self, cmd: Command, wait_s: float,
              abort: Callable[[], bool] | None = None) -> Sample:
        """RPDO, SYNC, the TPDOs of that SYNC (at most ``wait_s``); never raises.

        ``abort()`` true ends a long wait early (checked every 50 ms): the node is stopping.

        Any exception: a quick-stop controlword with a zero target is sent (if the bus takes
        it), the fault is latched with the exception's text, and the sample reports it.
        """
        cw, target = self.controlword, 0
        try:
            cw, target = self._rpdo(cmd)
            with self._cv:
                self._rx = {}
            self.send_rpdos(cw, target)
            self.controlword = cw
            self.send(mapping.SYNC_COB_ID, b'')
            self.cycles += 1
            fresh = self._await(wait_s, abort)
            self._last_fresh, self._last_cw_target = fresh, (cw, target)
            self._take_emcy()
            if fresh:
                self.missing = 0
                if self.state not in (State.FAULT, State.FAULT_REACTION_ACTIVE):
                    self._reset = False  # out of Fault: the reset is done
            else:
                self.missing += 1
                self.missed_total += 1
                if self.missing >= self.p.missing_tpdo_cycles and not self.fault_reason:
                    with self._cv:
                        got = set(self._rx)
                    io = self.plan.io_node_id
                    io_cobs = {p_.cob_id(io) for p_ in self.plan.io_tpdos}
                    lost = [c for c in self.tpdos if c not in got]
                    who = ('I/O node (gap)' if lost and set(lost) <= io_cobs else 'drive')
                    node = io if who != 'drive' else self.node_id
                    self.fault_reason = (f'no TPDO from node {node} for '
                                         f'{self.missing} cycles (SYNC {self.p.period_s * 1e3:g}'
                                         f' ms): bus or {who} lost')
            return self._sample(fresh, cw, target)
        except Exception as exc:  # noqa: BLE001 -- every exception path ends in a quick stop
            self._exception(exc)
            return self._sample(False, self.controlword, 0)

    def take_late(self) -> Sample | None:
        """Return the last cycle's sample if its TPDOs came after its wait (before the next SYNC).

        Free-running on a slow bus a TPDO pair may come after the cycle stopped waiting; taken
        before the next SYNC it is that cycle's sample, late (the driver publishes it with the
        SYNC's stamp), not a lost one: the missing count goes back by one.
        """
        if self._last_fresh:
            return None
        try:
            if not self._await(0.0):
                return None
        except Exception as exc:  # noqa: BLE001 -- a statusword of no state: the fault path
            self._exception(exc)
            return None
        self._last_fresh = True
        self.missing = max(0, self.missing - 1)
        self.missed_total -= 1
        self.late_total += 1
        if (self.fault_reason.startswith('no TPDO') and self.missing == 0
                and self._stale_fault_allowed):
            self.fault_reason = ''
        return self._sample(True, *self._last_cw_target)

    _stale_fault_allowed = False  # a latched "no TPDO" fault stays latched (the reset clears)

    def clear_faults_at_rest(self) -> bool:
        """Clear latched faults before the first motion, once the bus is healthy again.

        Until a commander first commands motion the axis has only been held at zero: a fault of
        the start (a TPDO late while the processes came up, the drive's RPDO deadline while the
        master was configuring) is reset as a master does at start-up, so the first motion gets
        a clean drive. From the first motion on, a fault stays latched until the operator's
        reset (:meth:`request_reset`). Returns True when a reset was started.
        """
        if not (self.fault_reason or self.emcy_reason or self.state in (
                State.FAULT, State.FAULT_REACTION_ACTIVE)):
            return False
        if self.missing or self._reset:
            return False
        self.request_reset()
        return True

    def _exception(self, exc: BaseException) -> None:
        reason = f'driver exception: {type(exc).__name__}: {exc}; quick stop'
        if not self.fault_reason:
            self.fault_reason = ' '.join(reason.split())
        try:
            self.send_rpdos(ds402.CW_QUICK_STOP, 0)
            self.controlword = ds402.CW_QUICK_STOP
        except Exception:  # noqa: BLE001, S110 -- the bus is gone: the drive's deadline stops it
            pass

    def _await(self, wait_s: float, abort: Callable[[], bool] | None = None) -> bool:
        end = time.monotonic() + wait_s
        want = len(self.tpdos)
        with self._cv:
            while len(self._rx) < want:
                left = end - time.monotonic()
                if left <= 0 or (abort is not None and abort()):
                    break
                self._cv.wait(min(left, 0.05) if abort is not None else left)
            rx = dict(self._rx)
        if len(rx) < want:
            return False
        values = {}
        for cob, entries in self.tpdos.items():
            values.update(zip((e.name for e in entries), mapping.unpack(entries, rx[cob]),
                              strict=True))
        self.statusword = values['statusword']
        self.position = values['position_actual']
        self.velocity = values['velocity_actual']
        self.counts = values.get('gap', self.analog.invalid)
        self.state = ds402.state_of(self.statusword)  # UnknownStatus -> the exception path
        return True

    def _take_emcy(self) -> None:
        with self._cv:
            frames, self._emcy = self._emcy, []
        for code, register, manufacturer in frames:
            if code == 0:  # error reset / no error: the drive's answer to the reset
                continue
            self.emcy_count += 1
            if not self.emcy_reason:
                self.emcy_reason = emcy.fault_text(code, register, manufacturer)

    def _sample(self, fresh: bool, cw: int, target: int) -> Sample:
        state = self.state
        reasons = [r for r in (self.fault_reason, self.emcy_reason) if r]
        if state in (State.FAULT, State.FAULT_REACTION_ACTIVE, State.QUICK_STOP_ACTIVE) \
                and not reasons:
            reasons.append(f'drive in {state.value} (statusword 0x{self.statusword:04X})')
        gap, valid = self.analog.mm(self.counts)
        return Sample(fresh=fresh, position_mm=self.units.position_mm(self.position),
                      velocity_mm_s=self.units.velocity_mm_s(self.velocity),
                      enabled=state is State.OPERATION_ENABLED and not reasons,
                      fault=bool(reasons), fault_reason='; '.join(reasons), gap_mm=gap,
                      gap_valid=valid, gap_status=self.analog.status(self.counts),
                      analog_counts=int(self.counts), state=state,
                      controlword=cw, target=target)
