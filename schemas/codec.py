"""Encoding and decoding of bus payloads.

We publish MessagePack maps (Zenoh encoding ``application/msgpack``). We decode
by the sample's encoding:

* ``application/msgpack``: MessagePack.
* ``application/json`` (or ``text/json``): JSON with the same fields.
* ``zenoh/bytes`` (what Zenoh tools send when no encoding is given): JSON if the
  payload starts with ``{``, else MessagePack, so ``z_put -p '{"v": 0.1}'`` works.
* Anything else is rejected.

An empty payload means an empty map, so ``cmd/stop`` needs no payload at all.
"""

from __future__ import annotations

from typing import TypeVar

import msgspec

from ..errors import BadPayload
from .messages import Message

MSGPACK = "application/msgpack"
JSON = "application/json"
ACCEPTED = (MSGPACK, JSON, "text/json", "zenoh/bytes", "")

T = TypeVar("T", bound=Message)

_msgpack_encoder = msgspec.msgpack.Encoder()
_msgpack_decoders: dict[type, msgspec.msgpack.Decoder] = {}
_json_decoders: dict[type, msgspec.json.Decoder] = {}


def encode(message: Message) -> bytes:
    """MessagePack bytes of a message (a map keyed by field names)."""
    return _msgpack_encoder.encode(message)


def encode_json(message: Message) -> bytes:
    """JSON bytes of a message (for logs, the CLI and other languages' tests)."""
    return msgspec.json.encode(message)


KIND_NAMES = {"msgpack": "MessagePack", "json": "JSON"}


def _kind(encoding: str, payload: bytes) -> str:
    base = encoding.split(";", 1)[0].strip()
    if base == MSGPACK:
        return "msgpack"
    if base in (JSON, "text/json"):
        return "json"
    if base in ("zenoh/bytes", ""):
        return "json" if payload.lstrip()[:1] == b"{" else "msgpack"
    raise BadPayload(f"unknown encoding {base!r} (send application/msgpack or application/json)")


def decode(payload: bytes, encoding: str, type_: type[T], key: str = "payload") -> T:
    """Decode a payload into ``type_``; raise `BadPayload` naming ``key`` and the field."""
    try:
        kind = _kind(encoding, payload)
    except BadPayload as exc:
        raise BadPayload(f"{key}: {exc}") from None
    if not payload.strip():
        payload = b"{}" if kind == "json" else b"\x80"
    try:
        if kind == "json":
            decoder = _json_decoders.get(type_)
            if decoder is None:
                decoder = _json_decoders[type_] = msgspec.json.Decoder(type_)
        else:
            decoder = _msgpack_decoders.get(type_)
            if decoder is None:
                decoder = _msgpack_decoders[type_] = msgspec.msgpack.Decoder(type_)
        return decoder.decode(payload)
    except msgspec.ValidationError as exc:  # well-formed, but a field is missing, of a wrong type or out of range
        raise BadPayload(f"{key}: {exc}") from None
    except (msgspec.DecodeError, UnicodeDecodeError) as exc:
        # Not well-formed: truncated, garbage, or a string that is not UTF-8 (msgspec < 0.23 raised
        # UnicodeDecodeError for that, 0.23 a DecodeError). Our words say which; the library's, in
        # parentheses, say where, and are not read by anything.
        raise BadPayload(f"{key}: not valid {KIND_NAMES[kind]} ({exc})") from None


def to_builtins(payload: bytes, encoding: str) -> object:
    """Decode any payload to plain Python objects (for ``icefloe echo`` on unknown keys)."""
    kind = _kind(encoding, payload)
    if kind == "json":
        return msgspec.json.decode(payload)
    return msgspec.msgpack.decode(payload)
