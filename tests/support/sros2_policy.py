"""The shipped SROS2 policy read as plain sets: who may publish, subscribe, serve, call what.

``config/sros2_policy.xml`` in ladrc_tools is an SROS2 policy (docs/safety.md, "SROS2"): per
enclave, per node, the topics it may publish and subscribe and the services it may serve
(``reply``) and call (``request``). :func:`allowed` expands every name the way the policy's
transform does: a relative name under the profile's namespace, ``~/`` under the node's own name.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
import xml.etree.ElementTree as ET

ROOT = Path(__file__).resolve().parents[2]
POLICY = ROOT / 'ros2_ws' / 'src' / 'ladrc_bringup' / 'config' / 'sros2_policy.xml'
SCHEMA = ROOT / 'tests' / 'vendor' / 'sros2' / 'policy.xsd'
# (element, attribute) -> the kind of endpoint it allows
KINDS = {('topics', 'publish'): 'publishers', ('topics', 'subscribe'): 'subscriptions',
         ('services', 'reply'): 'services', ('services', 'request'): 'clients'}


@dataclass
class Profile:
    """One node's rights: endpoint kind -> the fully qualified names it may use."""

    enclave: str
    node: str  # fully qualified: /ns/name
    allowed: dict[str, set[str]] = field(default_factory=lambda: {k: set() for k in
                                                                  KINDS.values()})


def expand(name: str, ns: str, node: str) -> str:
    """Return the fully qualified form of a policy name (``~/x``, ``x``, ``/x``)."""
    if name.startswith('~/'):
        return f'{ns.rstrip("/")}/{node}/{name[2:]}'
    if name.startswith('/'):
        return name
    return f'{ns.rstrip("/")}/{name}'


def profiles(path: Path = POLICY) -> dict[str, Profile]:
    """Return every profile of the policy by its node's fully qualified name (ALLOW only)."""
    out: dict[str, Profile] = {}
    for enclave in ET.parse(path).getroot().iter('enclave'):
        for prof in enclave.iter('profile'):
            ns, node = prof.get('ns', '/'), prof.get('node', '')
            full = f'{ns.rstrip("/")}/{node}'
            p = out.setdefault(full, Profile(enclave.get('path', ''), full))
            for rules in prof:
                for (tag, attr), kind in KINDS.items():
                    if rules.tag == tag and rules.get(attr) == 'ALLOW':
                        p.allowed[kind] |= {expand(e.text.strip(), ns, node) for e in rules}
    return out


def uncovered(graph: dict, policy: dict[str, Profile]) -> list[str]:
    """Return each endpoint of ``graph`` (rosnodes.Probe.graph) the policy does not allow."""
    out = []
    for node, kinds in sorted(graph.items()):
        prof = policy.get(node)
        for kind, endpoints in sorted(kinds.items()):
            for name, _types in endpoints:
                if prof is None or name not in prof.allowed[kind]:
                    out.append(f'{node} {kind} {name}'
                               + ('' if prof is not None else ' (node not in the policy)'))
    return out
