"""The ladrc_msgs contract: every message crosses DDS intact and bags serialize it identically."""

from __future__ import annotations

import importlib
import time

from msgfill import cdr_padding, fill_rclpy, to_plain, to_rosbags
import pytest

rclpy = pytest.importorskip('rclpy')
from ladrc_bags.typestore import ladrc_typestore, msg_definitions  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402

MESSAGES = sorted(name.rsplit('/', 1)[1] for name in msg_definitions())


def test_contract_has_every_interface():
    # DESIGN.md's contract: capacitive height, axis feedback, velocity command, follow status,
    # sim truth, plus the event log the replay needs; revision 2: the lock step and the CNC
    # interface (docs/interfaces.md, "Revisions")
    assert set(MESSAGES) == {'AxisFeedback', 'CapacitiveHeight', 'FollowEvent', 'FollowStatus',
                             'SimTruth', 'VelocityCommand', 'LockStep', 'CncMotion'}
    srv = importlib.import_module('ladrc_msgs.srv')
    for name in ('StartFollow', 'StopFollow', 'SetTarget', 'SetMachining', 'HeightCompensation',
                 'GradientFollow', 'ResetFault', 'Pierce', 'Lift', 'Leapfrog', 'Hold'):
        assert hasattr(srv, name), name


def _rclpy_class(name: str):
    return getattr(importlib.import_module('ladrc_msgs.msg'), name)


@pytest.mark.ros
@pytest.mark.parametrize('name', MESSAGES)
def test_message_crosses_dds_intact(ros_context, name):
    cls = _rclpy_class(name)
    sent = [fill_rclpy(cls(), salt=i) for i in range(3)]
    pub_node = rclpy.create_node('contract_pub', context=ros_context)
    sub_node = rclpy.create_node('contract_sub', context=ros_context)
    received = []
    topic = f'contract/{name}'
    pub = pub_node.create_publisher(cls, topic, 10)
    sub_node.create_subscription(cls, topic, received.append, 10)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(pub_node)
    executor.add_node(sub_node)
    try:
        deadline = time.monotonic() + 20.0
        while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        assert pub.get_subscription_count() == 1, 'discovery failed on the test domain'
        for msg in sent:
            pub.publish(msg)
        while len(received) < len(sent) and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
    finally:
        executor.shutdown()
        pub_node.destroy_node()
        sub_node.destroy_node()
    assert [to_plain(m) for m in received] == [to_plain(m) for m in sent]
    # the filler really changed the fields (a default-valued message would pass trivially)
    assert to_plain(sent[0]) != to_plain(cls())


@pytest.mark.parametrize('name', MESSAGES)
def test_rosbags_serialization_is_byte_identical(name):
    store = ladrc_typestore()
    msg = fill_rclpy(_rclpy_class(name)(), salt=5)
    typename = f'ladrc_msgs/msg/{name}'
    ours = bytes(store.serialize_cdr(to_rosbags(msg, store, typename), typename))
    theirs = serialize_message(msg)
    assert len(ours) == len(theirs)
    # Identical byte for byte, except CDR alignment padding, which Fast-CDR (rclpy) leaves
    # uninitialised and rosbags writes as zeros: no reader ever looks at those bytes.
    padding = cdr_padding(store, typename, to_rosbags(msg, store, typename))
    assert all(ours[i] == 0 for i in padding)
    differing = {i for i in range(len(ours)) if ours[i] != theirs[i]}
    assert differing <= padding, f'data bytes differ at {sorted(differing - padding)}'
    assert theirs == bytes(b if i not in padding else theirs[i] for i, b in enumerate(ours))
    # rclpy's bytes (what the recorder writes to bags raw) read back to the same values
    assert store.deserialize_cdr(theirs, typename) == to_rosbags(msg, store, typename)


def test_the_contract_codes_are_the_generated_constants():
    """ladrc_contract.codes: each enum is its message's constants, name for name."""
    from ladrc_contract.codes import MESSAGE_CONSTANTS

    for enum, (typename, prefix) in MESSAGE_CONSTANTS.items():
        cls = _rclpy_class(typename.rsplit('/', 1)[1])
        generated = {k[len(prefix):]: v for k, v in vars(cls).items()
                     if k.isupper() and k.startswith(prefix) and isinstance(v, int)
                     and not k.startswith('SLOT')}
        assert {m.name: int(m) for m in enum} == generated, enum.__name__


def test_the_contract_services_and_topics_name_generated_types():
    from ladrc_contract.services import FOLLOW_SERVICES, service_class
    from ladrc_contract.topics import TOPIC_TYPES

    for name, (srv_type, _, fields) in FOLLOW_SERVICES.items():
        request = service_class(srv_type).Request()
        assert all(hasattr(request, f) for f in fields.values()), name
    for typename in TOPIC_TYPES.values():
        pkg, _, name = typename.split('/')
        assert hasattr(importlib.import_module(f'{pkg}.msg'), name), typename
