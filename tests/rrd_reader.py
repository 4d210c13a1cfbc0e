"""Reads logged archetype columns back from an .rrd with rerun's chunk reader (tests only)."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np
import rerun.chunk as rc


def read_columns(path: Path, entity: str) -> dict[int, dict[str, list]]:
    """{frame sequence: {"Archetype:component": value}} for one entity path ("/world/...")."""
    out: dict[int, dict[str, list]] = defaultdict(dict)
    for chunk in rc.RrdReader(str(path)).stream():
        batch = chunk.to_record_batch()
        if batch.schema.metadata.get(b"rerun:entity_path", b"").decode() != entity:
            continue
        if "frame" not in batch.schema.names:
            continue
        frames = batch.column("frame").to_pylist()
        for name in batch.schema.names:
            if ":" not in name:
                continue
            for frame, value in zip(frames, batch.column(name).to_pylist(), strict=True):
                if value is not None:
                    out[frame][name] = value
    return dict(out)


def as_array(value: list) -> np.ndarray:
    return np.asarray(value, dtype=np.float64)


def entity_paths(path: Path) -> set[str]:
    """Every entity path ("/world/...") the recording logs something at."""
    return {
        chunk.to_record_batch().schema.metadata.get(b"rerun:entity_path", b"").decode()
        for chunk in rc.RrdReader(str(path)).stream()
    }
