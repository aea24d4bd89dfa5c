"""Log rows as CSV files: written with the union of their columns, read back with numbers as numbers.

A path ending in ``.gz`` is gzip-compressed. The combined results of an experiment are shipped that way
(:func:`results_file`); the compression is deterministic (no time stamp in the header), so the same rows give
the same bytes.

Floats are stored to :data:`SIGNIFICANT_DIGITS` significant digits (:func:`stored_rows`): a relative rounding
below the tolerance within which a re-run is compared with the shipped rows (tests/test_regeneration.py), and it
makes the shipped CSVs markedly smaller (docs/results.md, "Stored digits of the shipped rows"). A column of
seconds (:func:`is_timing_column`) is stored to :data:`TIMING_DIGITS` digits. The grid hands experiments their
rows already rounded (:func:`vdtutorial.runner.grid.run_grid`), so what an experiment derives from its rows is
what :func:`read_rows` gives back from its CSV.

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


#: Significant digits of a stored float (module docstring, "Floats are stored to").
SIGNIFICANT_DIGITS = 8
#: Significant digits of a column of seconds (:func:`is_timing_column`).
TIMING_DIGITS = 3
#: The endings of a column's name that say it holds seconds.
TIMING_SUFFIXES = ("_s", "_time")


def is_timing_column(name: str) -> bool:
    """Whether the column ``name`` holds seconds, by its name's ending (:data:`TIMING_SUFFIXES`), as TRPO's
    ``collect_s``, ``update_s`` and ``wall_time`` do. Seconds measure the machine's load, which moves them by far
    more than a part in a thousand from one run to the next: no result is derived from them, and the regeneration
    tests leave them out, so they are stored to :data:`TIMING_DIGITS` digits."""
    return name.endswith(TIMING_SUFFIXES)


def stored_value(value, digits: int = SIGNIFICANT_DIGITS):
    """``value`` as a CSV stores it: a float rounded to ``digits`` significant digits, anything else as it is.
    Rounding again changes nothing."""
    return float(f"{value:.{digits}g}") if isinstance(value, float) else value


def stored_rows(rows: list[dict]) -> list[dict]:
    """``rows`` as :func:`write_csv` stores them and :func:`read_rows` reads them back (:func:`stored_value`;
    columns of seconds to :data:`TIMING_DIGITS` digits)."""
    stored = []
    for row in rows:
        digits = {key: TIMING_DIGITS if is_timing_column(key) else SIGNIFICANT_DIGITS for key in row}
        stored.append({key: stored_value(value, digits[key]) for key, value in row.items()})
    return stored


def write_csv(path: Path, rows: list[dict]) -> Path:
    """Rows with possibly different keys -> one CSV with the union of the columns (blank where absent), floats
    rounded (:func:`stored_rows`); gzip-compressed when ``path`` ends in ``.gz``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    columns = list(dict.fromkeys(key for row in rows for key in row))
    text = io.StringIO(newline="")
    writer = csv.DictWriter(text, fieldnames=columns, restval="")
    writer.writeheader()
    writer.writerows(stored_rows(rows))
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
