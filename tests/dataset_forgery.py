"""Shared by the integrity and signing tests: edits a forger (or an older recorder) leaves in a dataset."""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow.parquet as pq


def drop_seals(root: Path) -> None:
    """Remove every seal: the episodes' ``seal/*`` columns and the sidecar's ``seals`` entry (a dataset recorded before
    seals existed looks like this; so does one whose forger dropped them)."""
    for path in sorted((root / "meta" / "episodes").rglob("*.parquet")):
        table = pq.read_table(path)
        pq.write_table(table.drop_columns([c for c in table.column_names if c.startswith("seal/")]), path)
    side_path = root / "meta" / "surrol_data.json"
    side = json.loads(side_path.read_text())
    side.pop("seals")
    side_path.write_text(json.dumps(side))
