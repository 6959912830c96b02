"""Every node starts through ladrc_contract.node_entry; no other file handles stop signals.

Read from the sources (ast), no ROS needed: a node that installs its own SIGINT/SIGTERM handler
or keeps its own ``running = [True]`` flag escapes the entry's zero command on a stop; a node's
console script whose ``main`` does not call ``run_node`` starts outside it. The entry's
behaviour with a real rclpy node: tests/ros/test_node_entry_run.py.
"""

from __future__ import annotations

import ast
import os
from pathlib import Path
import signal
import time

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / 'ros2_ws' / 'src'
ENTRY = SRC / 'ladrc_contract' / 'ladrc_contract' / 'node_entry.py'

# Files that may keep their own signal code, with the reason.
EXEMPT = {
    # LinuxCNC's side: run on LinuxCNC's system Python, where only the stdlib, LinuxCNC's
    # modules and the protocol may be imported (tests/test_layers.py), not ladrc_contract
    'ladrc_linuxcnc/ladrc_linuxcnc/display.py': "LinuxCNC's Python: no ladrc_contract",
    'ladrc_linuxcnc/ladrc_linuxcnc/hal_component.py': "LinuxCNC's Python: no ladrc_contract",
}
# Node classes: a module that builds one of these (or a subclass) is a node's module.
NODE_BASES = {'Node', 'LoopNode'}
# The nodes the scan must find (so an empty scan cannot pass).
KNOWN_NODES = {'follow_node', 'sim_node', 'cnc_node', 'driver_node', 'bridge_node'}


def _sources() -> list[Path]:
    return sorted(p for p in SRC.rglob('*.py')
                  if '__pycache__' not in p.parts and not any(
                      part in ('build', 'install', 'log') for part in p.relative_to(SRC).parts))


def _rel(path: Path) -> str:
    return path.relative_to(SRC).as_posix()


def _dotted(node: ast.AST) -> str:
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        return f'{_dotted(node.value)}.{node.attr}'
    return ''


def signal_code(tree: ast.AST) -> list[str]:
    """Return where ``tree`` installs a signal handler or sets a ``[True]`` flag (line: what)."""
    names = {'signal.signal'}  # `from signal import signal [as x]` too
    for n in ast.walk(tree):
        if isinstance(n, ast.ImportFrom) and n.module == 'signal':
            names |= {a.asname or a.name for a in n.names if a.name == 'signal'}
    found = []
    for n in ast.walk(tree):
        if isinstance(n, ast.Call) and _dotted(n.func) in names:
            found.append((n.lineno, f'{_dotted(n.func)}()'))
        elif isinstance(n, (ast.Assign, ast.AnnAssign)) and isinstance(n.value, ast.List) and (
                len(n.value.elts) == 1 and isinstance(n.value.elts[0], ast.Constant)
                and n.value.elts[0].value is True):
            found.append((n.lineno, 'a [True] flag'))
    return [f'{line}: {what}' for line, what in sorted(found)]


def test_the_scan_sees_signal_code():
    code = ('import signal\nfrom signal import signal as on\nrunning = [True]\n'
            'signal.signal(signal.SIGINT, h)\non(2, h)\nflag: list = [True]\nx = [False]\n')
    assert [f.split(':')[0] for f in signal_code(ast.parse(code))] == ['3', '4', '5', '6']


def test_no_file_but_the_entry_has_signal_code():
    offenders = {}
    for path in _sources():
        rel = _rel(path)
        if path == ENTRY or rel in EXEMPT:
            continue
        found = signal_code(ast.parse(path.read_text(encoding='utf-8'), str(path)))
        if found:
            offenders[rel] = found
    assert not offenders, ('signal handling outside ladrc_contract/node_entry.py (use run_node, '
                           f'stop_signals or ignore_stop_signals): {offenders}')


def test_the_exemptions_still_have_signal_code():
    """An exemption that no longer needs it goes (the list stays the truth)."""
    for rel in EXEMPT:
        path = SRC / rel
        assert signal_code(ast.parse(path.read_text(encoding='utf-8'))), rel


def console_scripts() -> dict[str, tuple[Path, Path, str]]:
    """Every package's console scripts: name -> (setup.py, module file, function)."""
    out = {}
    for setup in sorted(SRC.glob('*/setup.py')):
        for n in ast.walk(ast.parse(setup.read_text(encoding='utf-8'))):
            if not (isinstance(n, ast.Constant) and isinstance(n.value, str)
                    and '=' in n.value and ':' in n.value):
                continue
            name, _, target = (s.strip() for s in n.value.partition('='))
            module, _, func = target.partition(':')
            if not module.replace('.', '').replace('_', '').isalnum():
                continue
            base = setup.parent / Path(*module.split('.'))
            path = base.with_suffix('.py') if base.with_suffix('.py').exists() \
                else base / '__init__.py'
            out[name] = (setup, path, func)
    return out


def _node_classes(tree: ast.AST) -> set[str]:
    """Class names in ``tree`` deriving from a node class (directly or through one here)."""
    classes = {n.name: {_dotted(b).rsplit('.', 1)[-1] for b in n.bases}
               for n in ast.walk(tree) if isinstance(n, ast.ClassDef)}
    nodes = set(NODE_BASES)
    grown = True
    while grown:
        new = {c for c, bases in classes.items() if bases & nodes} - nodes
        nodes |= new
        grown = bool(new)
    return nodes


def builds_a_node(tree: ast.AST) -> bool:
    """Whether the module builds a node (calls a node class, its own subclasses included)."""
    nodes = _node_classes(tree)
    return any(isinstance(n, ast.Call) and _dotted(n.func).rsplit('.', 1)[-1] in nodes
               for n in ast.walk(tree))


def _function(tree: ast.AST, name: str) -> ast.FunctionDef | None:
    for n in getattr(tree, 'body', []):
        if isinstance(n, ast.FunctionDef) and n.name == name:
            return n
    return None


def test_every_node_console_script_starts_through_run_node():
    scripts = console_scripts()
    nodes, outside = set(), {}
    for name, (setup, path, func) in scripts.items():
        assert path.exists(), f'{_rel(setup)}: {name} -> {path} does not exist'
        tree = ast.parse(path.read_text(encoding='utf-8'))
        if not builds_a_node(tree):
            continue
        nodes.add(name)
        main = _function(tree, func)
        assert main is not None, f'{name}: no function {func} in {_rel(path)}'
        calls = {_dotted(n.func).rsplit('.', 1)[-1] for n in ast.walk(main)
                 if isinstance(n, ast.Call)}
        if 'run_node' not in calls:
            outside[name] = _rel(path)
    assert KNOWN_NODES <= nodes, f'the scan missed nodes: {sorted(KNOWN_NODES - nodes)}'
    assert not outside, f'node entry points not starting through run_node: {outside}'


def test_the_node_scan_tells_a_node_from_a_tool():
    node = 'class A(LoopNode):\n    pass\nclass B(A):\n    pass\ndef main():\n    B()\n'
    plain = 'class A:\n    pass\ndef main():\n    A()\n'
    assert builds_a_node(ast.parse(node)) and not builds_a_node(ast.parse(plain))


def test_stop_signals_requests_the_stop_and_restores_the_handlers():
    from ladrc_contract.node_entry import stop_signals

    before = signal.getsignal(signal.SIGTERM)
    calls = []
    with stop_signals() as stop:
        stop.on_stop(lambda: calls.append(stop.stop_reason))
        os.kill(os.getpid(), signal.SIGTERM)
        assert stop.wait(5.0)
    assert calls == ['SIGTERM'] and stop.stop_reason == 'SIGTERM'
    assert signal.getsignal(signal.SIGTERM) is before


def test_a_hook_added_after_the_stop_runs_at_once():
    from ladrc_contract.node_entry import NodeRun

    run = NodeRun()
    run.request_stop('SIGINT')
    run.request_stop('SIGTERM')  # the first reason stays
    seen = []
    run.on_stop(lambda: seen.append(run.stop_reason))
    assert seen == ['SIGINT'] and run.wait(0.0)


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_ignore_stop_signals(sig):
    from ladrc_contract.node_entry import ignore_stop_signals

    before = signal.getsignal(sig)
    try:
        ignore_stop_signals((sig,))
        assert signal.getsignal(sig) is signal.SIG_IGN
    finally:
        signal.signal(sig, before)  # the test process's handler back


def test_take_stop_signals_keeps_its_handlers():
    from ladrc_contract.node_entry import take_stop_signals

    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        stop = take_stop_signals()
        os.kill(os.getpid(), signal.SIGINT)
        assert stop.wait(5.0) and stop.stop_reason == 'SIGINT'
        os.kill(os.getpid(), signal.SIGTERM)  # handled still: no exit, the first reason stays
        time.sleep(0.05)
        assert stop.stop_reason == 'SIGINT'
    finally:
        for s, handler in before.items():
            signal.signal(s, handler)
