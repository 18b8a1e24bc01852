"""The results table of a design study: one CSV row per run, appended and flushed as runs
finish, read back on resume (runs identified by their parameter values); Parquet beside it
when pyarrow is importable."""
from __future__ import annotations

import csv
from pathlib import Path
from typing import Iterable

from ..errors import UsageError
from .job import QUANTITIES
from ..scene.variations import value_text


def columns(paths: Iterable[str], collect: Iterable[str]) -> list[str]:
    return ["run", *paths, "status", "error", *QUANTITIES, *collect]


class ResultsTable:
    """A CSV appended and flushed row by row.  With ``resume`` an existing table is read
    back (a row cut short by a kill is dropped) and its runs are not run again."""

    def __init__(self, path: Path, cols: list[str], n_params: int, resume: bool, force: bool):
        self.path, self.cols, self.n_params = Path(path), cols, n_params
        self.done: dict[tuple, dict] = {}
        if self.path.is_dir():
            raise UsageError(f"{self.path}: is a folder; give a file name")
        if not self.path.parent.exists():
            raise UsageError(f"{self.path}: folder {self.path.parent} does not exist")
        if self.path.exists() and resume:
            self._read()
        elif self.path.exists() and not force:
            raise UsageError(f"{self.path}: exists; pass --resume to run only its missing runs, "
                             "or --force to start the sweep over")
        fresh = not (self.path.exists() and resume)
        self.file = open(self.path, "w" if fresh else "a", newline="", encoding="utf-8")
        self.writer = csv.DictWriter(self.file, fieldnames=cols)
        if fresh:
            self.writer.writeheader()
            self.file.flush()

    def key(self, row: dict) -> tuple:
        return tuple(row[c] for c in self.cols[1:1 + self.n_params])

    def _read(self) -> None:
        with open(self.path, newline="", encoding="utf-8") as f:
            text = f.read()
        rows = list(csv.reader(text.splitlines(keepends=True)))
        if not rows or rows[0] != self.cols:
            have = rows[0] if rows else []
            raise UsageError(f"{self.path}: its columns ({', '.join(have) or 'none'}) are not this sweep's "
                             f"({', '.join(self.cols)}); resume with the same --set paths and --collect")
        kept, dropped = [], 0
        for cells in rows[1:]:
            if len(cells) != len(self.cols):
                dropped += 1  # a row cut short when the sweep was killed: run again
                continue
            row = dict(zip(self.cols, cells))
            if self.key(row) in self.done:
                dropped += 1
                continue
            self.done[self.key(row)] = row
            kept.append(cells)
        if dropped or not text.endswith("\n"):
            from ..results.trajectory import atomic_write
            atomic_write(self.path, lambda f: csv.writer(f).writerows([self.cols, *kept]), force=True)

    def append(self, row: dict) -> None:
        cells = {c: "" if row.get(c) is None else value_text(row[c]) for c in self.cols}
        self.writer.writerow(cells)
        self.file.flush()
        self.done[self.key(cells)] = cells

    def close(self) -> None:
        self.file.close()

    def rows(self) -> list[dict]:
        return list(self.done.values())


def write_parquet(csv_path: Path) -> Path | None:
    """The table as Parquet next to the CSV, when pyarrow is importable (else ``None``)."""
    try:
        import pyarrow.csv as pacsv
        import pyarrow.parquet as pq
    except ImportError:
        return None
    from ..results.trajectory import atomic_write
    table = pacsv.read_csv(csv_path)
    out = Path(csv_path).with_suffix(".parquet")
    atomic_write(out, lambda f: pq.write_table(table, f), force=True, binary=True)
    return out
