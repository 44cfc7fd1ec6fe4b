"""Read a recording (``--save FILE.rrd``) back into plain Python, with Rerun's own reader.

    columns = read_rrd("run.rrd")
    columns["/robots/sim/map/odom"]["Arrows2D:origins"]   # one list of [x, y] per logged row
    columns["/robots/sim/map/odom"]["stamp"]              # ns since the epoch, per row

The tests and ``bench/viz_lag.py`` use it; it is also a quick way to get a run into numpy.
Each entity maps to its columns (``"<Archetype>:<field>"``, the timelines ``stamp``
and ``log_time``), rows sorted by ``log_time``.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import Any

import pyarrow as pa
from rerun.chunk import RrdReader

Columns = dict[str, list[Any]]


def read_rrd(path: str | Path) -> dict[str, Columns]:
    """Every temporal (non-static) row of the first recording in ``path``, by entity path."""
    entities: dict[str, Columns] = {}
    rows: dict[str, int] = defaultdict(int)
    for chunk in RrdReader(path).stream():
        if chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        columns = entities.setdefault(chunk.entity_path, {})
        before = rows[chunk.entity_path]
        for name, column in zip(batch.schema.names, batch.columns, strict=True):
            if name.startswith("rerun.controls"):
                continue
            if pa.types.is_timestamp(column.type):
                column = column.cast(pa.int64())  # ns as int: Python datetimes stop at microseconds
            # A column this entity's earlier chunks did not have is None in their rows.
            columns.setdefault(name, [None] * before).extend(column.to_pylist())
        rows[chunk.entity_path] = before + batch.num_rows
        for values in columns.values():  # and the other way round
            values.extend([None] * (rows[chunk.entity_path] - len(values)))
    return {path: _sorted(cols) for path, cols in entities.items()}


def read_static(path: str | Path) -> dict[str, Columns]:
    """The static rows (e.g. the landmark map) of the first recording in ``path``, by entity path."""
    entities: dict[str, Columns] = defaultdict(lambda: defaultdict(list))
    for chunk in RrdReader(path).stream():
        if chunk.is_static:
            batch = chunk.to_record_batch()
            for name, column in zip(batch.schema.names, batch.columns, strict=True):
                if not name.startswith("rerun.controls"):
                    entities[chunk.entity_path][name].extend(column.to_pylist())
    return {path: dict(cols) for path, cols in entities.items()}


def _sorted(columns: Columns) -> Columns:
    """Rows in the order they were logged (chunks can be stored in any order)."""
    log_time = columns.get("log_time", [])
    order = sorted(range(len(log_time)), key=log_time.__getitem__)
    return {name: [values[i] for i in order] for name, values in columns.items()}
