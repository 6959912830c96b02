"""Bring-up without ros2cli: the sim node, the follow node and the recorder as processes.

``bringup --scenario showcase --params config/follow.yaml --bag out/run1`` (or ``--job NAME``:
a cutting job, the sim node playing the simulated CNC; with ``--separate-cnc`` the CNC node
plays it) starts each node as a separate process
on an isolated DDS domain (its own ``ROS_DOMAIN_ID``, localhost discovery), waits until the
simulator has played its scenario (or Ctrl-C), then stops them in the safe
order: the controller first (it commands zero velocity), then the simulator, then the recorder
(so the bag holds the stop). ``launch/bringup.launch.py`` starts the same nodes with the same
arguments from :func:`node_specs` on a stock Jazzy install.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
import json
import os
from pathlib import Path
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from typing import Any, Mapping

from ladrc_contract.node_entry import take_stop_signals
from ladrc_contract.run_log import verdict


@dataclass
class NodeSpec:
    """One node of the bring-up: package, executable and its ``--ros-args``."""

    package: str
    executable: str
    name: str
    ros_args: list[str] = field(default_factory=list)
    parameters: dict[str, object] = field(default_factory=dict)
    params_file: str | None = None


def default_params_file() -> str:
    """Return the shipped controller parameter file (install space, else the source tree)."""
    try:
        from ament_index_python.packages import get_package_share_directory

        path = Path(get_package_share_directory('ladrc_bringup')) / 'config' / 'follow.yaml'
        if path.is_file():
            return str(path)
    except (ImportError, LookupError, ValueError):
        pass
    # <root>/ros2_ws/src/ladrc_bringup/ladrc_bringup/bringup.py -> ros2_ws/src/ladrc_bringup
    return str(Path(__file__).resolve().parents[1] / 'config' / 'follow.yaml')


LIVE_LOOPS = ('deadline', 'sync')
"""The follow node's loops against a drive (``lockstep`` is the sim node's alone)."""


def node_specs(scenario: str, params_file: str | None = None, bag: str | None = None,
               loop: str = 'deadline', storage: str = 'mcap', lockstep: bool = False,
               paced: bool = True, job: str | None = None,
               separate_cnc: bool = False, drive: str = '', bus: str = '',
               node_id: int = 5, period_s: float = 0.0005, device: str = ''
               ) -> list[NodeSpec]:
    """Return the nodes of a simulated run: the one configuration bringup and launch share.

    ``lockstep``: the sim node and the follow node in lock step (docs/follow-node.md), the
    recorder reliable; ``paced``: lock step no faster than real time (else as fast as the
    two processes go); ``job``: the sim node plays this cutting job instead of ``scenario``;
    ``separate_cnc``: the job's CNC is the CNC node (docs/job-world.md, "A separate CNC");
    ``drive='cia402'``: the drive is the emulated CiA 402 drive on the CAN bus ``bus`` (the sim
    node's, ``-p drive:=cia402``), mastered by the CiA 402 driver node (docs/real-axis.md), its
    SYNC period ``period_s`` the controller's and the simulated world's period too.
    """
    if drive not in ('', 'cia402'):
        raise ValueError(f"drive {drive!r}: '' (the sim node's own) or 'cia402'")
    specs = []
    if bag:
        rec: dict[str, object] = {'output': bag, 'storage': storage,
                                  'scenario': job or scenario,
                                  'machine_id': LAUNCH_ARGUMENTS['hardware_id'][0]}
        if lockstep:
            rec['reliable'] = True
        specs.append(NodeSpec('ladrc_bags', 'recorder', 'ladrc_recorder', parameters=rec))
    # The product's defaults (stale input 10 ms, drive watchdog 5 ms) in simulated runs too:
    # robustness against a loaded machine comes from the loop's real-time settings
    # (SCHED_FIFO, locked memory: ladrc_contract/realtime.py), not from wider timeouts.
    # No CPU pinning: on this 2-core class, pinning the two loops to a CPU each starved the
    # simulator's publishing under load (docs/safety.md).
    follow: dict[str, object] = {'loop': 'lockstep' if lockstep else loop}
    if drive == 'cia402' and abs(period_s - 0.0005) > 1e-12:
        follow['h_s'] = period_s  # the controller's period is the SYNC period
    specs.append(NodeSpec('ladrc_follow', 'follow_node', 'ladrc_follow', parameters=follow,
                          params_file=params_file or default_params_file()))
    sim: dict[str, object] = {'exit_at_end': True, **({'job': job} if job else
                                                      {'scenario': scenario})}
    if lockstep:
        sim.update({'lockstep': True, 'realtime': bool(paced)})
    if bag:  # the bag holds the run from its first tick
        sim.update({'wait_for_recorder_s': 10.0, 'start_delay_s': 1.0})
    if job and separate_cnc:
        sim['separate_cnc'] = True
    if drive == 'cia402':
        # the drive's device file (``device``; default the shipped drive's): both load it
        device = device or emulated_drive_device()
        sim.update({'drive': 'cia402', 'can_bus': bus, 'can_device': device, 'h_s': period_s})
        driver: dict[str, object] = {'device': device, 'bus_interface': bus_interface(bus),
                                     'bus_channel': bus,
                                     'lockstep': bool(lockstep), 'period_s': period_s}
        specs.append(NodeSpec('ladrc_cia402', 'driver_node', 'ladrc_driver',
                              parameters=driver))
    specs.append(NodeSpec('ladrc_sim', 'sim_node', 'ladrc_sim', parameters=sim))
    if job and separate_cnc:
        specs.append(NodeSpec('ladrc_sim', 'cnc_node', 'ladrc_cnc',
                              parameters={'job': job, 'lockstep': bool(lockstep)}))
    return specs


def emulated_drive_device() -> str:
    """Return the device file of the emulated CiA 402 drive (ladrc_sim), its EDS beside it."""
    from ladrc_sim import default_device

    return str(default_device())


def bus_interface(bus: str) -> str:
    """python-can interface of a bus: ``ws://…`` is python-can-remote, else socketcan."""
    return 'remote' if bus.startswith(('ws://', 'wss://')) else 'socketcan'


VIEW_PORT = 8765
"""The live view's default WebSocket port (docs/live-view.md)."""


def view_spec(port: int = VIEW_PORT) -> NodeSpec:
    """Return the live view node (Foxglove WebSocket on 127.0.0.1:``port``; docs/live-view.md).

    Read-only beside any node set, at the normal scheduler; its operator calls go through the
    follow node's own services and checks.
    """
    return NodeSpec('ladrc_tools', 'view_node', 'ladrc_view', parameters={'port': int(port)})


def port_in_use(port: int, host: str = '127.0.0.1') -> str | None:
    """Return why ``host:port`` cannot be listened on (one line), or None when it is free."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the view's server binds
        try:
            s.bind((host, port))
        except OSError as exc:
            return f'{host}:{port}: {exc.strerror or exc}'
    return None


def axis_node_specs(params_file: str | None = None, bag: str | None = None,
                    loop: str = 'deadline', storage: str = 'mcap',
                    hardware_id: str = 'z_axis', cia402_eds: str = '', can: str = 'can0',
                    node_id: int = 5, cia402_device: str = '') -> list[NodeSpec]:
    """Return the nodes of a run on a real axis: the follow node (+ recorder), no simulator.

    The axis' driver node is the integrator's: it publishes ``axis/capacitive_height`` and
    ``axis/feedback`` and executes ``axis/velocity_command`` (docs/interfaces.md); with
    ``cia402_eds`` (the drive's EDS/DCF) it is the shipped CiA 402 driver node on the socketcan
    channel (or ``ws://`` test bus) ``can`` (docs/cia402.md); with ``cia402_device`` (the drive's
    device file: its node id, EDS, objects, PDOs and watchdog) the same driver configured from
    it. Lock step is refused: it is the sim node's (a drive does not wait for its controller).
    """
    if loop not in LIVE_LOOPS:
        raise ValueError(f"loop {loop!r} is not offered against a real axis (one of "
                         f"{', '.join(LIVE_LOOPS)}; 'lockstep' needs the sim node)")
    specs = []
    if bag:
        specs.append(NodeSpec('ladrc_bags', 'recorder', 'ladrc_recorder',
                              parameters={'output': bag, 'storage': storage,
                                          'machine_id': hardware_id}))
    if cia402_device:
        specs.append(NodeSpec('ladrc_cia402', 'driver_node', 'ladrc_driver', parameters={
            'device': cia402_device, 'bus_interface': bus_interface(can), 'bus_channel': can}))
    elif cia402_eds:
        specs.append(NodeSpec('ladrc_cia402', 'driver_node', 'ladrc_driver', parameters={
            'eds': cia402_eds, 'bus_interface': bus_interface(can), 'bus_channel': can,
            'node_id': int(node_id)}))
    specs.append(NodeSpec('ladrc_follow', 'follow_node', 'ladrc_follow',
                          parameters={'loop': loop, 'hardware_id': hardware_id},
                          params_file=params_file or default_params_file()))
    return specs


LAUNCH_ARGUMENTS: dict[str, tuple[str, str]] = {
    'scenario': ('showcase', 'scenario the simulator plays: a shipped name (ladrc_sim '
                 'scenarios) or a YAML path; the node set stops when it ends'),
    'params': ('', 'controller parameter file (ROS layout, /** applies to any node name); '
               'empty: the shipped config/follow.yaml'),
    'bag': ('', 'record every contract topic into this bag folder (must not exist); empty: '
            'no recorder'),
    'loop': ('deadline', "follow node tick source: 'deadline' or 'sync' "
             '(docs/follow-node.md)'),
    'lockstep': ('false', 'simulated runs only: the sim node and the follow node in lock step '
                 '(deterministic, equal to the headless runner; docs/follow-node.md)'),
    'storage': ('mcap', "bag storage: 'mcap' or 'sqlite3'"),
    'hardware_id': ('z_axis', 'hardware_id of the follow node on /diagnostics'),
    'view': ('false', 'also start the live view: Foxglove WebSocket on 127.0.0.1 '
             '(docs/live-view.md)'),
    'view_port': ('8765', 'with view:=true: its port on 127.0.0.1'),
}
"""The launch files' arguments: default and description (one declaration for both files)."""


def ros_arguments(spec: NodeSpec) -> list[str]:
    """Return the ``--ros-args`` list of a node spec."""
    args = ['--ros-args']
    if spec.params_file:
        args += ['--params-file', spec.params_file]
    for key, value in spec.parameters.items():
        text = json.dumps(value) if isinstance(value, bool) else str(value)
        args += ['-p', f'{key}:={text}']
    return args + spec.ros_args


def executable_path(package: str, executable: str) -> str:
    """Find an installed console script as ``ros2 run`` would (``<prefix>/lib/<pkg>/<exe>``)."""
    try:
        from ament_index_python.packages import get_package_prefix

        path = Path(get_package_prefix(package)) / 'lib' / package / executable
        if path.exists():
            return str(path)
    except (ImportError, LookupError, ValueError):
        pass
    raise FileNotFoundError(f'{package}/{executable} is not installed (build the workspace: '
                            'scripts/setup-env)')


LOOPBACK_PROFILE = 'fastdds_localhost.xml'
"""The shipped Fast DDS profile (config/): UDP on 127.0.0.1 only, no shared memory."""
MIDDLEWARE_KEYS = ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE',
                   'FASTRTPS_DEFAULT_PROFILES_FILE')
"""What a tool's own process takes over from the environment of the nodes it starts."""


def loopback_profile() -> Path:
    """Return the path of the loopback-only Fast DDS profile (installed, else the source's)."""
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory('ladrc_bringup')) / 'config' / LOOPBACK_PROFILE
    except (ImportError, LookupError, ValueError):  # no ROS install (the noble library check)
        return Path(__file__).resolve().parents[1] / 'config' / LOOPBACK_PROFILE


def loopback_settings(env: Mapping[str, str]) -> dict[str, str]:
    """Return the middleware settings of a node set that is not reachable from the network.

    The shipped profile (docs/safety.md, "Not reachable from the network"), with the rmw's own
    discovery range left to it (``SYSTEM_DEFAULT``): the ``LOCALHOST`` range of rmw_fastrtps
    adds a UDP transport of its own on every interface. A profile of the user's in
    ``FASTRTPS_DEFAULT_PROFILES_FILE`` stays as it is, with their range: that is how a set-up
    opens exactly the interface it needs (docs/real-axis.md). Empty: nothing to change.
    """
    profile = env.get('FASTRTPS_DEFAULT_PROFILES_FILE', '')
    if profile and Path(profile).name != LOOPBACK_PROFILE:
        return {}
    return {'FASTRTPS_DEFAULT_PROFILES_FILE': profile or str(loopback_profile()),
            'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SYSTEM_DEFAULT'}


def isolated_env(domain_id: int | None = None) -> dict[str, str]:
    """Environment of the node processes: own DDS domain, this machine only (loopback).

    The domain: ``domain_id``, else ``LADRC_DOMAIN_ID`` when set (a test running the README's
    commands keeps them on its own domains), else drawn at random from 1..101.
    """
    env = dict(os.environ)
    if domain_id is None and env.get('LADRC_DOMAIN_ID', '').isdigit():
        domain_id = int(env['LADRC_DOMAIN_ID'])
    env['ROS_DOMAIN_ID'] = str(domain_id if domain_id is not None else random.randint(1, 101))
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'  # with a profile of the user's
    env.update(loopback_settings(env))
    env.pop('ROS_LOCALHOST_ONLY', None)
    env.setdefault('PYTHONUNBUFFERED', '1')
    return env


class Bringup:
    """Start node processes from specs; stop them in order; never leave one behind."""

    def __init__(self, specs: list[NodeSpec], env: dict[str, str], log_dir: Path | None = None):
        self.specs = specs
        self.env = env
        self.log_dir = log_dir
        self.procs: dict[str, subprocess.Popen] = {}

    def start(self) -> None:
        """Start every node (in spec order: recorder first, simulator last)."""
        for spec in self.specs:
            cmd = [executable_path(spec.package, spec.executable)] + ros_arguments(spec)
            out = None
            if self.log_dir is not None:
                self.log_dir.mkdir(parents=True, exist_ok=True)
                out = open(self.log_dir / f'{spec.name}.log', 'wb')  # noqa: SIM115
            self.procs[spec.name] = subprocess.Popen(
                cmd, env=self.env, stdout=out, stderr=subprocess.STDOUT if out else None,
                start_new_session=True)
            if out is not None:
                out.close()

    def wait(self, name: str, timeout_s: float | None) -> int | None:
        """Wait for one node to exit by itself; None on timeout."""
        try:
            return self.procs[name].wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            return None

    def stop(self, order: list[str] | None = None, timeout_s: float = 10.0) -> dict[str, int]:
        """SIGINT each node in ``order`` (default: controller, simulator, recorder)."""
        order = order or ['ladrc_follow', 'ladrc_sim', 'ladrc_recorder']
        codes: dict[str, int] = {}
        for name in order + [n for n in self.procs if n not in order]:
            proc = self.procs.get(name)
            if proc is None:
                continue
            codes[name] = interrupt_process(proc, timeout_s)
        return codes


def interrupt_process(proc: subprocess.Popen, timeout_s: float = 10.0) -> int:
    """SIGINT a node process (it commands zero and shuts down); SIGKILL its group if it hangs.

    A process that leads its own group (started with ``start_new_session``) gets the SIGINT as
    a terminal's Ctrl-C would send it, to the whole group: a wrapper such as ``ros2 run``
    waits for its child, which must get the signal itself to command zero.
    """
    if proc.poll() is None:
        try:
            leader = os.getpgid(proc.pid) == proc.pid
        except ProcessLookupError:
            leader = False
        if leader:
            os.killpg(proc.pid, signal.SIGINT)
        else:
            proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return proc.returncode


def job_params_file(job_name: str, base_file: str | None, folder: Path) -> str:
    """Write the follow node's parameters of a job: ``base_file`` with the job's overrides.

    The job file's ``controller`` section over the given (or shipped) set, through the same
    validation and stability gate as ``ladrc job`` (a headless job runs the same set). Raises
    ValueError with one line when the job or the set is unusable.
    """
    from ladrc_follow import (
        ParameterError,
        check_gate,
        dotted,
        dump_params,
        load_params,
        params_from_dict,
        params_to_dict,
    )
    from ladrc_sim import JobError, find_job

    try:
        job = find_job(job_name)
    except JobError as exc:
        raise ValueError(str(exc)) from None
    try:
        base = load_params(base_file or default_params_file())
    except ParameterError as exc:
        raise ValueError(' '.join(str(exc).split())) from None
    try:
        params = check_gate(params_from_dict({**dotted(params_to_dict(base)),
                                              **dotted(job.controller)}))
    except ParameterError as exc:
        raise ValueError(f'{job.path}: controller: {" ".join(str(exc).split())}') from None
    path = folder / 'job_params.yaml'
    path.write_text(dump_params(params, '/**'), encoding='utf-8')
    return str(path)


def run_expects_fault(job: str | None, scenario: str) -> bool:
    """Whether the run may end in FAULT: its scenario's or job's ``expect_fault``.

    Raises ValueError (one line) when the scenario or job does not load.
    """
    if job:
        from ladrc_sim import JobError, find_job

        try:
            return bool(getattr(find_job(job), 'expect_fault', False))
        except JobError as exc:
            raise ValueError(str(exc)) from None
    from ladrc_sim import ScenarioError, load_scenario

    try:
        return load_scenario(scenario).expect_fault
    except ScenarioError as exc:
        raise ValueError(str(exc)) from None


def run_summary(path: Path) -> dict[str, Any]:
    """Return the run the follow node wrote (ladrc_contract.run_log); {} if it wrote none."""
    try:
        return json.loads(path.read_text(encoding='utf-8'))
    except (OSError, ValueError):
        return {}


def job_figures(path: Path | None) -> dict[str, Any]:
    """Return the job's figures the sim node wrote; ``{'finished': False}`` if it wrote none."""
    if path is None or not path.is_file():
        return {'finished': False, 'aborted': 'the job did not end (no figures written)'}
    return json.loads(path.read_text(encoding='utf-8'))


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``bringup``."""
    ap = argparse.ArgumentParser(prog='bringup', description=__doc__.split('\n\n')[0])
    ap.add_argument('--scenario', default='showcase',
                    help='scenario name (shipped library) or YAML path [showcase]')
    ap.add_argument('--job', default=None,
                    help='play a cutting job instead: a shipped job name or a job file '
                    '(ladrc_sim jobs; its controller section overrides --params)')
    ap.add_argument('--separate-cnc', action='store_true',
                    help="with --job: the job's CNC as a node of its own (cnc_node), the sim "
                    'taking XY, beam and cuts from cnc/motion (docs/job-world.md)')
    ap.add_argument('--drive', default='', choices=['', 'cia402'],
                    help="the drive: the sim node's own (default) or 'cia402': the emulated "
                    'CiA 402 drive on a CAN bus with the CiA 402 driver node (docs/real-axis.md)')
    ap.add_argument('--bus', default=None,
                    help='with --drive cia402: a running bus (ws://127.0.0.1:PORT/ of a '
                    'python-can-remote server, or a socketcan channel such as can0); default: '
                    'a bus started here on 127.0.0.1 and stopped at the end')
    ap.add_argument('--device', default='',
                    help="with --drive cia402: the drive's device file (the emulated drive "
                    'loads the same) [the shipped drive]')
    ap.add_argument('--period-ms', type=float, default=None,
                    help="with --drive cia402: the SYNC period = the controller's h_s [0.5 in "
                    'lock step; 1 free-running: the test bus does not hold 0.5 ms free-running '
                    'on 2 cores (docs/real-axis.md)]')
    ap.add_argument('--params', default=None, help='controller parameter file [shipped default]')
    ap.add_argument('--bag', default=None, help='record a bag to this folder (must not exist)')
    ap.add_argument('--storage', default='mcap', choices=['mcap', 'sqlite3'])
    ap.add_argument('--loop', default='deadline', choices=list(LIVE_LOOPS))
    ap.add_argument('--lockstep', action='store_true',
                    help='sim node and follow node in lock step: deterministic, equal to the '
                    'headless runner (docs/follow-node.md)')
    ap.add_argument('--unpaced', action='store_true',
                    help='lock step as fast as the processes go (default: real time at most)')
    ap.add_argument('--domain-id', type=int, default=None, help='ROS_DOMAIN_ID [random 1..101]')
    ap.add_argument('--timeout', type=float, default=600.0,
                    help='stop after this many seconds even if the scenario has not ended')
    ap.add_argument('--logs', default=None, help="folder for the nodes' output [terminal]")
    ap.add_argument('--view', action='store_true',
                    help='also start the live view: Foxglove WebSocket on 127.0.0.1 '
                    '(docs/live-view.md)')
    ap.add_argument('--view-port', type=int, default=VIEW_PORT,
                    help=f'with --view: its port on 127.0.0.1 [{VIEW_PORT}]')
    # LinuxCNC as the job's CNC: bringup/linuxcnc_run.py, docs/linuxcnc.md
    ap.add_argument('--cnc', default='sim', choices=['sim', 'linuxcnc'],
                    help="with --job: the job's CNC: the simulated one (default) or 'linuxcnc' "
                    '(LinuxCNC runs the G-code, the bridge speaks the CNC interface; '
                    'docs/linuxcnc.md)')
    ap.add_argument('--allowance', default='default',
                    help="with --cnc linuxcnc: the simulation's timing allowance (a YAML file; "
                    "'none': the product's values) [config/linuxcnc_allowance.yaml]")
    ap.add_argument('--blend-mm', type=float, default=None,
                    help="with --cnc linuxcnc: the post-processor's G64 P [0.05]; 0: G61")
    ap.add_argument('--fault', default=None,
                    help='with --cnc linuxcnc: inject KIND@SECONDS after cycle start '
                    '(kill-linuxcnc, kill-bridge, estop; the fault matrix)')
    args = ap.parse_args(argv)
    if args.cnc == 'linuxcnc':
        from .linuxcnc_run import main_linuxcnc

        return main_linuxcnc(args)

    if args.separate_cnc and not args.job:
        print('bringup: --separate-cnc needs --job (a scenario has no CNC)', file=sys.stderr)
        return 2
    if (args.bus or args.period_ms is not None or args.device) and args.drive != 'cia402':
        print('bringup: --bus, --period-ms and --device need --drive cia402', file=sys.stderr)
        return 2
    period_ms = args.period_ms if args.period_ms is not None else (
        0.5 if args.lockstep or args.job else 1.0)
    if not 0.25 <= period_ms <= 10.0 or (args.job and period_ms != 0.5):
        print(f'bringup: --period-ms {period_ms:g}: must be in [0.25, 10] (a job: 0.5, the job '
              "world's period)", file=sys.stderr)
        return 2
    if args.bag and Path(args.bag).exists():
        print(f'bringup: {args.bag} exists; choose a new bag folder', file=sys.stderr)
        return 2
    if args.view:  # the view's port: one line now rather than a node that exits at once
        busy = (f'port {args.view_port} out of range' if not 0 < args.view_port < 65536
                else port_in_use(args.view_port))
        if busy:
            print(f'bringup: --view-port: cannot listen on {busy}', file=sys.stderr)
            return 2
    try:
        expect_fault = run_expects_fault(args.job, args.scenario)
    except ValueError as exc:
        print(f'bringup: {exc}', file=sys.stderr)
        return 2
    scratch = Path(tempfile.mkdtemp(prefix='bringup-'))
    try:
        params = (job_params_file(args.job, args.params, scratch) if args.job
                  else args.params)
    except ValueError as exc:
        shutil.rmtree(scratch, ignore_errors=True)
        print(f'bringup: {exc}', file=sys.stderr)
        return 2
    bus_server = None
    if args.drive == 'cia402' and not args.bus:
        from ladrc_sim import start_bus_server

        log_dir = Path(args.logs) if args.logs else None
        if log_dir is not None:
            log_dir.mkdir(parents=True, exist_ok=True)
        try:
            bus_server = start_bus_server(log_dir / 'can_bus.log' if log_dir else None)
        except (OSError, RuntimeError) as exc:
            print(f'bringup: cannot start the CAN bus server: {exc}', file=sys.stderr)
            return 2
    bus = args.bus or (bus_server.url if bus_server is not None else '')
    specs = node_specs(args.scenario, params, args.bag, args.loop, args.storage,
                       lockstep=args.lockstep, paced=not args.unpaced, job=args.job,
                       separate_cnc=args.separate_cnc, drive=args.drive, bus=bus,
                       period_s=period_ms * 1e-3,
                       device=str(Path(args.device).resolve()) if args.device else '')
    figures_file = scratch / 'figures.json' if args.job else None
    if figures_file is not None:  # the sim node writes the job's figures there
        next(s for s in specs if s.name == 'ladrc_sim').parameters['figures_file'] = str(
            figures_file)
    summary_file = scratch / 'run.json'  # the follow node writes its run there at exit
    next(s for s in specs if s.name == 'ladrc_follow').parameters['summary_file'] = str(
        summary_file)
    if args.view:  # first, so that it shows the run from its start
        specs.insert(0, view_spec(args.view_port))
    env = isolated_env(args.domain_id)
    up = Bringup(specs, env, Path(args.logs) if args.logs else None)
    stop = take_stop_signals()  # SIGINT/SIGTERM: the nodes are stopped, the run reported
    print(f'bringup: ROS_DOMAIN_ID={env["ROS_DOMAIN_ID"]} '
          + (f'job={args.job}' if args.job else f'scenario={args.scenario}')
          + (f' drive=cia402 bus={bus}' if args.drive else ''), file=sys.stderr)
    try:
        up.start()
        deadline = time.monotonic() + args.timeout
        while not stop.stop_requested and time.monotonic() < deadline:
            if up.wait('ladrc_sim', 0.2) is not None:
                break
            # the CNC node ends when its job has (exit 0); the sim node follows it at once
            if any(p.poll() is not None and not (n == 'ladrc_cnc' and p.returncode == 0)
                   for n, p in up.procs.items() if n != 'ladrc_sim'):
                print('bringup: a node exited early: '
                      + ', '.join(f'{n}={p.returncode}' for n, p in up.procs.items()
                                  if p.poll() is not None), file=sys.stderr)
                break
    finally:
        codes = up.stop(['ladrc_follow', 'ladrc_driver', 'ladrc_sim', 'ladrc_recorder'])
        if bus_server is not None:
            bus_server.stop()
        figures = job_figures(figures_file)
        run = run_summary(summary_file)
        shutil.rmtree(scratch, ignore_errors=True)
    clean = all(c in (0, -2, 130) for c in codes.values())
    ok, text = verdict(run, expect_fault) if run else (False, 'the follow node wrote no run '
                                                              'summary')
    ok = ok and clean
    outcome = f'{"ok" if ok else "FAILED"}: {text}' + ('' if clean else f'; exit codes {codes}')
    print(f'bringup: {outcome}', file=sys.stderr)
    # last line: a job's figures (docs/job-world.md; none if it did not end), the run's faults
    print(json.dumps({'bag': args.bag, 'exit_codes': codes,
                      **({'job': args.job, **figures} if args.job else {}), 'run': run,
                      'ok': ok, 'outcome': outcome}))
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
