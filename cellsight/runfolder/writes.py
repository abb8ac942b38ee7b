"""Every file cellsight writes goes through here, so that a failed write (a full disk, a
read-only folder) is one :class:`WriteError` naming the file and why (``No space left on
device``), and never leaves a half-written file under the file's name:

- :func:`write_file`: a whole file, written to a temporary file in the same folder and put in
  place by :func:`os.replace` (the temporary file removed on failure); :func:`write_figure`
  the same for a matplotlib figure as PNG;
- :class:`AtomicFile`: the same for a file written as it goes (the MCAP export): it takes the
  file's name only on :meth:`AtomicFile.commit`;
- :func:`staged`: several files written together (``cameras --write``, ``show``): all of them
  are put in place, or none (those already moved are removed again; the folders made for
  them, :func:`make_folders`, too: :func:`remove_folders`);
- :class:`RunWrites`: the writes of one run into its folder, each failure recorded
  (:attr:`RunWrites.failures`) so that the run's ``metrics.json`` says so (``error``) and a
  sweep never takes the run for finished.

Temporary names start with ``.`` and end with :data:`TEMP_SUFFIX`; one left by a killed
process is taken for a run's output (:func:`cellsight.runfolder.folder.is_run_output`).
"""

from __future__ import annotations

import io
import logging
import os
import secrets
import shutil
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

from cellsight.errors import CellsightError

TEMP_SUFFIX = ".tmp"
"""The ending of every temporary file or folder this module makes."""


class WriteError(CellsightError):
    """A file could not be written: ``path``, ``reason`` (the system's words)."""

    def __init__(self, path: str | Path, reason: str) -> None:
        self.path, self.reason = Path(path), reason
        super().__init__(f"{path}: cannot write it ({reason})")


def reason_of(exc: BaseException) -> str:
    """Why a write failed, in one short line: the OSError's ``strerror`` (``No space left on
    device``), else the first line of its message."""
    text = getattr(exc, "strerror", None) or str(exc).strip() or type(exc).__name__
    line = text.splitlines()[0] if text.splitlines() else text
    return " ".join(line.split())[:200]


def write_error(path: str | Path, exc: BaseException) -> WriteError:
    """``exc`` (an OSError while writing ``path``) as a :class:`WriteError`; one already is."""
    return exc if isinstance(exc, WriteError) else WriteError(path, reason_of(exc))


def temp_path(path: Path) -> Path:
    """A fresh temporary name next to ``path`` (``.<name>.<random>.tmp``)."""
    return path.with_name(f".{path.name[:180]}.{secrets.token_hex(4)}{TEMP_SUFFIX}")


class AtomicFile:
    """A binary file written as it goes under a temporary name in its folder (:func:`temp_path`,
    made with the usual permissions), put in place by :meth:`commit`. A failed write, flush or
    commit removes the temporary file and raises a :class:`WriteError` naming ``path``; leaving
    a ``with`` block without :meth:`commit` just removes it. :attr:`failed`: a write failed
    (nothing more may be written)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.failed = False
        self.temp = temp_path(self.path)
        try:
            self._file = open(self.temp, "xb")  # noqa: SIM115 (closed by commit or discard)
        except OSError as exc:
            raise write_error(self.path, exc) from exc

    def _failing(self, exc: OSError) -> WriteError:
        self.failed = True
        self.discard()
        return write_error(self.path, exc)

    def write(self, data: bytes) -> int:
        try:
            return self._file.write(data)
        except OSError as exc:
            raise self._failing(exc) from exc

    def tell(self) -> int:
        try:
            return self._file.tell()
        except OSError as exc:
            raise self._failing(exc) from exc

    def flush(self) -> None:
        try:
            self._file.flush()
        except OSError as exc:
            raise self._failing(exc) from exc

    def commit(self) -> Path:
        """Close the file and give it its name (replacing any file there); returns ``path``."""
        try:
            self._file.close()
            os.replace(self.temp, self.path)
        except OSError as exc:
            raise self._failing(exc) from exc
        return self.path

    def discard(self) -> None:
        """Close and remove the temporary file (nothing under ``path`` changes)."""
        with suppress(OSError):
            self._file.close()
        with suppress(OSError):
            self.temp.unlink(missing_ok=True)

    def __enter__(self) -> AtomicFile:
        return self

    def __exit__(self, *exc_info: object) -> None:
        if self.temp.exists() or not self._file.closed:
            self.discard()


def write_file(path: str | Path, data: str | bytes) -> Path:
    """Write ``data`` (text as UTF-8) as the file ``path``, atomically (:class:`AtomicFile`):
    the whole file or, on a :class:`WriteError`, the file as it was. Returns ``path``."""
    with AtomicFile(path) as file:
        file.write(data.encode("utf-8") if isinstance(data, str) else data)
        return file.commit()


def write_figure(path: str | Path, figure, dpi: int = 100) -> Path:
    """Save a matplotlib ``figure`` as the PNG file ``path`` at ``dpi``, whole or not at all
    (:func:`write_file`). Returns ``path``."""
    png = io.BytesIO()
    figure.savefig(png, format="png", dpi=dpi)
    return write_file(path, png.getvalue())


@contextmanager
def staged(folder: Path) -> Iterator[Path]:
    """A temporary folder in ``folder`` to write files into: on leaving the block, every file
    written there is moved into ``folder`` (replacing files of the same names), or, when the
    block or a move fails, none is (those already moved are removed again). The temporary folder
    is removed either way; an OSError of its own is a :class:`WriteError`."""
    folder = Path(folder)
    stage = temp_path(folder / ".cellsight")
    try:
        stage.mkdir()
    except OSError as exc:
        raise write_error(stage.parent, exc) from exc
    moved: list[Path] = []
    try:
        yield stage
        for item in sorted(stage.iterdir()):
            try:
                os.replace(item, folder / item.name)
            except OSError as exc:
                raise write_error(folder / item.name, exc) from exc
            moved.append(folder / item.name)
    except BaseException:
        for path in moved:
            with suppress(OSError):
                path.unlink()
        raise
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def make_folders(folder: Path) -> list[Path]:
    """Make ``folder`` and the folders above it that are missing; returns those made, deepest
    first, for :func:`remove_folders`. An OSError is raised as it is."""
    folder = Path(folder)
    made = [p for p in (folder, *folder.parents) if not p.exists() and not p.is_symlink()]
    folder.mkdir(parents=True, exist_ok=True)
    return made


def remove_folders(made: list[Path]) -> None:
    """Remove the folders :func:`make_folders` made, deepest first, as long as they are empty."""
    for folder in made:
        try:
            folder.rmdir()
        except OSError:
            return


class _LogFile(logging.FileHandler):
    """``run.log``: a failed write is recorded in the run's :class:`RunWrites` (once), not
    printed with a traceback as :mod:`logging` does."""

    def __init__(self, path: Path, writes: RunWrites) -> None:
        self.writes = writes
        super().__init__(path, mode="w", encoding="utf-8")

    def handleError(self, record: logging.LogRecord) -> None:  # noqa: N802 (logging's name)
        exc = sys.exc_info()[1]
        if not isinstance(exc, OSError):
            super().handleError(record)
            return
        self.writes.record(self.baseFilename, exc)


class RunWrites:
    """The writes of one run into ``folder``: whole files (:meth:`file`), writes made elsewhere
    (:meth:`guard`, :meth:`close`) and ``run.log`` (:meth:`log_file`). Each failure is one line
    in :attr:`failures` (in order, each once), for the run's ``metrics.json``; :attr:`first`
    is the first as a :class:`WriteError`, to raise once the run has written what it could."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        self.failures: list[str] = []
        self.first: WriteError | None = None

    def record(self, path: str | Path, exc: BaseException) -> WriteError:
        """Record a failed write of ``path`` (``exc``: an OSError or a :class:`WriteError`);
        returns it as a :class:`WriteError`."""
        error = write_error(path, exc)
        self.note(str(error))
        self.first = self.first or error
        return error

    def note(self, line: str) -> None:
        """Record a failure that is not a write (the report could not be made): one line."""
        if line not in self.failures:
            self.failures.append(line)

    def file(self, name: str, data: str | bytes) -> Path:
        """Write the file ``name`` of the folder (:func:`write_file`); a failure is recorded
        and raised."""
        try:
            return write_file(self.folder / name, data)
        except WriteError as exc:
            raise self.record(exc.path, exc) from exc

    @contextmanager
    def guard(self, path: str | Path) -> Iterator[None]:
        """Writes to ``path`` made by others (a picture, the video): an OSError in the block is
        recorded and raised as a :class:`WriteError` naming the file (its own name if it has
        one)."""
        try:
            yield
        except WriteError as exc:
            raise self.record(exc.path, exc) from exc
        except OSError as exc:
            raise self.record(exc.filename or path, exc) from exc

    def close(self, path: str | Path, close: Callable[[], object]) -> None:
        """Call ``close`` (of a file written as it goes); a failure to write out its end is
        recorded, not raised."""
        with suppress(WriteError), self.guard(path):
            close()

    def log_file(self, name: str) -> logging.Handler:
        """A logging handler writing the folder's ``name`` (``run.log``); a failed write is
        recorded (:class:`_LogFile`); failing to create it is raised."""
        try:
            return _LogFile(self.folder / name, self)
        except OSError as exc:
            raise self.record(self.folder / name, exc) from exc

    def error(self, first: str | None = None) -> str | None:
        """``first`` (how the run ended, when it failed) and every failure recorded, as the
        ``error`` of ``metrics.json`` (at most 1000 characters); None when there is none."""
        lines = [first] if first else []
        lines += [f for f in self.failures if not first or f not in first]
        return "; ".join(lines)[:1000] or None


def log_to(writes: RunWrites) -> logging.Handler:
    """Send the package's log (INFO and up) to the run's ``run.log`` as it goes, one message
    per line; a failed write is recorded in ``writes``."""
    handler = writes.log_file("run.log")
    handler.setFormatter(logging.Formatter("%(message)s"))
    root = logging.getLogger("cellsight")
    root.addHandler(handler)
    root.setLevel(logging.INFO)
    return handler


def stop_logging_to(handler: logging.FileHandler, writes: RunWrites) -> None:
    logging.getLogger("cellsight").removeHandler(handler)
    writes.close(handler.baseFilename, handler.close)
