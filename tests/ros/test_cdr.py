"""The fast CDR packer of the publish path equals the reference serializers."""

from __future__ import annotations

from msgfill import cdr_padding, fill_rclpy, to_rosbags
import pytest

rclpy = pytest.importorskip('rclpy')
from ladrc_follow.cdr import CdrPacker  # noqa: E402
from ladrc_follow.typestore import ladrc_typestore, msg_definitions  # noqa: E402
import ladrc_msgs.msg  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402

MESSAGES = sorted(name.rsplit('/', 1)[1] for name in msg_definitions())


def _leaf(msg, dotted: str):
    for part in dotted.split('.'):
        msg = getattr(msg, part)
    return msg


@pytest.mark.parametrize('name', MESSAGES)
@pytest.mark.parametrize('salt', [0, 1, 2, 3])  # different string lengths shift the alignment
def test_packer_matches_rosbags_and_rclpy(name, salt):
    store = ladrc_typestore()
    typename = f'ladrc_msgs/msg/{name}'
    msg = fill_rclpy(getattr(ladrc_msgs.msg, name)(), salt=salt)
    packer = CdrPacker(typename)
    ours = packer.pack([_leaf(msg, f) for f, _ in packer.fields])
    reference = bytes(store.serialize_cdr(to_rosbags(msg, store, typename), typename))
    assert ours == reference
    theirs = serialize_message(msg)
    padding = cdr_padding(store, typename, to_rosbags(msg, store, typename))
    assert len(ours) == len(theirs)
    assert all(ours[i] == theirs[i] for i in range(len(ours)) if i not in padding)
