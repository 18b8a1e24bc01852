"""The results table of a design study: a record of runs, not a text file appended to.

* Every row is written whole, in one ``write`` of one line to a file opened for appending,
  and carries a checksum of its cells (column ``check``, CRC-32).  On ``resume`` a row whose
  checksum does not match its cells (cut short by a kill, a full disk, a file-size limit, or
  edited) is dropped, reported, and its run is run again.
* The table is locked (:mod:`filelock`, an OS lock on ``TABLE.lock``) for the length of the
  sweep: a second sweep or resume on the same table is refused, not interleaved.
* A table at a symbolic link is refused (pcmm never writes through a link).
* Text cells go through the same neutralisation as ``pcmm run --csv``
  (:func:`pcmm.results.trajectory.spreadsheet_text`): a cell never starts a spreadsheet formula.
* Every operating-system failure is an :class:`~pcmm.errors.OutputError` naming the table.
* **What a row written promises**: a row is in the table (the operating system's file cache)
  when the sweep counts it, so a kill of the sweep, ``kill -9`` included, loses no counted row.
  The table is forced to the disk (``fsync``) at most once every :data:`SYNC_EVERY` seconds and
  when the sweep ends, not at every row: a crash of the machine or a power cut loses at most the
  rows of the last :data:`SYNC_EVERY` seconds, and a row it cuts short fails its checksum and is
  run again on resume.

Runs are identified by their parameter values' cell text; Parquet is written beside the CSV
when pyarrow is importable.
"""
from __future__ import annotations

import csv
import errno
import io
import os
import time
import zlib
from pathlib import Path
from typing import Iterable

from ..errors import OutputError, UsageError
from ..results.trajectory import spreadsheet_text
from ..scene.variations import value_text
from .job import QUANTITIES

#: statuses of runs that did not end by themselves: kept, and run again only with retry_failed
FAILED_RUN = ("crashed", "timeout")
CHECK = "check"
#: the table is forced to the disk at most this often, s (and when the sweep ends)
SYNC_EVERY = 1.0
_now = time.monotonic  # the clock of the syncs (a test's to replace)


def columns(paths: Iterable[str], collect: Iterable[str]) -> list[str]:
    return ["run", *paths, "status", "error", *QUANTITIES, *collect, CHECK]


def cell(value) -> str:
    """One value as its table cell: numbers as their exact text (:func:`value_text`), text
    neutralised against formula injection exactly as ``pcmm run --csv`` does."""
    if value is None:
        return ""
    if isinstance(value, str):
        return spreadsheet_text(value)
    text = value_text(value)
    try:
        float(text)  # a number's own text (a leading minus sign is a number's, not a formula's)
        return text
    except ValueError:
        return spreadsheet_text(text)


def checksum(cells: Iterable[str]) -> str:
    """The CRC-32 of a row's cells (every column but ``check``), as 8 hex digits."""
    return f"{zlib.crc32(chr(31).join(cells).encode('utf-8')):08x}"


def _line(cells: list[str]) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow(cells)
    return buf.getvalue()


def _link_error(path: Path) -> OutputError:
    target = os.readlink(path) if path.is_symlink() else "?"
    return OutputError(path, OSError(errno.ELOOP, f"is a symbolic link (to {target}); pcmm does not write a "
                                     "results table through a link: give the file's own path"))


class ResultsTable:
    """The rows of a sweep's table.  Opened, it holds the table's lock until :meth:`close`.

    ``resume`` reads the table back (rows failing their checksum are dropped and listed in
    :attr:`dropped`); ``retry_failed`` also drops the rows of crashed and timed-out runs so
    that they run again."""

    def __init__(self, path: Path, cols: list[str], n_params: int, resume: bool, force: bool,
                 retry_failed: bool = False):
        self.path, self.cols, self.n_params = Path(path), list(cols), n_params
        self.header = [spreadsheet_text(c) for c in self.cols]
        self.done: dict[tuple, dict] = {}
        self.dropped: list[str] = []  # why each dropped row was dropped
        self.retried = 0
        self.fd = None
        self.lock = None
        self.synced = _now()  # when the table was last forced to the disk
        self.syncs = 0
        if self.path.is_symlink():
            raise _link_error(self.path)
        if self.path.is_dir():
            raise UsageError(f"{self.path}: is a folder; give a file name")
        if not self.path.parent.exists():
            raise UsageError(f"{self.path}: folder {self.path.parent} does not exist")
        if self.path.exists() and not resume and not force:
            raise UsageError(f"{self.path}: exists; pass --resume to run only its missing runs, "
                             "or --force to start the sweep over")
        self._lock()
        try:
            self._open(resume, retry_failed)
        except BaseException:
            self._unlock()
            raise

    # -- the lock -------------------------------------------------------------------------------
    @property
    def lock_path(self) -> Path:
        return self.path.with_name(self.path.name + ".lock")

    def _lock(self) -> None:
        import filelock
        lock_path = self.lock_path
        if lock_path.is_symlink():
            raise _link_error(lock_path)
        self.lock = filelock.FileLock(str(lock_path), timeout=0)
        try:
            self.lock.acquire()
        except filelock.Timeout:
            raise UsageError(f"{self.path}: another pcmm sweep is writing this table (it holds {lock_path}); "
                             "wait for it to finish, or give another --out") from None
        except OSError as exc:
            raise OutputError(lock_path, exc) from None

    def _unlock(self) -> None:
        if self.lock is not None:
            self.lock.release()
            self.lock = None

    # -- reading and opening --------------------------------------------------------------------
    def key(self, row: dict) -> tuple:
        """A row's identity: its parameter values' cells."""
        return tuple(row[c] for c in self.cols[1:1 + self.n_params])

    def key_of(self, values: Iterable) -> tuple:
        """The identity of a run with these parameter values (as :meth:`key` reads them back)."""
        return tuple(cell(v) for v in values)

    def _open(self, resume: bool, retry_failed: bool) -> None:
        try:
            if resume and self.path.exists():
                kept = self._read(retry_failed)
                if kept is not None:  # rows were dropped: the table is rewritten with the rows kept
                    from ..files import atomic_write
                    atomic_write(self.path, lambda f: f.write("".join(_line(c) for c in [self.header, *kept])),
                                 force=True)
                fresh = False
            else:
                fresh = True
            flags = os.O_WRONLY | os.O_CREAT | os.O_APPEND | getattr(os, "O_NOFOLLOW", 0)
            if fresh:
                flags |= os.O_TRUNC
            self.fd = os.open(self.path, flags, 0o666)
            if fresh:
                self._write(_line(self.header))
                self.sync()  # a new table's header is on the disk before its first row
        except OSError as exc:
            if exc.errno == errno.ELOOP:
                raise _link_error(self.path) from None
            raise OutputError(self.path, exc) from None

    def _from_older(self, rows: list[list[str]]) -> bool:
        """A table a pcmm with fewer quantities wrote (before ``first_impulse_magnitude``, or
        ``last_merge_t``): the same columns in the same order but for some of :data:`QUANTITIES`.  Its rows are
        read into this study's columns, those cells empty (unknown, never a number they did not
        compute), each row's checksum checked on its own cells first and written anew; the table is
        rewritten, and the warning says which columns its rows lack.  ``False`` (rows untouched) for
        any other difference."""
        old, header = rows[0], self.header
        missing = [c for c in header if c not in old]
        if not missing or [c for c in header if c in old] != old or \
                not set(missing) <= {spreadsheet_text(q) for q in QUANTITIES}:
            return False
        upgraded, whole = [header], 0
        for cells in rows[1:]:
            if len(cells) != len(old) or checksum(cells[:-1]) != cells[-1]:
                upgraded.append(cells)  # dropped below (and said there), as a cut or altered row is
                continue
            by_column = dict(zip(old, cells))
            new = [by_column.get(c, "") for c in header[:-1]]
            upgraded.append([*new, checksum(new)])
            whole += 1
        rows[:] = upgraded
        self.dropped.append(f"written before the columns {', '.join(missing)}: its {whole} rows keep "
                            "them empty (the table is rewritten with them; --force runs every row again)")
        return True

    def _read(self, retry_failed: bool):
        """Read the table back; the rows to keep if any row was dropped (else ``None``)."""
        with open(self.path, newline="", encoding="utf-8", errors="replace") as f:
            rows = list(csv.reader(f))
        upgraded = bool(rows) and rows[0] != self.header and self._from_older(rows)
        if not rows or rows[0] != self.header:
            have = rows[0] if rows else []
            raise UsageError(f"{self.path}: its columns ({', '.join(have) or 'none'}) are not this study's "
                             f"({', '.join(self.header)}); resume with the same --set paths and --collect")
        kept, changed = [], upgraded
        for n, cells in enumerate(rows[1:], start=2):
            run = cells[0] if cells else "?"
            if len(cells) != len(self.cols) or checksum(cells[:-1]) != cells[-1]:
                self.dropped.append(f"line {n} (run {run}): cut short or altered (its checksum does not match); "
                                    "dropped, run again")
                changed = True
                continue
            row = dict(zip(self.cols, cells))
            if self.key(row) in self.done:
                self.dropped.append(f"line {n} (run {run}): a second row of the same run; dropped")
                changed = True
                continue
            if retry_failed and row["status"] in FAILED_RUN:
                self.retried += 1
                changed = True
                continue
            self.done[self.key(row)] = row
            kept.append(cells)
        return kept if changed else None

    # -- writing --------------------------------------------------------------------------------
    def _write(self, text: str) -> None:
        data = text.encode("utf-8")
        try:
            n = os.write(self.fd, data)
            if n != len(data):  # a short write: the disk filled (the checksum marks the row on resume)
                os.write(self.fd, data[n:])
        except OSError as exc:
            raise OutputError(self.path, exc) from None

    def append(self, row: dict) -> dict:
        """Write one run's row, whole, with its checksum; the row as its cells.  The table is
        forced to the disk when the last time is :data:`SYNC_EVERY` seconds ago."""
        cells = [cell(row.get(c)) for c in self.cols[:-1]]
        cells.append(checksum(cells))
        self._write(_line(cells))
        out = dict(zip(self.cols, cells))
        self.done[self.key(out)] = out
        if _now() - self.synced >= SYNC_EVERY:
            self.sync()
        return out

    def sync(self) -> None:
        """Force the rows written so far to the disk (``fsync``)."""
        try:
            os.fsync(self.fd)
        except OSError as exc:
            raise OutputError(self.path, exc) from None
        self.synced = _now()
        self.syncs += 1

    def close(self) -> None:
        try:
            if self.fd is not None:
                try:
                    self.sync()
                finally:
                    os.close(self.fd)
                    self.fd = None
        finally:
            self._unlock()

    def rows(self) -> list[dict]:
        return list(self.done.values())


def write_parquet(csv_path: Path) -> Path | None:
    """The table as Parquet next to the CSV, when pyarrow is importable (else ``None``)."""
    try:
        import pyarrow.csv as pacsv
        import pyarrow.parquet as pq
    except ImportError:
        return None
    from ..files import atomic_write
    import pyarrow as pa
    # the checksum is text (an all-digit one would otherwise be read as a number, leading zeros lost)
    table = pacsv.read_csv(csv_path, convert_options=pacsv.ConvertOptions(column_types={CHECK: pa.string()}))
    out = Path(csv_path).with_suffix(".parquet")
    atomic_write(out, lambda f: pq.write_table(table, f), force=True, binary=True)
    return out
