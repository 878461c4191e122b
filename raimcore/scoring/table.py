"""A small column-oriented result table (no pandas dependency; ``to_pandas`` if installed)."""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np

__all__ = ["ResultTable"]


class ResultTable:
    """Per-epoch columns (each shape ``(E,)``) and per-satellite arrays (each ``(E, S)``).

    Columns keep their order of insertion. ``table["hpe_after_m"]`` returns a column;
    ``table.sat("isolation", "G10")`` one satellite's series.
    """

    def __init__(self, columns: Mapping[str, np.ndarray], per_sat: Mapping[str, np.ndarray]
                 | None = None, sat_names=()):
        self.columns = {k: np.asarray(v) for k, v in columns.items()}
        lengths = {len(v) for v in self.columns.values()}
        if len(lengths) > 1:
            raise ValueError(f"all columns must have the same length, got {sorted(lengths)}")
        self.per_sat = {k: np.asarray(v) for k, v in (per_sat or {}).items()}
        self.sat_names = tuple(sat_names)

    def __len__(self) -> int:
        return len(next(iter(self.columns.values()))) if self.columns else 0

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.columns[name]
        except KeyError:
            raise KeyError(f"no column {name!r}; columns: {', '.join(self.columns)}") from None

    def __contains__(self, name: str) -> bool:
        return name in self.columns

    @property
    def names(self) -> list[str]:
        return list(self.columns)

    def sat(self, key: str, sat_name: str) -> np.ndarray:
        """Per-satellite series ``key`` of satellite ``sat_name``."""
        return self.per_sat[key][:, self.sat_names.index(sat_name)]

    def rows(self):
        """Iterate over rows as dicts of Python scalars."""
        for i in range(len(self)):
            yield {k: _scalar(v[i]) for k, v in self.columns.items()}

    def to_csv(self, path) -> Path:
        """Write the per-epoch columns as CSV (per-satellite arrays go to ``to_json``)."""
        path = Path(path)
        with path.open("w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow(self.names)
            for row in self.rows():  # NaN became None: an empty CSV field
                writer.writerow(row.values())
        return path

    def to_dict(self) -> dict:
        return {
            "columns": {k: [_scalar(x) for x in v] for k, v in self.columns.items()},
            "sat_names": list(self.sat_names),
            "per_sat": {k: [[_scalar(x) for x in row] for row in v]
                        for k, v in self.per_sat.items()},
        }

    def to_json(self, path) -> Path:
        """Write columns and per-satellite arrays as JSON (NaN written as null)."""
        path = Path(path)
        path.write_text(json.dumps(self.to_dict(), allow_nan=False))
        return path

    def to_pandas(self):
        """The per-epoch columns as a pandas DataFrame (pandas must be installed)."""
        import pandas as pd

        return pd.DataFrame(self.columns)


def _scalar(x):
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x
