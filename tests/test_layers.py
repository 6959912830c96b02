"""The package split holds: which package may import which, and package.xml declares every import.

Read from the source files (ast), nothing is imported:

* the arrows between the project's packages point down only (:data:`ALLOWED`, the picture in
  docs/architecture.md, "Layers"): a package imports only the packages its row names (and
  ``ladrc_msgs``, the interfaces every package may use); the table has no cycle; a package.xml
  names no package above it;
* ``control/``, ``models/``, ``headless/``, ``offline/``, ... are pure: no rclpy; so are
  ``ladrc_bags`` (but its recorder node) and ``ladrc_fleet``;
* ``ladrc_follow`` (the controller) imports none of rosbags, matplotlib, scipy;
* ``ladrc_cia402``'s CANopen layer (``ds402``, ``emcy``, ``units``, ``mapping``) no rclpy;
* ``ladrc_linuxcnc``'s files that run on the system Python inside LinuxCNC (``hal_component``,
  ``display``, ``z_filter``, ``gcode_path``, and ``protocol`` they share) import only the
  standard library, LinuxCNC's own modules and ``protocol``: no rclpy, no numpy, nothing of
  the contract; LinuxCNC's modules (``hal``, ``linuxcnc``, ``gcode``: the Debian package
  linuxcnc-uspace, no rosdep key) only there;
* each package's package.xml has a ``<depend>`` or ``<exec_depend>`` for every third-party
  top-level module its Python files import (including imports inside functions);
* no package imports a private name (``_name``, or a name from a ``_module``) of another
  package: what crosses a package's border is its public API.
"""

from __future__ import annotations

import ast
from pathlib import Path
import sys
import xml.etree.ElementTree as ET

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / 'ros2_ws' / 'src'
PACKAGES = ('ladrc_contract', 'ladrc_cia402', 'ladrc_linuxcnc', 'ladrc_follow', 'ladrc_sim',
            'ladrc_bags', 'ladrc_tools', 'ladrc_bringup', 'ladrc_fleet')
INTERFACES = 'ladrc_msgs'  # generated message classes: any package may import them
# who may import whom: each package's row names the project's packages it may import. The
# arrows point down: machine side (contract, drive, LinuxCNC, controller), then the simulator,
# the bags, the tools, and on top the bring-up and the fleet tools. A package above another
# adds to it without being imported (ladrc's subcommands: the entry-point group ladrc.commands).
ALLOWED: dict[str, frozenset[str]] = {
    'ladrc_contract': frozenset(),
    'ladrc_cia402': frozenset({'ladrc_contract'}),
    'ladrc_linuxcnc': frozenset({'ladrc_contract'}),
    'ladrc_follow': frozenset({'ladrc_contract'}),
    'ladrc_sim': frozenset({'ladrc_contract', 'ladrc_cia402'}),  # the emulated CiA 402 drive
    'ladrc_bags': frozenset({'ladrc_contract'}),
    'ladrc_tools': frozenset({'ladrc_contract', 'ladrc_cia402', 'ladrc_follow', 'ladrc_sim',
                              'ladrc_bags'}),
    'ladrc_fleet': frozenset({'ladrc_contract', 'ladrc_follow', 'ladrc_sim', 'ladrc_bags',
                              'ladrc_tools'}),
    'ladrc_bringup': frozenset({'ladrc_contract', 'ladrc_linuxcnc', 'ladrc_follow', 'ladrc_sim',
                                'ladrc_bags', 'ladrc_tools'}),
}
PURE_FOLDERS = ('control', 'models', 'headless', 'job', 'offline', 'commissioning', 'cia402',
                'cam')
PURE_PACKAGES = {'ladrc_bags': {'recorder_node.py'}, 'ladrc_fleet': set()}
"""Packages with no rclpy, but for the files named (their ROS side)."""
LINUXCNC_SIDE = ('hal_component.py', 'display.py', 'z_filter.py', 'gcode_path.py',
                 'protocol.py')  # ladrc_linuxcnc's files on the system Python, inside LinuxCNC
LINUXCNC_MODULES = {'hal', 'linuxcnc', 'gcode'}  # LinuxCNC's own (system Python only)
CIA402_PURE = ('ds402.py', 'emcy.py', 'units.py', 'mapping.py', 'master.py')  # plain layer

# top-level module -> rosdep key / ROS package name in package.xml
DEPEND_KEY = {
    'rclpy': 'rclpy',
    'numpy': 'python3-numpy',
    'scipy': 'python3-scipy',
    'yaml': 'python3-yaml',
    'matplotlib': 'python3-matplotlib',
    'rosbags': 'python3-rosbags-pip',
    'mcap': 'mcap-ros2-support',  # rosdistro's pip key whose package depends on mcap
    'shapely': 'python3-shapely',
    'ezdxf': 'python3-ezdxf',
    'dask': 'python3-dask-pip',  # the fleet tools: pip on every path (requirements/stock.txt)
    'distributed': 'python3-distributed-pip',
    'pyarrow': 'python3-pyarrow-pip',
    'foxglove': 'python3-foxglove-sdk-pip',  # the live view: pip on every path
    'websockets': 'python3-websockets',  # the live view's tests (a Foxglove client)
    'ladrc_msgs': 'ladrc_msgs',
    'ladrc_contract': 'ladrc_contract',
    'ladrc_cia402': 'ladrc_cia402',
    'ladrc_linuxcnc': 'ladrc_linuxcnc',
    'canopen': 'python3-canopen-pip',  # pip on every path (requirements/stock.txt)
    'can': 'python3-can',
    'std_msgs': 'std_msgs',
    'diagnostic_msgs': 'diagnostic_msgs',
    'rcl_interfaces': 'rcl_interfaces',
    'builtin_interfaces': 'builtin_interfaces',
    'ament_index_python': 'ament_index_python',
    'launch': 'launch',
    'launch_ros': 'launch_ros',
    'ladrc_follow': 'ladrc_follow',
    'ladrc_sim': 'ladrc_sim',
    'ladrc_bags': 'ladrc_bags',
    'ladrc_tools': 'ladrc_tools',
    'ladrc_bringup': 'ladrc_bringup',
    'ladrc_fleet': 'ladrc_fleet',
    'pytest': 'python3-pytest',
}
RUN_DEPEND_TAGS = ('depend', 'exec_depend')
TEST_DEPEND_TAGS = RUN_DEPEND_TAGS + ('test_depend',)  # for the package's own test/ folder
# setup.py runs at build time (ament_python brings setuptools); it is not a run-time import.
BUILD_ONLY = {'setup.py'}


# ---- the checks, as functions of source text (so they can be tested on small examples) ------
def imported_modules(source: str, filename: str = '<string>') -> set[str]:
    """Return the top-level names of every absolute import in ``source`` (any nesting level)."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(source, filename)):
        if isinstance(node, ast.Import):
            found.update(alias.name.split('.')[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.add(node.module.split('.')[0])
    return found


def third_party(modules: set[str], own: str) -> set[str]:
    """Drop the standard library and the package's own name from ``modules``."""
    return {m for m in modules if m != own and m not in sys.stdlib_module_names
            and m != '__future__'}


def run_depends(package_xml: str, tags: tuple[str, ...] = RUN_DEPEND_TAGS) -> set[str]:
    """Return the dependencies of a package.xml text under ``tags`` (default: run time)."""
    root = ET.fromstring(package_xml)
    return {el.text.strip() for tag in tags for el in root.iter(tag) if el.text}


def missing_depends(modules: set[str], package_xml: str,
                    tags: tuple[str, ...] = RUN_DEPEND_TAGS) -> list[str]:
    """Return one line per third-party module whose key is missing (or unknown to the map)."""
    declared = run_depends(package_xml, tags)
    out = []
    for m in sorted(modules):
        key = DEPEND_KEY.get(m)
        if key is None:
            out.append(f'{m}: no package.xml key known for this module (add it to DEPEND_KEY)')
        elif key not in declared:
            out.append(f'{m}: package.xml lacks <{tags[-1]}>{key}</{tags[-1]}>')
    return out


# ---- the source tree ----------------------------------------------------------------------
def _py_files(package: str) -> list[Path]:
    return sorted(p for p in (SRC / package).rglob('*.py') if '__pycache__' not in p.parts)


def _imports(path: Path) -> set[str]:
    return imported_modules(path.read_text(encoding='utf-8'), str(path))


def _rel(path: Path) -> str:
    return str(path.relative_to(SRC))


def test_the_packages_exist():
    for pkg in PACKAGES:
        assert (SRC / pkg / 'package.xml').is_file(), pkg
        assert _py_files(pkg), pkg


def test_pure_folders_do_not_import_rclpy():
    pure = [p for pkg in PACKAGES for p in _py_files(pkg)
            if any(part in PURE_FOLDERS for part in p.relative_to(SRC / pkg).parts[:-1])]
    assert len(pure) >= 20  # the folders are where this test looks for them
    offenders = [_rel(p) for p in pure if 'rclpy' in _imports(p)]
    assert not offenders, f'pure layers import rclpy: {offenders}'


@pytest.mark.parametrize('package', sorted(PURE_PACKAGES))
def test_pure_packages_do_not_import_rclpy(package):
    files = [p for p in _py_files(package) if p.relative_to(SRC / package).parts[0] == package]
    ros_side = [p for p in files if p.name in PURE_PACKAGES[package]]
    assert len(ros_side) == len(PURE_PACKAGES[package])  # the exceptions exist
    offenders = [_rel(p) for p in files if p not in ros_side and 'rclpy' in _imports(p)]
    assert not offenders, f'{package} imports rclpy: {offenders}'


# ---- the arrows between the packages -------------------------------------------------------
def cycle_in(graph: dict[str, frozenset[str]]) -> list[str]:
    """Return one cycle of ``graph`` (name -> names it imports) as a path, [] when it has none."""
    done: set[str] = set()
    path: list[str] = []

    def visit(node: str) -> list[str]:
        if node in path:
            return path[path.index(node):] + [node]
        if node in done:
            return []
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            found = visit(nxt)
            if found:
                return found
        path.pop()
        done.add(node)
        return []

    for start in sorted(graph):
        found = visit(start)
        if found:
            return found
    return []


def below(graph: dict[str, frozenset[str]], package: str) -> set[str]:
    """Return every package ``package`` reaches by the arrows of ``graph`` (not itself)."""
    seen: set[str] = set()
    todo = list(graph.get(package, ()))
    while todo:
        p = todo.pop()
        if p not in seen:
            seen.add(p)
            todo.extend(graph.get(p, ()))
    return seen


def upward_imports(package: str, modules: set[str],
                   graph: dict[str, frozenset[str]] = ALLOWED) -> set[str]:
    """Return the project's packages in ``modules`` that ``package`` may not import."""
    ours = {m for m in modules if m.startswith('ladrc_')}
    return ours - graph[package] - {package, INTERFACES}


def test_the_arrows_point_down_only():
    assert set(ALLOWED) == set(PACKAGES)
    assert all(set(v) <= set(PACKAGES) for v in ALLOWED.values())
    assert cycle_in(ALLOWED) == []


def test_a_cycle_or_an_upward_import_is_found():
    assert cycle_in({'a': frozenset({'b'}), 'b': frozenset({'c'}), 'c': frozenset({'a'})}) == [
        'a', 'b', 'c', 'a']
    assert cycle_in({'a': frozenset({'b'}), 'b': frozenset(), 'c': frozenset({'a', 'b'})}) == []
    assert below(ALLOWED, 'ladrc_bringup') >= {'ladrc_tools', 'ladrc_bags', 'ladrc_cia402'}
    assert upward_imports('ladrc_tools', {'ladrc_fleet', 'ladrc_bags', 'ladrc_msgs', 'numpy'}
                          ) == {'ladrc_fleet'}
    assert upward_imports('ladrc_bags', {'ladrc_tools', 'ladrc_bringup'}) == {
        'ladrc_tools', 'ladrc_bringup'}


@pytest.mark.parametrize('package', PACKAGES)
def test_a_package_imports_only_the_packages_below_it(package):
    offenders = {_rel(p): sorted(upward_imports(package, _imports(p)))
                 for p in _py_files(package) if p.relative_to(SRC / package).parts[0] != 'test'}
    assert not {k: v for k, v in offenders.items() if v}, f'{package} may import only ' \
        f'{sorted(ALLOWED[package])}: {offenders}'


@pytest.mark.parametrize('package', PACKAGES)
def test_package_xml_names_no_package_above(package):
    """Its ladrc_* dependencies are packages its arrows reach: never one above (a cycle)."""
    xml = (SRC / package / 'package.xml').read_text(encoding='utf-8')
    ours = {d for d in run_depends(xml, TEST_DEPEND_TAGS) if d.startswith('ladrc_')}
    assert not ours - below(ALLOWED, package) - {INTERFACES}


@pytest.mark.parametrize('module', ['rosbags', 'matplotlib', 'scipy'])
def test_controller_package_stays_lean(module):
    offenders = [_rel(p) for p in _py_files('ladrc_follow') if module in _imports(p)]
    assert not offenders, f'ladrc_follow imports {module}: {offenders}'


@pytest.mark.parametrize('package', PACKAGES)
def test_package_xml_declares_every_import(package):
    modules: set[str] = set()
    tests: set[str] = set()
    for p in _py_files(package):
        if p.name in BUILD_ONLY:
            continue
        if p.relative_to(SRC / package).parts[0] == 'test':  # colcon test: test_depend
            tests |= third_party(_imports(p), package)
        else:  # (LinuxCNC's own modules: checked by test_the_linuxcnc_package_is_machine_side)
            modules |= third_party(_imports(p), package) - LINUXCNC_MODULES
    xml = (SRC / package / 'package.xml').read_text(encoding='utf-8')
    assert not missing_depends(modules, xml)
    assert tests and not missing_depends(tests, xml, TEST_DEPEND_TAGS)


def _private(name: str) -> bool:
    return name.startswith('_') and not name.startswith('__')


def private_imports(source: str, own: str, filename: str = '<string>') -> list[str]:
    """Return ``'module.name'`` for every private name ``source`` imports from another package.

    A private name is ``_name`` or anything under a ``_module``; the own package (``own``),
    relative imports and packages outside the project (not ``ladrc_*``) do not count.
    """
    out = []
    for node in ast.walk(ast.parse(source, filename)):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            parts = node.module.split('.')
            if not parts[0].startswith('ladrc_') or parts[0] == own:
                continue
            out += [f'{node.module}.{a.name}' for a in node.names
                    if any(map(_private, parts)) or _private(a.name)]
        elif isinstance(node, ast.Import):
            out += [a.name for a in node.names if a.name.startswith('ladrc_')
                    and a.name.split('.')[0] != own and any(map(_private, a.name.split('.')))]
    return out


@pytest.mark.parametrize('package', PACKAGES)
def test_no_package_imports_a_private_name_of_another(package):
    offenders = {_rel(p): private_imports(p.read_text(encoding='utf-8'), package, str(p))
                 for p in _py_files(package)}
    assert not {k: v for k, v in offenders.items() if v}, \
        f'{package} imports private names of other packages (make them public): {offenders}'


# Packages whose public API is their top level (``__init__``'s ``_EXPORTS``, imported on first
# use): another package imports their names from there, never from a module inside.
TOP_LEVEL_API = ('ladrc_follow', 'ladrc_sim', 'ladrc_cia402', 'ladrc_linuxcnc')


def deep_imports(source: str, own: str) -> list[str]:
    """``from P.mod import name`` in ``own`` for P of TOP_LEVEL_API, name not a module of P."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if not (isinstance(node, ast.ImportFrom) and node.module and node.level == 0):
            continue
        top = node.module.split('.')[0]
        if top not in TOP_LEVEL_API or top == own or node.module == top:
            continue
        folder = SRC / top / Path(*node.module.split('.'))
        out += [f'{node.module}.{a.name}' for a in node.names
                if not ((folder / f'{a.name}.py').exists() or (folder / a.name).is_dir())]
    return out


@pytest.mark.parametrize('package', PACKAGES)
def test_other_packages_import_the_public_api_from_the_top_level(package):
    offenders = {_rel(p): deep_imports(p.read_text(encoding='utf-8'), package)
                 for p in _py_files(package)}
    assert not {k: v for k, v in offenders.items() if v}, \
        f'{package}: import these from the package itself (its __init__ exports them): {offenders}'


@pytest.mark.parametrize('package', TOP_LEVEL_API)
def test_every_exported_name_resolves(package):
    import importlib
    mod = importlib.import_module(package)
    assert mod.__all__ and sorted(mod.__all__) == mod.__all__
    missing = [n for n in mod.__all__ if not hasattr(mod, n)]
    assert not missing, f'{package} exports names its modules do not define: {missing}'


# ---- the checks themselves, on small in-memory examples ------------------------------------
EXAMPLE_XML = """<?xml version="1.0"?>
<package format="3">
  <name>demo</name>
  <depend>rclpy</depend>
  <exec_depend>python3-numpy</exec_depend>
  <build_depend>python3-yaml</build_depend>
  <test_depend>python3-scipy</test_depend>
</package>
"""
EXAMPLE_SOURCE = """
from __future__ import annotations
import os.path
import numpy as np
from . import sibling
from .sub.mod import thing
from demo.other import x

def late():
    import yaml
    from rclpy.node import Node
"""


def test_import_scan_finds_nested_and_skips_relative_imports():
    mods = imported_modules(EXAMPLE_SOURCE)
    assert mods == {'__future__', 'os', 'numpy', 'demo', 'yaml', 'rclpy'}
    assert third_party(mods, own='demo') == {'numpy', 'yaml', 'rclpy'}


def test_a_private_import_across_packages_is_found():
    source = """
from ladrc_sim.job import jobfile, _helper
from ladrc_sim._internal.mod import thing
from ladrc_demo.x import _own
from .sibling import _fine
import ladrc_sim._internal
from numpy import _private_of_numpy

def late():
    from ladrc_contract.schema import _join as join
"""
    assert private_imports(source, own='ladrc_demo') == [
        'ladrc_sim.job._helper', 'ladrc_sim._internal.mod.thing', 'ladrc_sim._internal',
        'ladrc_contract.schema._join']


def test_missing_key_is_reported():
    mods = third_party(imported_modules(EXAMPLE_SOURCE), own='demo')
    # yaml is only a build_depend: not a run-time dependency
    assert missing_depends(mods, EXAMPLE_XML) == [
        'yaml: package.xml lacks <exec_depend>python3-yaml</exec_depend>']
    full = EXAMPLE_XML.replace('<build_depend>python3-yaml', '<exec_depend>python3-yaml') \
                      .replace('</build_depend>', '</exec_depend>')
    assert missing_depends(mods, full) == []
    # removing any one key makes it fail again
    for key in ('rclpy', 'python3-numpy'):
        assert missing_depends(mods, full.replace(f'>{key}<', '>gone<'))


def test_unknown_third_party_module_is_reported():
    assert missing_depends({'pandas'}, EXAMPLE_XML) == [
        'pandas: no package.xml key known for this module (add it to DEPEND_KEY)']


def test_the_cia402_canopen_layer_is_plain():
    """ladrc_cia402's CANopen layer (what a real drive's master runs) imports no rclpy."""
    pure = [p for p in _py_files('ladrc_cia402') if p.name in CIA402_PURE]
    assert len(pure) == len(CIA402_PURE)
    assert not [_rel(p) for p in pure if 'rclpy' in _imports(p)]


def test_machine_side_packages_do_not_import_the_live_view():
    """The live view (foxglove-sdk, ladrc_tools' view node) is a tool beside the machine."""
    offenders = {_rel(p): sorted(_imports(p) & {'foxglove', 'websockets'})
                 for pkg in ('ladrc_contract', 'ladrc_follow', 'ladrc_cia402')
                 for p in _py_files(pkg)}
    assert not {k: v for k, v in offenders.items() if v}


def test_the_linuxcnc_package_is_machine_side():
    """ladrc_linuxcnc runs beside LinuxCNC (its imports: :data:`ALLOWED`).

    Its LinuxCNC side runs on the system Python (whatever Python the venv was made from):
    standard library, LinuxCNC's modules and the shared protocol only; LinuxCNC's modules
    nowhere else in the project.
    """
    files = _py_files('ladrc_linuxcnc')
    side = [p for p in files if p.name in LINUXCNC_SIDE and p.parent.name == 'ladrc_linuxcnc']
    assert len(side) == len(LINUXCNC_SIDE)
    for p in side:
        extra = third_party(_imports(p), 'ladrc_linuxcnc') - LINUXCNC_MODULES
        assert not extra, f'{_rel(p)} runs on the system Python: it imports {sorted(extra)}'
    elsewhere = [_rel(p) for pkg in PACKAGES for p in _py_files(pkg)
                 if _imports(p) & LINUXCNC_MODULES and p not in side]
    assert not elsewhere, f"LinuxCNC's modules imported off its side: {elsewhere}"
