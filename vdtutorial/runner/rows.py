"""Log rows as CSV files: written with the union of their columns, read back with numbers as numbers.

A path ending in ``.gz`` is gzip-compressed (about 3x smaller for TRPO logs, whose floats are written
with all their digits so that a re-run can be compared with them exactly). The combined results of an
experiment are shipped that way (:func:`results_file`); the compression is deterministic (no time stamp
in the header), so the same rows give the same bytes.

Taught in chapter 07.
"""
from __future__ import annotations

import csv
import gzip
import io
from pathlib import Path


def results_file(folder: str | Path, name: str) -> Path:
    """Where the combined rows of experiment ``name`` live in its results ``folder``: ``NAME.csv.gz``."""
    return Path(folder) / f"{name}.csv.gz"


def write_csv(path: Path, rows: list[dict]) -> Path:
    """Rows with possibly different keys -> one CSV with the union of the columns (blank where absent);
    gzip-compressed when ``path`` ends in ``.gz``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    columns = list(dict.fromkeys(key for row in rows for key in row))
    text = io.StringIO(newline="")
    writer = csv.DictWriter(text, fieldnames=columns, restval="")
    writer.writeheader()
    writer.writerows(rows)
    data = text.getvalue().encode()
    if path.suffix == ".gz":
        buffer = io.BytesIO()
        with gzip.GzipFile(filename="", mode="wb", fileobj=buffer, mtime=0) as f:
            f.write(data)
        data = buffer.getvalue()
    path.write_bytes(data)
    return path


def _parse(value: str):
    if value == "":
        return None
    for kind in (int, float):
        try:
            return kind(value)
        except ValueError:
            pass
    return value


def read_rows(path: str | Path) -> list[dict]:
    """Read a CSV written by :func:`write_csv` (plain or ``.gz``) back into rows (numbers as numbers,
    blanks as None)."""
    path = Path(path)
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt", newline="") as f:
        return [{k: _parse(v) for k, v in row.items()} for row in csv.DictReader(f)]
