"""The schemas as archives embed them: a self-contained FileDescriptorSet per message.

MCAP's protobuf profile stores, per channel, the message's full name and a binary
FileDescriptorSet holding its .proto file and every file it imports, so Foxglove,
Rerun and the mcap readers decode the archive without schemas/ at hand.
"""

from __future__ import annotations

from google.protobuf.descriptor import FileDescriptor
from google.protobuf.descriptor_pb2 import FileDescriptorProto, FileDescriptorSet

from bridge.bus.gx3_pb2 import DESCRIPTOR

#: Full protobuf name of the message on each key leaf.
MESSAGE_NAMES = {leaf: f"gx3.v1.{name}" for leaf, name in
                 (("imu", "ImuSample"), ("status", "Status"), ("event", "Event"),
                  ("info", "Info"))}


def file_descriptor_set(root: FileDescriptor = DESCRIPTOR) -> bytes:
    """A .proto file and its imports, dependencies first, as one FileDescriptorSet.

    Args:
        root: The file; default schemas/gx3.proto.

    Returns:
        The serialized FileDescriptorSet, as MCAP's protobuf profile stores it.
    """
    files = FileDescriptorSet()
    seen: set[str] = set()

    def add(fd: FileDescriptor) -> None:
        if fd.name in seen:
            return
        for dep in fd.dependencies:
            add(dep)
        seen.add(fd.name)
        proto = FileDescriptorProto()
        fd.CopyToProto(proto)
        files.file.append(proto)

    add(root)
    return files.SerializeToString()
