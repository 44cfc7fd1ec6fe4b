"""The messages of one key in a recording as plain data (dicts), whatever its channel's form: for
tools that read fields by name (``icefloe score``), on keys of the key table or not."""

from __future__ import annotations

from collections.abc import Iterator

import msgspec

from ..errors import BadRecording
from ..schemas import codec, keys
from .reader import Bag, Entry


def plain(entry: Entry) -> object:
    """One message as plain Python data; BadRecording naming the channel if it does not decode."""
    try:
        if entry.channel.form == "raw":
            return codec.to_builtins(entry.data, entry.channel.encoding)
        return msgspec.json.decode(entry.data)  # typed and image channels hold JSON
    except Exception as exc:  # msgspec.DecodeError, BadPayload (an unknown encoding), UnicodeDecodeError
        raise BadRecording(f"{entry.channel.topic}: a message does not decode: {exc}") from None


def find_key(bag: Bag, name: str) -> str:
    """The recording's bus key for ``name``: a full key as it is, or a key-table name (``loc/pose``)
    of the one robot the recording has it for; BadRecording saying what there is otherwise."""
    recorded = sorted({c.key for c in bag.channels() if c.key})
    if name.startswith(keys.PREFIX + "/"):
        if name in recorded:
            return name
        found = []
    else:
        found = [k for k in recorded if k.startswith(keys.PREFIX + "/") and keys.split(k)[1] == name]
        if len(found) == 1:
            return found[0]
    where = bag.files[0].path
    if found:
        raise BadRecording(f"{where}: {name} is recorded for several robots ({', '.join(found)}): "
                           "give the full key")
    listed = ", ".join(recorded[:12]) + (" ..." if len(recorded) > 12 else "") or "nothing"
    raise BadRecording(f"{where}: no messages on {name} (it has {listed})")


def entries_on(bag: Bag, key: str) -> Iterator[Entry]:
    """Every message on ``key`` (a full bus key), in the file's order (`plain` decodes one)."""
    return (entry for entry in bag.entries() if entry.channel.key == key)
