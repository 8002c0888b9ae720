"""Metric tables for the terminal that stay readable in a narrow (80-column) window.

Rows of metrics (one per operator, group or policy) are laid out as usual, one row per line, when every word
of every header and cell fits the console; rich would otherwise cut the headers to ``Ope… Suc…``. When they do
not fit (``surrol-data assess`` has 14 columns), the table is turned on its side: one line per metric, one
column per row, so the metric names stay whole and the values can still be compared across a line.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from rich import box
from rich.console import Console
from rich.table import Table
from rich.text import Text

from surrol_data.evaluation.report import Column

_UNCONSTRAINED = 100_000


def _cell(value, column: Column) -> Text:
    """The cell as plain text (never markup: a name may hold brackets); "—" for a missing or non-finite value."""
    if value is None or (isinstance(value, (float, np.floating)) and not math.isfinite(value)):
        return Text("—")
    return Text(column.fmt(value))


def terminal_table(console: Console, rows: Sequence[Mapping], columns: Sequence[Column],
                   title: str | None = None) -> Table:
    """``rows`` under ``columns`` (the first column names the row) as a rich table that fits ``console``:
    the usual layout when no word has to be cut, else transposed (a line per column of ``columns``)."""
    cells = [[_cell(row.get(c.key), c) for c in columns] for row in rows]
    wide = Table(title=title, box=box.SIMPLE_HEAD, collapse_padding=True, pad_edge=False)
    for i, column in enumerate(columns):
        wide.add_column(Text(column.header), justify="left" if i == 0 else "right", overflow="fold")
    for line in cells:
        wide.add_row(*line)
    # measured unconstrained: at the console's width rich reports the squeezed widths, not the longest words
    if console.measure(wide, options=console.options.update_width(_UNCONSTRAINED)).minimum <= console.width:
        return wide
    tall = Table(title=title, box=box.SIMPLE_HEAD, collapse_padding=True, pad_edge=False)
    tall.add_column(Text(columns[0].header), no_wrap=True)
    for line in cells:
        tall.add_column(line[0], justify="right", overflow="fold")
    for j, column in enumerate(columns[1:], start=1):
        tall.add_row(Text(column.header), *(line[j] for line in cells))
    return tall
