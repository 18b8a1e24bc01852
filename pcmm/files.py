"""Output files: written whole or not at all, never over another file unasked, never lost.

* :func:`atomic_write` writes through a temporary file in the target folder.  Without
  ``force`` the temporary file is then *linked* to its name (``os.link``: atomic, and it fails
  when the name exists), so a file that appeared after start-up (a concurrent run on the same
  ``--out``) is never replaced; with ``force`` it is renamed over it (``os.replace``).
* An operating-system failure (read-only or full folder, a file-size limit) becomes an
  :class:`~pcmm.errors.OutputError` naming the path and the OS error; the caller keeps the
  results in memory and writes them elsewhere (:func:`fallback_path`).
* :func:`unique_path` gives partial results names no other file has (``X-partial-2.npz``).
* :func:`publish_folder` moves a freshly written folder of figures into place, file by file,
  with the same rule.
"""
from __future__ import annotations

import errno
import os
import shutil
import tempfile
from pathlib import Path

from .errors import OutputError, UsageError


def _reserve(tmp: str, path: Path) -> None:
    """Give ``tmp`` the name ``path`` only if no file has it (atomic create-if-absent)."""
    try:
        os.link(tmp, path)
    except FileExistsError:
        raise
    except OSError as exc:  # a file system without hard links: reserve the name, then rename onto it
        if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EMLINK, errno.EXDEV):
            raise
        os.close(os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
        os.replace(tmp, path)
        return
    os.unlink(tmp)


def exists_error(path: Path) -> UsageError:
    return UsageError(f"{path}: exists; pass --force to overwrite it")


def atomic_write(path: str | Path, write, force: bool, binary: bool = False) -> Path:
    """Write ``path`` via ``write(f)`` on a temporary file in the same folder, then give it its name.

    Raises :class:`UsageError` when ``path`` exists (without ``force``), is a folder or lies in a
    missing folder, and :class:`OutputError` when the operating system refuses the write."""
    path = Path(path)
    if not path.parent.exists():
        raise UsageError(f"{path}: folder {path.parent} does not exist")
    if path.is_dir():
        raise UsageError(f"{path}: is a folder; give a file name")
    if path.exists() and not force:
        raise exists_error(path)
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the file the mode an ordinary open would
        with os.fdopen(fd, "wb" if binary else "w", **({} if binary else {"encoding": "utf-8", "newline": ""})) as f:
            write(f)
        if force:
            os.replace(tmp, path)
        else:
            _reserve(tmp, path)
        tmp = None
    except FileExistsError:
        raise UsageError(f"{path}: was created by someone else while pcmm wrote it; it is left as it is "
                         "(pass --force to overwrite it)") from None
    except OSError as exc:
        raise OutputError(path, exc) from None
    finally:
        if tmp is not None and os.path.lexists(tmp):
            os.unlink(tmp)
    return path


def unique_path(path: Path) -> Path:
    """``path`` if no file has that name, else ``stem-2.suffix``, ``stem-3.suffix``, ..."""
    path = Path(path)
    n = 1
    candidate = path
    while candidate.exists() or candidate.is_symlink():
        n += 1
        candidate = path.with_name(f"{path.stem}-{n}{path.suffix}")
    return candidate


def write_new(path: Path, write_to) -> Path:
    """Write ``write_to(p)`` (which must refuse an existing ``p``) at ``path`` or the first free
    ``stem-N`` name next to it, whatever other processes create meanwhile."""
    for _ in range(1000):
        candidate = unique_path(path)
        try:
            return write_to(candidate)
        except UsageError as exc:
            if not candidate.exists():
                raise exc
    raise UsageError(f"{path}: no free file name next to it")


def fallback_folders(preferred: Path | None = None) -> list[Path]:
    """Where results go when their own folder refuses them: the working folder, then the
    system's temporary folder (each only if writable)."""
    candidates = [preferred] if preferred else []
    for where in (Path.cwd, lambda: Path(tempfile.gettempdir())):
        try:  # gettempdir itself fails when no folder takes a file (a file-size limit of 0)
            candidates.append(where())
        except (OSError, RuntimeError):
            pass
    out = []
    for d in candidates:
        try:
            d = d.resolve()
            if d not in out and d.is_dir() and os.access(d, os.W_OK | os.X_OK):
                out.append(d)
        except (OSError, RuntimeError, ValueError):
            continue
    return out


def fallback_path(path: Path, folder: Path) -> Path:
    return unique_path(folder / Path(path).name)


def publish_folder(staging: Path, dest: Path, force: bool) -> list[Path]:
    """Move every file of ``staging`` into ``dest`` (created if needed), refusing existing names
    without ``force`` - all of them are checked before any is moved, and each move is atomic
    create-if-absent.  ``staging`` is removed."""
    try:
        names = sorted(p.name for p in staging.iterdir())
        if dest.exists() and not dest.is_dir():
            raise UsageError(f"{dest}: not a folder")
        dest.mkdir(parents=True, exist_ok=True)
        taken = [dest / n for n in names if (dest / n).exists()]
        if taken and not force:
            raise UsageError([f"{p}: exists; pass --force to overwrite it" for p in taken])
        out = []
        for n in names:
            src, target = staging / n, dest / n
            try:
                if force:
                    os.replace(src, target)
                else:
                    _reserve(str(src), target)
            except FileExistsError:
                raise exists_error(target) from None
            out.append(target)
        return out
    except OSError as exc:
        raise OutputError(dest, exc) from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)


__all__ = ["atomic_write", "unique_path", "write_new", "fallback_folders", "fallback_path", "publish_folder"]


def terminal_text(text: str) -> str:
    """``text`` with control and escape characters shown escaped (``\x1b``), newlines and tabs
    kept: a name in a scene can never move the cursor or recolour the terminal."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() or c in "\n\t" else c.encode("unicode_escape").decode("ascii")
                   for c in text)
