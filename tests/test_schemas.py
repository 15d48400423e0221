"""schemas/gx3.proto stays in step with the command table and with the committed code."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any, cast

from google.protobuf import descriptor_pool, message_factory
from google.protobuf.descriptor import FieldDescriptor
from google.protobuf.descriptor_pb2 import FileDescriptorSet

from bridge.bus import gx3_pb2
from bridge.bus.codec import HEADER, elements, record_quantities
from bridge.bus.gx3_pb2 import ImuSample
from bridge.bus.schema import MESSAGE_NAMES, file_descriptor_set
from bridge.protocol.table import DATA_CODES, QUANTITIES

ROOT = Path(__file__).resolve().parent.parent
FIELDS = ImuSample.DESCRIPTOR.fields_by_name
PROTOC = "python -m grpc_tools.protoc -I schemas --python_out=bridge/bus --pyi_out=bridge/bus " \
         "schemas/gx3.proto"


def test_generated_code_is_what_protoc_makes_of_the_schema(tmp_path: Path) -> None:
    subprocess.run([sys.executable, "-m", "grpc_tools.protoc", f"-I{ROOT / 'schemas'}",
                    f"--python_out={tmp_path}", f"--pyi_out={tmp_path}",
                    str(ROOT / "schemas" / "gx3.proto")], check=True)
    for name in ("gx3_pb2.py", "gx3_pb2.pyi"):
        assert (tmp_path / name).read_bytes() == (ROOT / "bridge" / "bus" / name).read_bytes(), \
            f"bridge/bus/{name} is stale; regenerate with: {PROTOC}"


def test_every_reply_quantity_of_every_data_record_has_its_field() -> None:
    in_records = {q for code in DATA_CODES for q in record_quantities(code)}
    in_schema = {name for name, f in FIELDS.items() if f.GetOptions().HasExtension(
        cast(Any, gx3_pb2.elements))}
    assert in_schema == in_records
    for name in in_records:
        field = FIELDS[name]
        assert elements(name) == QUANTITIES[name].count, name
        assert field.is_repeated, name
        want = FieldDescriptor.TYPE_FLOAT if QUANTITIES[name].kind == "f32" \
            else FieldDescriptor.TYPE_FIXED32
        assert field.type == want, name
    assert set(FIELDS) == {"unit", *HEADER, *in_records}


def test_header_fields_have_presence_and_fixed_width() -> None:
    fixed = {FieldDescriptor.TYPE_FIXED32, FieldDescriptor.TYPE_SFIXED64}
    for name in HEADER:
        assert FIELDS[name].has_presence, name
        assert FIELDS[name].type in fixed, name
    assert FIELDS["unit"].has_presence


def test_the_embedded_descriptor_set_decodes_messages_on_its_own() -> None:
    """What an archive embeds is enough for a reader that has never seen schemas/."""
    files = FileDescriptorSet.FromString(file_descriptor_set())
    assert [f.name for f in files.file] == ["google/protobuf/descriptor.proto", "gx3.proto"]
    pool = descriptor_pool.DescriptorPool()
    for f in files.file:
        pool.Add(f)
    for leaf, name in MESSAGE_NAMES.items():
        cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(name))
        original = getattr(gx3_pb2, name.rsplit(".", 1)[1])(unit=f"u-{leaf}")
        decoded: Any = cls.FromString(original.SerializeToString())
        assert decoded.unit == f"u-{leaf}"
