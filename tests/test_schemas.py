"""The contract: key table, codec, and the generated JSON Schemas (pure, no bus)."""

from __future__ import annotations

import json
import math

import msgspec
import pytest

from icefloe.errors import BadPayload
from icefloe.schemas import codec, export, keys
from icefloe.schemas import messages as m


def test_json_schemas_are_current() -> None:
    stale = export.stale()
    assert stale == [], f"run `icefloe schemas`: stale {stale}"


def test_a_bound_is_written_the_same_however_a_module_spelled_it_first() -> None:
    # typing caches Annotated[float, Meta(le=10)] and Meta(le=10.0) as one: a config field
    # spelled 10.0 once made LabStop's schema say 10.0 when it was imported first.
    spelled = {"maximum": 10.0, "items": [{"exclusiveMinimum": 0.0, "maximum": 0.5}], "default": 1.0}
    assert export._whole_bounds(spelled) == {
        "maximum": 10, "items": [{"exclusiveMinimum": 0, "maximum": 0.5}], "default": 1.0}
    assert isinstance(export._whole_bounds(spelled)["maximum"], int)


def test_every_message_has_a_schema_naming_its_keys() -> None:
    names = {t.__name__ for t in export.message_types()}
    for topic in keys.TABLE.values():
        assert topic.type.__name__ in names
        schema = json.loads((export.JSON_DIR / f"{topic.type.__name__}.json").read_text())
        assert f"icefloe/<robot>/{topic.name}" in schema["x-icefloe-keys"]


def test_field_docstrings_reach_the_schema() -> None:
    schema = json.loads((export.JSON_DIR / "Twist.json").read_text())
    assert "m/s" in schema["$defs"]["Twist"]["properties"]["v"]["description"]


def test_keys() -> None:
    assert keys.key("penguin1", keys.TWIST) == "icefloe/penguin1/cmd/twist"
    assert keys.split("icefloe/sim/odom/pose") == ("sim", "odom/pose")
    assert keys.topic_of("icefloe/sim/odom/pose") is keys.ODOM_POSE
    assert keys.topic_of("icefloe/sim/nope") is None
    assert keys.topic_of("other/sim/odom/pose") is None
    with pytest.raises(ValueError, match="not an icefloe key"):
        keys.split("icefloe/sim")


def test_roundtrip_msgpack_is_a_map_with_field_names() -> None:
    lm = m.Landmarks(stamp=5, landmarks=[m.Landmark(id=3, range=1.5, bearing=-0.2, corners=[1.0] * 8)])
    raw = codec.encode(lm)
    assert msgspec.msgpack.decode(raw)["landmarks"][0]["id"] == 3
    assert codec.decode(raw, codec.MSGPACK, m.Landmarks) == lm


def test_json_input_with_the_same_fields() -> None:
    assert codec.decode(b'{"v": 0.1, "w": -0.5}', "application/json", m.Twist) == m.Twist(v=0.1, w=-0.5)
    # Zenoh tools without an encoding send zenoh/bytes: JSON is recognised by its brace.
    assert codec.decode(b' {"left": 1, "right": 2}', "zenoh/bytes", m.WheelSpeeds).right == 2.0
    assert codec.decode(b"", "zenoh/bytes", m.Stop) == m.Stop()


BAD = [
    (b'{"v": "fast", "w": 0}', "application/json", "$.v"),
    (b'{"v": 1}', "application/json", "`w`"),
    (b'{"v": 1, "w": 0, "x": 2}', "application/json", "`x`"),
    (codec.encode(m.Twist(v=1.0, w=2.0))[:-4], "application/msgpack", "not valid MessagePack"),  # truncated
    (msgspec.msgpack.encode({"v": math.nan, "w": 0.0}), "application/msgpack", "`v` must be a finite"),
    (msgspec.msgpack.encode({"v": math.inf, "w": 0.0}), "application/msgpack", "`v` must be a finite"),
    (b'{"v": 1, "w": 0}', "text/plain", "unknown encoding 'text/plain'"),
    (b"\xc1", "application/msgpack", "not valid MessagePack"),
]


@pytest.mark.parametrize(("payload", "encoding", "names"), BAD)
def test_bad_payloads_name_the_key_and_the_field(payload: bytes, encoding: str, names: str) -> None:
    with pytest.raises(BadPayload) as err:
        codec.decode(payload, encoding, m.Twist, "icefloe/sim/cmd/twist")
    assert str(err.value).startswith("icefloe/sim/cmd/twist: ")
    assert names in str(err.value)


def test_messages_are_frozen_and_reject_nan_on_construction() -> None:
    t = m.Twist(v=1.0, w=0.0)
    with pytest.raises(AttributeError):
        t.v = 2.0  # type: ignore[misc]
    with pytest.raises(ValueError, match="`w` must be a finite"):
        m.Twist(v=0.0, w=math.nan)


def test_a_string_that_is_not_utf8_is_a_bad_payload_not_a_crash() -> None:
    """Our words, whatever msgspec says: msgspec < 0.23 raised UnicodeDecodeError for such a string,
    0.23 a DecodeError worded its own way; both are a payload that is not valid MessagePack."""
    payload = b"\x81\xa4text\xa2\xff\xfe"  # {"text": <2 bytes that are not UTF-8>}
    with pytest.raises(BadPayload, match=r"^icefloe/sim/oled/text: not valid MessagePack "):
        codec.decode(payload, codec.MSGPACK, m.OledText, "icefloe/sim/oled/text")
    with pytest.raises(BadPayload, match=r"^icefloe/sim/oled/text: not valid JSON "):
        codec.decode(b'{"text": "\xff"}', codec.JSON, m.OledText, "icefloe/sim/oled/text")


@pytest.mark.parametrize("raised", [UnicodeDecodeError("utf-8", b"\xff", 0, 1, "invalid start byte"),
                                    msgspec.DecodeError("a text of the library's own")])
def test_either_error_kind_of_a_bad_string_is_a_bad_payload(raised: Exception, monkeypatch: pytest.MonkeyPatch) -> None:
    """Both kinds msgspec has raised for a string that is not UTF-8, whatever their words."""

    class Decoder:
        def __init__(self, type_: type) -> None: ...

        def decode(self, payload: bytes) -> None:
            raise raised

    monkeypatch.setattr(codec, "_msgpack_decoders", {})
    monkeypatch.setattr(codec.msgspec.msgpack, "Decoder", Decoder)
    with pytest.raises(BadPayload, match=r"^icefloe/sim/oled/text: not valid MessagePack "):
        codec.decode(b"\x81", codec.MSGPACK, m.OledText, "icefloe/sim/oled/text")
