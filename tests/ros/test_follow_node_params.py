"""The follow node's parameters over real ROS: schema descriptors, bad values, parameter files."""

from __future__ import annotations

import math
import subprocess

import pytest

pytest.importorskip('ladrc_msgs', reason='needs the built workspace (make test)')
from ladrc_bringup.bringup import executable_path  # noqa: E402
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue  # noqa: E402
from rcl_interfaces.srv import (  # noqa: E402
    DescribeParameters,
    GetParameters,
    SetParameters,
)
from rosnodes import NodeProcesses, Probe  # noqa: E402

pytestmark = pytest.mark.ros
NS = '/machine_7'
NODE = f'{NS}/ladrc_follow'


def _double(name: str, value: float) -> Parameter:
    return Parameter(name=name, value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE,
                                                     double_value=value))


def _set(probe: Probe, *params: Parameter):
    return probe.call(SetParameters, f'{NODE}/set_parameters',
                      SetParameters.Request(parameters=list(params))).results


def _get(probe: Probe, name: str) -> ParameterValue:
    return probe.call(GetParameters, f'{NODE}/get_parameters',
                      GetParameters.Request(names=[name])).values[0]


@pytest.fixture()
def follow_node(tmp_path):
    """Start a follow node in a namespace with a '/**' file that gives integers for floats."""
    params = tmp_path / 'p.yaml'
    params.write_text('/**:\n  ros__parameters:\n    law:\n      kp: 12\n'
                      '    eso:\n      betas: [180, 10800]\n')
    nodes = NodeProcesses()
    nodes.start('follow', 'ladrc_follow', 'follow_node', '-r', f'__ns:={NS}',
                '--params-file', str(params))
    try:
        probe = Probe()
    except BaseException:
        nodes.close()
        raise
    try:
        yield nodes, probe
    finally:
        try:
            probe.close()  # raises with the probe's exit and output if it did not end cleanly
        finally:
            nodes.close()


def test_parameters_from_the_schema(follow_node):
    nodes, probe = follow_node
    # the '/**' file applied to the namespaced node, integers taken as floats
    assert _get(probe, 'law.kp').double_value == 12.0, nodes.log('follow')
    assert list(_get(probe, 'eso.betas').double_array_value) == [180.0, 10800.0]

    # descriptors from the one declaration: unit, range, read-only
    d = probe.call(DescribeParameters, f'{NODE}/describe_parameters',
                   DescribeParameters.Request(names=['eso.w0_rad_s', 'h_s'])).descriptors
    assert '[rad/s]' in d[0].description and d[0].floating_point_range[0].to_value == 20000.0
    assert d[1].read_only

    # invalid values: rejected with the reason, never a crash, the running value stays
    for name, value in (('td_b.r_per_s', 1e300), ('pid.kp_1_s', 1e300), ('pid.ki_1_s2', math.inf),
                        ('pid.ff_delay_s', math.inf), ('follow.stale_timeout_s', 1e300),
                        ('eso.b0', 0.0), ('pid.ff_ref_gain', math.nan)):
        before = _get(probe, name).double_value
        res = _set(probe, _double(name, value))[0]
        assert not res.successful and res.reason, (name, value)
        assert _get(probe, name).double_value == before
    res = _set(probe, _double('h_s', 0.001))[0]
    assert not res.successful and 'read-only' in res.reason.lower(), res.reason

    # an array parameter changes at run time
    betas = Parameter(name='eso.betas', value=ParameterValue(
        type=ParameterType.PARAMETER_DOUBLE_ARRAY, double_array_value=[240.0, 19200.0]))
    res = _set(probe, betas)[0]
    assert res.successful, res.reason
    assert list(_get(probe, 'eso.betas').double_array_value) == [240.0, 19200.0]
    assert nodes.procs['follow'].poll() is None, nodes.log('follow')
    assert nodes.interrupt('follow') == 0


@pytest.mark.parametrize('text,expect', [
    ('/**:\n  ros__parameters:\n    law:\n      kp: -3.0\n', 'law.kp'),
    ('/**:\n  ros__parameters:\n    law:\n      kp: fast\n', 'law.kp'),
    ('/**:\n  ros__parameters:\n    law: [1, 2\n', ''),
    ('/**:\n  ros__parameters:\n    follow:\n      colision_gap_mm: 0.5\n', 'colision_gap_mm'),
    ('/**:\n  ros__parameters:\n    eso:\n      betas: [true, true]\n', 'eso.betas'),
])
def test_a_bad_parameter_file_is_one_line_and_exit_code(tmp_path, text, expect):
    path = tmp_path / 'bad.yaml'
    path.write_text(text)
    proc = subprocess.run([executable_path('ladrc_follow', 'follow_node'), '--ros-args',
                           '--params-file', str(path)], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode != 0
    err = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(err) == 1 and err[0].startswith('follow_node: '), proc.stderr
    assert expect in err[0]
    assert 'Traceback' not in proc.stderr + proc.stdout


def test_diagnostics_named_after_the_node_and_stamped_on_its_clock(tmp_path):
    """Name diagnostics as diagnostic_updater does; stamp on the node clock (/clock)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from ladrc_msgs.msg import FollowStatus
    from rosgraph_msgs.msg import Clock

    nodes = NodeProcesses()
    nodes.start('follow', 'ladrc_follow', 'follow_node', '-r', f'__ns:={NS}',
                '-p', 'hardware_id:=head_7', '-p', 'diagnostics_period_s:=0.2',
                '-p', 'use_sim_time:=true')
    probe = None
    seen = []
    try:
        probe = Probe()
        probe.subscribe(DiagnosticArray, '/diagnostics',
                        lambda m: seen.extend((s.name, s.hardware_id) for s in m.status))
        status = probe.record(FollowStatus, f'{NS}/follow/status',
                              fields=['header.stamp.sec', 'header.stamp.nanosec'],
                              keep=lambda r: r[0] + r[1] * 1e-9)

        def tick_clock() -> bool:
            msg = Clock()
            msg.clock.sec = 1000
            probe.publish(Clock, '/clock', msg, qos=10)
            return bool(seen) and len(status) > 10 and status[-1] == 1000.0

        assert probe.spin_until(tick_clock, 30.0), nodes.log('follow')
        assert ('machine_7/ladrc_follow: follow loop', 'head_7') in seen
    finally:
        try:
            if probe is not None:
                probe.close()
        finally:
            nodes.close()
