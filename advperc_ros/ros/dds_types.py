"""Cyclone DDS IDL types of the topic contract, generated from the rosbags Jazzy typestore.

ROS 2 (rmw_cyclonedds) puts a message `pkg/msg/Type` on the wire as the DDS type
`pkg::msg::dds_::Type_`: a final (non-extensible) struct with the message's fields in order,
serialised as plain CDR (XCDR1, encapsulation 0x0001 little-endian). The structs here are built
at import time by walking `TYPESTORE.fielddefs`, the same definitions rosbags serialises with,
so nothing is hand-written and a new contract type needs no code.

Field mapping (the rosidl IDL mapping): ROS `byte` -> octet, `char` -> uint8, other primitives
1:1, `string<=N` -> bounded string, `T[N]` -> array, `T[]` / `T[<=N]` -> (bounded) sequence,
nested messages -> nested structs. Constants are not part of the wire format and are skipped.
`wstring` is not supported (no contract type has one).

Conversion strategy: through the bytes, not field by field. `to_idl` deserialises rosbags' CDR
with the IDL type and `from_idl` deserialises the IDL type's CDR with rosbags. The two object
models differ in representation (numpy arrays vs lists/bytes, rosbags' frozen dataclasses), and
the wire format is the one thing both must agree on anyway; test_dds proves byte equality for
every contract type, so the same proof covers the conversion. The transport (dds.py) goes further
and puts the bytes on the wire directly, which is about five times faster than Cyclone's
Python serialiser for a MarkerArray even when rosbags makes them.

No `from __future__ import annotations` here: cyclonedds reads the field annotations of
IdlStruct classes as real objects, not strings.
"""

from typing import Any

from cyclonedds.idl import IdlStruct, make_idl_struct
from cyclonedds.idl import types as idl

from advperc_ros.ros.cdr import TYPESTORE, payload
from advperc_ros.ros.topics import TOPIC_TYPES

# rosbags Nodetype values (rosbags.interfaces.Nodetype): BASE, NAME, ARRAY, SEQUENCE
_BASE, _NAME, _ARRAY, _SEQUENCE = 1, 2, 3, 4

_PRIMITIVES: dict[str, Any] = {
    "bool": bool,
    "byte": idl.byte,
    "char": idl.uint8,
    "int8": idl.int8,
    "uint8": idl.uint8,
    "int16": idl.int16,
    "uint16": idl.uint16,
    "int32": idl.int32,
    "uint32": idl.uint32,
    "int64": idl.int64,
    "uint64": idl.uint64,
    "float32": idl.float32,
    "float64": idl.float64,
}

IDL_TYPES: dict[str, type[IdlStruct]] = {}
"""Generated IDL struct per ROS type name (`pkg/msg/Type`), filled by `idl_type`."""


def dds_type_name(msgtype: str) -> str:
    """The DDS type name ROS 2 uses for `pkg/msg/Type`: `pkg::msg::dds_::Type_`."""
    *namespace, name = msgtype.split("/")
    return "::".join([*namespace, "dds_", f"{name}_"])


def _field_type(desc: tuple, where: str) -> Any:
    # cyclonedds' bounded_str, array and sequence are subscripted at run time (__class_getitem__ returns an
    # Annotated type), which mypy reads as a generic class that is not one: hence the three ignores
    kind, rest = int(desc[0]), desc[1]
    if kind == _BASE:
        name, bound = rest
        if name == "string":
            return idl.bounded_str[bound] if bound else str  # type: ignore[misc]
        if name in _PRIMITIVES:
            return _PRIMITIVES[name]
        raise TypeError(f"{where}: ROS type {name!r} has no DDS mapping here")
    if kind == _NAME:
        return idl_type(rest)
    if kind == _ARRAY:
        element, length = rest
        return idl.array[_field_type(element, where), int(length)]  # type: ignore[misc]
    if kind == _SEQUENCE:
        element, bound = rest
        sub = _field_type(element, where)
        return idl.sequence[sub, int(bound)] if bound else idl.sequence[sub]  # type: ignore[misc]
    raise TypeError(f"{where}: unknown rosbags node type {desc!r}")


def idl_type(msgtype: str) -> type[IdlStruct]:
    """The IDL struct of a typestore message type, generated (with its nested types) on first use."""
    cls = IDL_TYPES.get(msgtype)
    if cls is not None:
        return cls
    if msgtype not in TYPESTORE.fielddefs:
        raise KeyError(f"{msgtype}: not in the rosbags Jazzy typestore")
    _, fields = TYPESTORE.fielddefs[msgtype]
    annotations = {name: _field_type(desc, f"{msgtype}.{name}") for name, desc in fields}
    cls = make_idl_struct(msgtype.rsplit("/", 1)[-1] + "_", dds_type_name(msgtype), annotations)
    cls.__module__ = __name__
    IDL_TYPES[msgtype] = cls
    return cls


def from_cdr(data: bytes, msgtype: str) -> object:
    """A DDS payload (encapsulation header, CDR, up to 3 bytes padding) as a rosbags message."""
    return TYPESTORE.deserialize_cdr(data, msgtype)


def idl_to_cdr(sample: IdlStruct) -> bytes:
    """An IDL sample as plain CDR (XCDR1), the representation ROS 2 uses; unpadded."""
    return sample.serialize(use_version_2=False)


def to_idl(msg: object, msgtype: str) -> IdlStruct:
    """rosbags message (or its CDR payload) -> IDL sample, through the shared wire format."""
    return idl_type(msgtype).deserialize(payload(msg, msgtype))


def from_idl(sample: IdlStruct, msgtype: str) -> object:
    """IDL sample -> rosbags message, through the shared wire format."""
    return from_cdr(idl_to_cdr(sample), msgtype)


for _msgtype in sorted(set(TOPIC_TYPES.values())):
    idl_type(_msgtype)
