"""How a bus key becomes an MCAP channel, and how a channel's messages become bus payloads again.

Recording: one channel per key (and per Zenoh encoding seen on it), in one of three forms.

* ``typed``: a key of the key table whose payload decodes. Schema: the message's JSON Schema
  (schema encoding ``jsonschema``, name ``icefloe.<Message>``), self-contained (no ``$ref``) and
  with a ``type`` on every property, as Foxglove's reader needs; messages: JSON (message encoding
  ``json``), so Foxglove and any JSON reader decode them with no plug-in. msgspec writes
  ``bytes`` fields as base64 strings, as the schema says (``contentEncoding: base64``).
* ``image``: ``camera/image`` as Foxglove's ``foxglove.CompressedImage`` (timestamp, frame_id,
  data, format), so Foxglove's Image panel shows it, plus ``width`` and ``height``: icefloe's
  `Image` needs them back on replay, and Foxglove ignores fields it does not know.
* ``raw``: anything else (a key outside the table, a payload that does not decode): the bytes
  as they came, with no schema, message encoding ``msgpack``/``json``/the Zenoh encoding.
  Replay sends them back unchanged, so a TA reproduces a student's bad input too.

Every channel's metadata holds ``zenoh_encoding``, what the publisher sent (MessagePack for
icefloe's own publishers), so replay puts the same encoding back on the bus.

Replay reads any MCAP file: a channel of another tool (ROS 2 ``cdr``, protobuf, JSON of
unknown schemas) is replayed as raw bytes on a key made from its topic, or refused with the
reason when its topic cannot be a key (`ChannelPlan.refused`).
"""

from __future__ import annotations

import functools
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Annotated, Any, Literal

import msgspec
import zenoh

from ..errors import BadPayload, BadRecording
from ..schemas import codec, export, keys
from ..schemas import messages as m

ENCODING_META = "zenoh_encoding"
"""Channel metadata: the Zenoh encoding the publisher used."""
SCHEMA_PREFIX = "icefloe."
IMAGE_SCHEMA = "foxglove.CompressedImage"
JSONSCHEMA = "jsonschema"

Form = Literal["typed", "image", "raw", "ros2"]
"""``ros2``: a ROS 2 topic (CDR) that replay turns back into an icefloe key's messages (`ros2.Ros2Replay`)."""


class FoxgloveTime(msgspec.Struct, frozen=True):
    sec: int
    nsec: int


class CompressedImage(msgspec.Struct, frozen=True, kw_only=True):
    """A compressed image (Foxglove's ``foxglove.CompressedImage``, plus icefloe's width and height)."""

    timestamp: Annotated[FoxgloveTime, msgspec.Meta(description="Timestamp of image (the frame's stamp)")]
    frame_id: Annotated[str, msgspec.Meta(description="Frame of reference for the image")] = "camera"
    data: Annotated[bytes, msgspec.Meta(description="Compressed image data")]
    format: Annotated[str, msgspec.Meta(description="Image format (jpeg)")] = "jpeg"
    width: Annotated[int, msgspec.Meta(description="icefloe: image width, px")] = 0
    height: Annotated[int, msgspec.Meta(description="icefloe: image height, px")] = 0


@dataclass(frozen=True, eq=False)  # one object per channel (`Transcoder.spec`): hashed by identity
class ChannelSpec:
    """A channel to register in a file: its topic (the full bus key), schema and metadata."""

    topic: str
    form: Form
    schema_name: str
    schema_encoding: str
    schema: bytes
    message_encoding: str
    metadata: dict[str, str] = field(default_factory=dict)


# --------------------------------------------------------------------------- schemas


def inline_refs(schema: dict[str, Any]) -> dict[str, Any]:
    """``schema`` with every ``{"$ref": "#/$defs/X"}`` replaced by ``X`` itself, and no ``$defs``.

    Foxglove reads a JSON Schema's top-level ``properties`` (to find base64 ``bytes`` fields,
    and the fields to plot); it does not follow references.
    """
    defs = schema.get("$defs", {})

    def resolve(node: Any) -> Any:
        if isinstance(node, dict):
            ref = node.get("$ref")
            rest = {k: resolve(v) for k, v in node.items() if k not in ("$ref", "$defs")}
            if isinstance(ref, str) and ref.startswith("#/$defs/"):
                return {**resolve(defs[ref.removeprefix("#/$defs/")]), **rest}
            return rest
        if isinstance(node, list):
            return [resolve(v) for v in node]
        return node

    return resolve(schema)


def typed_enums(schema: Any) -> Any:
    """``schema`` with a ``type`` on every ``enum`` that has none.

    msgspec writes a `Literal` field as a bare ``{"enum": [...]}``; Foxglove's JSON Schema reader
    needs a ``type`` on every property and refuses the whole channel without one.
    """
    if isinstance(schema, dict):
        out = {k: typed_enums(v) for k, v in schema.items()}
        values = out.get("enum")
        if "type" not in out and isinstance(values, list) and values:
            if all(isinstance(v, str) for v in values):
                out["type"] = "string"
            elif all(isinstance(v, int) and not isinstance(v, bool) for v in values):
                out["type"] = "integer"
        return out
    if isinstance(schema, list):
        return [typed_enums(v) for v in schema]
    return schema


@functools.cache
def message_schema(type_name: str) -> bytes:
    """The JSON Schema of an icefloe message (as in schemas/json/, references inlined, enums typed)."""
    schema = json.loads(export.schemas()[f"{type_name}.json"])
    return json.dumps(typed_enums(inline_refs(schema)), sort_keys=True).encode()


@functools.cache
def image_schema() -> bytes:
    schema = inline_refs(msgspec.json.schema(CompressedImage))
    schema["title"] = IMAGE_SCHEMA
    return json.dumps(schema, sort_keys=True).encode()


@functools.cache
def message_types() -> dict[str, type[m.Message]]:
    return {t.__name__: t for t in export.message_types()}


def message_encoding_of(zenoh_encoding: str) -> str:
    """The MCAP message encoding for a raw payload of this Zenoh encoding."""
    base = zenoh_encoding.split(";", 1)[0].strip()
    return {codec.MSGPACK: "msgpack", codec.JSON: "json", "text/json": "json"}.get(base, base)


def zenoh_encoding_of(message_encoding: str, schema_name: str = "") -> str:
    """The Zenoh encoding to publish a foreign channel's bytes with (its schema name as the suffix)."""
    base = {"json": codec.JSON, "msgpack": codec.MSGPACK, "cdr": "application/cdr",
            "protobuf": "application/protobuf", "cbor": "application/cbor"}.get(message_encoding, "zenoh/bytes")
    return f"{base};{schema_name}" if schema_name else base


# --------------------------------------------------------------------------- recording


class Transcoder:
    """Turns bus samples into (channel spec, MCAP message data, publish time) for the file."""

    def __init__(self) -> None:
        self._specs: dict[tuple[str, Form, str], ChannelSpec] = {}

    def spec(self, key: str, form: Form, encoding: str, type_name: str = "") -> ChannelSpec:
        found = self._specs.get((key, form, encoding))
        if found is None:
            meta = {ENCODING_META: encoding}
            if form == "typed":
                found = ChannelSpec(key, form, SCHEMA_PREFIX + type_name, JSONSCHEMA, message_schema(type_name),
                                    "json", meta)
            elif form == "image":
                found = ChannelSpec(key, form, IMAGE_SCHEMA, JSONSCHEMA, image_schema(), "json", meta)
            else:
                found = ChannelSpec(key, form, "", "", b"", message_encoding_of(encoding), meta)
            self._specs[(key, form, encoding)] = found
        return found

    def encode(self, key: str, payload: bytes, encoding: str) -> tuple[ChannelSpec, bytes, int | None]:
        """A sample as (its channel, the message data, its ``stamp`` if it has one)."""
        topic = keys.topic_of(key)
        if topic is not None and topic.kind != "query":
            try:
                msg = codec.decode(payload, encoding, topic.type, key)
            except BadPayload:
                msg = None
            if isinstance(msg, m.Image):
                image = CompressedImage(timestamp=FoxgloveTime(*divmod(msg.stamp, 1_000_000_000)), data=msg.data,
                                        format=msg.format, width=msg.width, height=msg.height)
                return self.spec(key, "image", encoding), msgspec.json.encode(image), msg.stamp
            if msg is not None:
                return (self.spec(key, "typed", encoding, topic.type.__name__), msgspec.json.encode(msg),
                        getattr(msg, "stamp", None))
        return self.spec(key, "raw", encoding), payload, None


# --------------------------------------------------------------------------- replaying


@dataclass(frozen=True)
class ChannelPlan:
    """What replay does with one channel of a file."""

    topic: str
    """The channel's topic in the file."""
    key: str
    """The bus key its messages go to ("" when refused)."""
    form: Form
    type: type[m.Message] | None
    """The icefloe message of a typed or image channel."""
    encoding: str
    """The Zenoh encoding they are published with."""
    note: str = ""
    """Why the channel is replayed as raw bytes, or refused."""
    refused: bool = False
    convert: Callable[[bytes], m.Message] | None = None
    """A ``ros2`` channel's message data to the icefloe message (ValueError naming what is wrong)."""


def bus_key(topic: str, robot: str | None = None) -> str:
    """The bus key of a channel's topic: an icefloe key as it is (under ``robot`` if given); another
    tool's topic (``/odom``) without its slashes, under ``icefloe/<robot>/`` if ``robot`` is given.

    Raises BadRecording for a topic that cannot be a key (wildcards, empty chunks).
    """
    if topic.startswith(keys.PREFIX + "/"):
        try:
            old, name = keys.split(topic)
            return keys.key(robot or old, name)
        except ValueError:
            pass
    name = topic.strip("/")
    if not name or any(c in name for c in "*$?#") or "//" in name:
        raise BadRecording(f"topic {topic!r} cannot be a Zenoh key (empty chunk or wildcard)")
    key = keys.key(robot, name) if robot else name
    try:
        zenoh.KeyExpr(key)
    except zenoh.ZError:
        raise BadRecording(f"topic {topic!r} cannot be a Zenoh key") from None
    return key


def plan(topic: str, schema_name: str, schema_encoding: str, message_encoding: str, metadata: dict[str, str],
         robot: str | None = None) -> ChannelPlan:
    """How to replay a channel, from its records in the file."""
    try:
        key = bus_key(topic, robot)
    except BadRecording as exc:
        return ChannelPlan(topic, "", "raw", None, "", note=str(exc), refused=True)
    encoding = metadata.get(ENCODING_META, "")
    if message_encoding == "json" and schema_encoding == JSONSCHEMA:
        if schema_name.startswith(SCHEMA_PREFIX):
            type_ = message_types().get(schema_name.removeprefix(SCHEMA_PREFIX))
            if type_ is not None:
                return ChannelPlan(topic, key, "typed", type_, encoding or codec.MSGPACK)
            note = f"{schema_name} is not a message of this icefloe: replayed as its JSON"
            return ChannelPlan(topic, key, "raw", None, codec.JSON, note=note)
        if schema_name == IMAGE_SCHEMA and encoding:  # ours: it has width and height
            return ChannelPlan(topic, key, "image", m.Image, encoding)
    if encoding:  # our raw channel: the bytes and encoding as they were on the bus
        return ChannelPlan(topic, key, "raw", None, encoding)
    note = (f"unknown schema {schema_name or '(none)'} ({schema_encoding or 'no schema encoding'}, "
            f"{message_encoding or 'no message encoding'}): replayed as raw bytes")
    return ChannelPlan(topic, key, "raw", None, zenoh_encoding_of(message_encoding, schema_name), note=note)


def decode(channel: ChannelPlan, data: bytes) -> m.Message | None:
    """The icefloe message of one MCAP message (None for raw channels); BadRecording if it does not decode."""
    try:
        if channel.form == "typed":
            assert channel.type is not None
            return msgspec.json.decode(data, type=channel.type)
        if channel.form == "image":
            image = msgspec.json.decode(data, type=CompressedImage)
            stamp = image.timestamp.sec * 1_000_000_000 + image.timestamp.nsec
            return m.Image(stamp=stamp, width=image.width, height=image.height, data=image.data,
                           format=image.format)  # type: ignore[arg-type]
        if channel.form == "ros2":
            assert channel.convert is not None
            return channel.convert(data)
    except (msgspec.DecodeError, msgspec.ValidationError, ValueError) as exc:
        raise BadRecording(f"{channel.topic}: a message does not decode: {exc}") from None
    return None


def payload(channel: ChannelPlan, data: bytes) -> bytes:
    """The bytes to publish for one MCAP message, in ``channel.encoding``."""
    if channel.form == "raw":
        return data
    message = decode(channel, data)
    assert message is not None
    base = channel.encoding.split(";", 1)[0].strip()
    return codec.encode(message) if base not in (codec.JSON, "text/json") else codec.encode_json(message)
