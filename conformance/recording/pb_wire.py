"""Protobuf's wire format, the part the frame batches use (:mod:`.traffic_pb`):
varints, tags, length-delimited fields, and the ``FileDescriptorSet`` of one proto3
message from a table of its fields (the schema an MCAP protobuf channel carries).

Protobuf's encoding (protobuf.dev, "Encoding"): a field is a varint tag (field number
<< 3 | wire type) and its value: a varint (wire type 0), 8 bytes (1), a varint length
and that many bytes (2), or 4 bytes (5).  ``descriptor.proto`` is itself such messages.
"""

from __future__ import annotations

from collections.abc import Sequence

__all__ = ["I32", "I64", "LEN", "VARINT", "descriptor_set", "field", "read_varint", "tag", "varint"]

#: The wire types this kit writes and reads.
VARINT, I64, LEN, I32 = 0, 1, 2, 5


def varint(v: int) -> bytes:
    """A non-negative integer as a varint (7 bits a byte, low bits first)."""
    if v < 0x80:
        return bytes((v,))
    out = bytearray()
    while v >= 0x80:
        out.append((v & 0x7F) | 0x80)
        v >>= 7
    out.append(v)
    return bytes(out)


def tag(number: int, wire: int) -> bytes:
    return varint(number << 3 | wire)


def field(number: int, payload: bytes) -> bytes:
    """A length-delimited field: tag, length, payload."""
    return tag(number, LEN) + varint(len(payload)) + payload


def read_varint(buf: bytes, i: int) -> tuple[int, int]:
    """The varint at ``buf[i]`` and the position after it: an ``IndexError`` when the
    buffer ends inside it, a ``ValueError`` past 10 bytes or 64 bits."""
    b = buf[i]
    if b < 0x80:
        return b, i + 1
    v = b & 0x7F
    shift = 7
    while True:
        i += 1
        b = buf[i]
        v |= (b & 0x7F) << shift
        if b < 0x80:
            if v >> 64:
                raise ValueError(f"a varint at byte {i} is past 64 bits")
            return v, i + 1
        shift += 7
        if shift >= 70:
            raise ValueError(f"a varint at byte {i} is longer than 10 bytes")


#: FieldDescriptorProto.Type and .Label values (google/protobuf/descriptor.proto).
_TYPES = {"fixed64": 6, "string": 9, "bytes": 12, "uint64": 4}
_OPTIONAL, _REPEATED = 1, 3


def descriptor_set(
    file: str, package: str, message: str, fields: Sequence[tuple[str, int, str, bool]]
) -> bytes:
    """The ``FileDescriptorSet`` of one proto3 file holding one message whose fields are
    ``(name, number, type, repeated)`` (types: fixed64, string, bytes, uint64)."""
    body = b"".join(
        field(
            2,  # DescriptorProto.field
            field(1, name.encode())  # name
            + tag(3, VARINT)
            + varint(number)  # number
            + tag(4, VARINT)
            + varint(_REPEATED if repeated else _OPTIONAL)  # label
            + tag(5, VARINT)
            + varint(_TYPES[kind]),  # type
        )
        for name, number, kind, repeated in fields
    )
    proto = (
        field(1, file.encode())  # FileDescriptorProto.name
        + field(2, package.encode())  # package
        + field(4, field(1, message.encode()) + body)  # message_type: name, field
        + field(12, b"proto3")  # syntax
    )
    return field(1, proto)  # FileDescriptorSet.file
