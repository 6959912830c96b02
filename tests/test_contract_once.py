"""The contract is written once (ladrc_contract): QoS, codes, event codec, real time, schema.

Read from the sources' syntax trees (nothing is imported): a QoS profile, a table of message
codes, the follow-command <-> event mapping, the tick input, the real-time set-up or a parameter
declaration (a dataclass field carrying its declaration as metadata) defined
anywhere but in its home in ``ladrc_contract`` fails here, with the file and line.
"""

from __future__ import annotations

import ast
from pathlib import Path
import re

import pytest

SRC = Path(__file__).resolve().parents[1] / 'ros2_ws' / 'src'
CONTRACT = 'ladrc_contract/ladrc_contract/'

# a code table: a name of the messages' constants bound to a number literal
CODE_NAME = re.compile(r'^(STATE|SUB|STATUS|GAP_STATUS|LIMIT|LIMIT_FLAG|SEGMENT)_[A-Z0-9_]+$')
# the follow-command kinds of FollowEvent (PARAMETERS is a parameter set, not a command)
COMMAND_KINDS = {'START_FOLLOW', 'STOP_FOLLOW', 'SET_TARGET', 'MACHINING', 'HEIGHT_COMPENSATION',
                 'GRADIENT_FOLLOW', 'RESET_FAULT', 'TARGET_WAVE', 'PIERCE', 'LIFT', 'LEAPFROG',
                 'HOLD'}
REALTIME_CALLS = {'sched_setscheduler', 'mlockall', 'sched_setaffinity'}


def _sources() -> list[Path]:
    return sorted(p for p in SRC.rglob('*.py') if '__pycache__' not in p.parts)


def _rel(p: Path) -> str:
    return str(p.relative_to(SRC))


def _call_name(node: ast.Call) -> str:
    f = node.func
    return f.attr if isinstance(f, ast.Attribute) else getattr(f, 'id', '')


def _is_number(node: ast.AST) -> bool:
    if isinstance(node, ast.Constant):
        return isinstance(node.value, int) and not isinstance(node.value, bool)
    if isinstance(node, ast.Tuple):
        return all(_is_number(e) for e in node.elts)
    return False


def findings(source: str, where: str) -> list[str]:
    """Every definition in ``source`` that belongs in ladrc_contract (``where``: its path)."""
    out = []
    tree = ast.parse(source)
    home = where.startswith(CONTRACT)
    for node in ast.walk(tree):
        line = f'{where}:{getattr(node, "lineno", 0)}'
        if isinstance(node, ast.Call):
            name = _call_name(node)
            if name == 'QoSProfile' and where != CONTRACT + 'qos.py':
                out.append(f'{line}: a QoS profile made outside ladrc_contract/qos.py')
            if name in REALTIME_CALLS and where != CONTRACT + 'realtime.py':
                out.append(f'{line}: {name} outside ladrc_contract/realtime.py')
            if (name == 'field' and any(k.arg == 'metadata' for k in node.keywords)
                    and where != CONTRACT + 'schema.py'):
                out.append(f'{line}: a parameter declared outside ladrc_contract/schema.py')
        elif isinstance(node, ast.Attribute):
            owner = getattr(node.value, 'id', '')
            if node.attr in ('ReliabilityPolicy', 'DurabilityPolicy') or owner in (
                    'ReliabilityPolicy', 'DurabilityPolicy'):
                if where != CONTRACT + 'qos.py':
                    out.append(f'{line}: a QoS policy named outside ladrc_contract/qos.py')
            if (owner in ('FollowEvent', 'EventKind') and node.attr in COMMAND_KINDS
                    and where != CONTRACT + 'events.py' and not home):
                out.append(f'{line}: {owner}.{node.attr}: the event codec is '
                           'ladrc_contract/events.py')
        elif isinstance(node, ast.Assign) and not home and _is_number(node.value):
            for target in node.targets:
                names = ([t.id for t in target.elts if isinstance(t, ast.Name)]
                         if isinstance(target, ast.Tuple) else [getattr(target, 'id', '')])
                out += [f'{line}: {n} = a number: the codes are ladrc_contract/codes.py'
                        for n in names if CODE_NAME.match(n)]
        elif isinstance(node, ast.Dict) and not home:
            keys = {k.value for k in node.keys if isinstance(k, ast.Constant)}
            if {'start_follow', 'stop_follow'} <= keys and all(map(_is_number, node.values)):
                out.append(f'{line}: a command -> event kind table: ladrc_contract/events.py')
        elif isinstance(node, ast.ClassDef) and not home:
            if node.name in ('TickInput', 'FollowState', 'EventKind', 'GapStatus', 'LimitFlag',
                             'SubState'):
                out.append(f'{line}: class {node.name}: defined in ladrc_contract')
    return out


# programs LinuxCNC runs on the system's Python (tests/test_layers.py LINUXCNC_SIDE): they can
# import nothing of the project, so they schedule themselves
SYSTEM_PYTHON_SIDE = {'ladrc_linuxcnc/ladrc_linuxcnc/hal_component.py'}


def test_the_contract_is_written_once():
    problems = []
    for path in _sources():
        if _rel(path) in SYSTEM_PYTHON_SIDE:
            continue
        problems += findings(path.read_text(encoding='utf-8'), _rel(path))
    assert not problems, '\n'.join(problems)


@pytest.mark.parametrize('source', [
    'from rclpy.qos import QoSProfile\nq = QoSProfile(depth=1)\n',
    'from rclpy.qos import ReliabilityPolicy\nr = ReliabilityPolicy.RELIABLE\n',
    'STATUS_OK, STATUS_FAULT = 0, 3\n',
    'class Ev:\n    LIMIT_VELOCITY = 1\n',
    "KIND = {'start_follow': 1, 'stop_follow': 2}\n",
    'kind = FollowEvent.SET_TARGET\n',
    'import os\nos.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(50))\n',
    'from typing import NamedTuple\nclass TickInput(NamedTuple):\n    t_s: float\n',
    ('from dataclasses import field\n'
     'def spec(d, **kw):\n    return field(default=d, metadata=kw)\n'),
])
def test_each_kind_of_second_definition_is_found(source):
    assert findings(source, 'ladrc_tools/ladrc_tools/somewhere.py')


@pytest.mark.parametrize('source', [
    'from ladrc_contract.codes import GapStatus\nSTATUS_OK = int(GapStatus.OK)\n',
    'from ladrc_contract.qos import to_rclpy, HIGH_RATE\nq = to_rclpy(HIGH_RATE)\n',
    'kind = FollowEvent.PARAMETERS\n',
    ('from ladrc_contract.schema import param\n'
     "class P:\n    x: float = param(1.0, 'mm', 'x', gt=0)\n"),
])
def test_uses_of_the_contract_are_not_definitions(source):
    assert not findings(source, 'ladrc_tools/ladrc_tools/somewhere.py')
