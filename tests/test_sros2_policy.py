"""The shipped SROS2 policy: valid against SROS2's own schema, and it covers the contract.

The schema is SROS2's, unmodified (tests/vendor/sros2/README.md names the commit and its
sha256). "Covers" is read from the contract's tables in docs/interfaces.md (topics with who
publishes them, the follow services, the drive's reset, the calibration service): each topic
has an allowed publisher and subscriber, each service an allowed server and client, and who
may command the axis or publish its samples is exactly who the contract says. The live check,
that a bring-up's nodes use nothing the policy does not allow, is tests/ros/test_network.py.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
import re

import pytest
import sros2_policy
import xmlschema

ROOT = Path(__file__).resolve().parents[1]
INTERFACES = ROOT / 'docs' / 'interfaces.md'


def _sha256_in_readme() -> str:
    text = (ROOT / 'tests' / 'vendor' / 'sros2' / 'README.md').read_text(encoding='utf-8')
    return re.search(r'sha256 `([0-9a-f]{64})`', text).group(1)


def _contract() -> tuple[list[str], list[str]]:
    """Return the topics and services of docs/interfaces.md's tables (first column)."""
    text = INTERFACES.read_text(encoding='utf-8')
    topics = section_names(text, '## Topics')
    services = section_names(text, '## Follow commands') + ['axis/reset_drive', 'calibrate']
    assert 'axis/reset_drive' in text and '`calibrate`' in text
    return topics, services


def section_names(text: str, heading: str) -> list[str]:
    """Return the first-column names of the table under ``heading``."""
    part = text.split(heading, 1)[1].split('\n## ', 1)[0]
    return re.findall(r'^\| `([^`]+)` \|', part, flags=re.M)


def _full(name: str) -> str:
    return name if name.startswith('/') else '/' + name


def test_the_schema_is_sros2s_unmodified_and_the_policy_is_valid():
    data = sros2_policy.SCHEMA.read_bytes()
    assert hashlib.sha256(data).hexdigest() == _sha256_in_readme()
    schema = xmlschema.XMLSchema(str(sros2_policy.SCHEMA))
    schema.validate(str(sros2_policy.POLICY))  # raises with the reason when it is not


def test_an_invalid_policy_is_refused(tmp_path):
    schema = xmlschema.XMLSchema(str(sros2_policy.SCHEMA))
    text = sros2_policy.POLICY.read_text(encoding='utf-8')
    for bad in (text.replace('version="0.2.0"', 'version="0.1.0"'),
                text.replace('publish="ALLOW"', 'publish="YES"', 1),
                text.replace('<topic>rosout</topic>', '<node>rosout</node>', 1)):
        path = tmp_path / 'bad.xml'
        path.write_text(bad, encoding='utf-8')
        assert not schema.is_valid(str(path))


def test_the_policy_covers_every_topic_and_service_of_the_contract():
    topics, services = _contract()
    assert {'axis/capacitive_height', 'axis/velocity_command', 'cnc/motion',
            '/diagnostics'} <= set(topics)
    assert len(services) >= 10
    profiles = sros2_policy.profiles().values()

    def who(kind: str, name: str) -> set[str]:
        return {p.node for p in profiles if _full(name) in p.allowed[kind]}

    for t in topics:
        assert who('publishers', t), f'{t}: nobody may publish it'
        assert who('subscriptions', t), f'{t}: nobody may subscribe it'
    for s in services:
        assert who('services', s), f'{s}: nobody may serve it'
        assert who('clients', s), f'{s}: nobody may call it'
    # who commands the axis and who publishes its samples: the contract's roles, nobody else
    assert who('publishers', 'axis/velocity_command') == {
        '/ladrc_follow', '/ladrc_conform', '/ladrc_calibrate'}
    for t in ('axis/capacitive_height', 'axis/feedback'):
        assert who('publishers', t) == {'/ladrc_sim'}, t
    assert who('services', 'axis/reset_drive') == {'/ladrc_sim'}
    for s in section_names(INTERFACES.read_text(encoding='utf-8'), '## Follow commands'):
        assert who('services', s) == {'/ladrc_follow'}, s
    assert who('publishers', 'cnc/motion') == {'/ladrc_cnc'}


@pytest.mark.parametrize('name, ns, node, full', [
    ('~/get_parameters', '/', 'ladrc_sim', '/ladrc_sim/get_parameters'),
    ('axis/feedback', '/', 'ladrc_sim', '/axis/feedback'),
    ('/diagnostics', '/machine1', 'x', '/diagnostics'),
    ('axis/feedback', '/machine1', 'x', '/machine1/axis/feedback'),
])
def test_names_expand_as_the_policy_transform_expands_them(name, ns, node, full):
    assert sros2_policy.expand(name, ns, node) == full
