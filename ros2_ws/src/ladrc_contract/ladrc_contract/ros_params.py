"""A parameter's one declaration (``schema.param``) as ROS declares it: descriptor and value.

Used by every node that declares a parameter section (the follow node, the CiA 402 driver): the
type, range, unit and read-only flag come from the declaration, nothing is restated.
"""

from __future__ import annotations

from array import array
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType

from .schema import Entry, entries

_ROS_TYPE = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
             float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING}


def descriptor(entry: Entry) -> ParameterDescriptor:
    """Return the ROS descriptor of one declared parameter (type, range, unit, read-only)."""
    s = entry.spec
    unit = f' [{s.unit}]' if s.unit else ''
    seed = f' ({s.seed})' if s.seed else ''
    desc = ParameterDescriptor(name=entry.name, description=f'{s.description}{unit}{seed}',
                               read_only=not s.runtime)
    desc.type = _ROS_TYPE.get(entry.type, ParameterType.PARAMETER_DOUBLE_ARRAY)
    if s.range_text():
        desc.additional_constraints = ('one of ' if s.choices else 'range ') + s.range_text()
    if s.choices or s.lower is None or s.upper is None:
        return desc
    if entry.type is int:
        desc.integer_range = [IntegerRange(from_value=int(s.lower), to_value=int(s.upper),
                                           step=1)]
    elif entry.type is float:
        desc.floating_point_range = [FloatingPointRange(from_value=float(s.lower),
                                                        to_value=float(s.upper), step=0.0)]
    return desc


def ros_value(entry: Entry, value: Any) -> Any:
    """Return a value as ROS wants it for this entry: floats for float fields, lists for arrays."""
    if entry.type is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(value, (tuple, list, array)) and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        return [float(v) for v in value]
    return value  # anything else goes to rclpy's type check as it is




def declare_section(node: Any, section: Any, prefix: str = '') -> Any:
    """Declare every parameter of ``section`` on ``node``; return the section as given.

    The values a ``--params-file`` or ``-p`` set are checked against the declaration
    (``schema.first_problem``): an invalid one raises ``ValueError`` naming it and its range.
    """
    from dataclasses import replace

    from .schema import first_problem

    values = {}
    for e in entries(section):
        name = prefix + e.name
        node.declare_parameter(name, ros_value(e, e.value), descriptor(e))
        values[e.name] = node.get_parameter(name).value
    out = replace(section, **values)
    problem = first_problem(out)
    if problem is not None:
        raise ValueError(f'parameter {prefix}{problem[0]}: {problem[1]}')
    return out
