"""Generate ``schemas/json/<Message>.json``: one JSON Schema per message, for other languages.

Run ``icefloe schemas`` after changing ``messages.py``; a test fails while the
checked-in files are stale (``icefloe schemas --check``).

The field docstrings of ``messages.py`` become each property's ``description``,
and each schema names the keys that carry its message (``x-icefloe-keys``) and the
msgspec that wrote it (``$comment``): msgspec's releases write schemas differently
(0.23 did), so the checked-in files are made with the lock's msgspec, and a check
that fails says which msgspec made them.
"""

from __future__ import annotations

import ast
import contextlib
import functools
import inspect
import itertools
import json
from pathlib import Path
from typing import Any

import msgspec

from . import keys, messages

JSON_DIR = Path(__file__).resolve().parent / "json"
MADE_BY = f"made by icefloe schemas with msgspec {msgspec.__version__}"
"""Every schema's ``$comment``."""


def message_types() -> list[type[messages.Message]]:
    """Every concrete message Struct in messages.py, in source order (not the bases
    `Message` and `Command`)."""
    return [
        obj for obj in vars(messages).values()
        if isinstance(obj, type) and issubclass(obj, messages.Message)
        and obj not in (messages.Message, messages.Command)
    ]


@functools.cache
def field_docs() -> dict[tuple[str, str], str]:
    """(class, field) -> the string literal written under the field in messages.py."""
    tree = ast.parse(inspect.getsource(messages))
    docs: dict[tuple[str, str], str] = {}
    for cls in (n for n in tree.body if isinstance(n, ast.ClassDef)):
        body = cls.body
        for node, nxt in itertools.pairwise(body):
            if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
                    and isinstance(nxt, ast.Expr) and isinstance(nxt.value, ast.Constant)
                    and isinstance(nxt.value.value, str)):
                docs[(cls.name, node.target.id)] = inspect.cleandoc(nxt.value.value)
    return docs


_BOUNDS = ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum")


def _whole_bounds(node: Any) -> Any:
    """``node`` with each whole-number bound written as an integer (``10.0`` -> ``10``).

    Why: typing caches ``Annotated[float, Meta(le=10)]``, and ``Meta(le=10.0)`` is equal to it, so
    whichever module spelled it first decides what msgspec sees: a config field could change a
    message's schema. Both mean the same bound; the files must not depend on import order.
    """
    if isinstance(node, dict):
        return {k: (int(v) if k in _BOUNDS and isinstance(v, float) and v.is_integer() else _whole_bounds(v))
                for k, v in node.items()}
    if isinstance(node, list):
        return [_whole_bounds(v) for v in node]
    return node


def schemas() -> dict[str, str]:
    """File name -> JSON text, for every message."""
    docs = field_docs()
    carried: dict[str, list[str]] = {}
    for topic in keys.TABLE.values():
        carried.setdefault(topic.type.__name__, []).append(f"icefloe/<robot>/{topic.name}")
        if topic.reply is not None:
            carried.setdefault(topic.reply.__name__, []).append(f"icefloe/<robot>/{topic.name} (reply)")
    out = {}
    for t in message_types():
        schema = _whole_bounds(msgspec.json.schema(t))
        for name, definition in schema.get("$defs", {}).items():
            bases = [c.__name__ for c in getattr(messages, name).__mro__]  # fields a base declares
            for field, prop in definition.get("properties", {}).items():
                doc = next((docs[b, field] for b in bases if (b, field) in docs), None)
                if doc and "description" not in prop:
                    prop["description"] = doc
        schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
        schema["$comment"] = MADE_BY
        schema["title"] = t.__name__
        schema["x-icefloe-keys"] = carried.get(t.__name__, [])
        out[f"{t.__name__}.json"] = json.dumps(schema, indent=2, sort_keys=True) + "\n"
    return out


def stale(directory: Path = JSON_DIR) -> list[str]:
    """Files in ``directory`` that differ from what `schemas` generates (or are missing or extra)."""
    want = schemas()
    have = {p.name for p in directory.glob("*.json")} if directory.exists() else set()
    wrong = [n for n, text in want.items() if not (directory / n).exists()
             or (directory / n).read_text() != text]
    return sorted(wrong + [n for n in have - set(want)])


def made_by(directory: Path = JSON_DIR) -> set[str]:
    """What the files in ``directory`` say made them (their ``$comment``; "unknown" if none)."""
    out = set()
    for path in directory.glob("*.json"):
        comment = "unknown"
        with contextlib.suppress(ValueError, AttributeError):
            comment = json.loads(path.read_text()).get("$comment", "unknown")
        out.add(comment)
    return out


def write(directory: Path = JSON_DIR) -> list[str]:
    """Regenerate the folder; returns the names written."""
    directory.mkdir(parents=True, exist_ok=True)
    want = schemas()
    for p in directory.glob("*.json"):
        if p.name not in want:
            p.unlink()
    for name, text in want.items():
        (directory / name).write_text(text)
    return sorted(want)
