"""Writing outputs safely: never onto an input, never half a file (issue 25, items 2, 3, 7).

- :func:`check_outputs` refuses, before anything is read or written, an output path that names
  an input — the same path, a file inside an input folder (a COLMAP model), or the same file
  through a symbolic or hard link (same device and inode) — an output named twice, and an
  output that cannot be written (its folder missing or not writable, a directory, ``/proc``).
- :func:`atomic_write` writes a file to a temporary file beside it and renames it over the
  target only when complete (``os.replace``, atomic on POSIX): an interrupted or failed write
  leaves the previous file as it was and no temporary file behind.
- :func:`csv_cell` makes a text cell of a CSV file safe for spreadsheets (one owner for the
  command line's and the dashboard's CSVs).

A failure to write is an :class:`OutputError` (``"PATH:0: cannot write: why"``): the user's
mistake, exit status 2 in the command line, never an internal error.
"""

from __future__ import annotations

import os
import secrets
import stat
from contextlib import contextmanager
from pathlib import Path

from ..errors import BaardaError
from ..text import printable


class OutputError(BaardaError):
    """An output that must not or cannot be written: ``str(err)`` is ``"{path}:0: {message}"``."""

    def __init__(self, path, message: str):
        self.path = str(path)
        self.message = message
        super().__init__(f"{self.path}:0: {message}")

    def __reduce__(self):
        return (type(self), (self.path, self.message))


def _identity(path: str):
    """(st_dev, st_ino) of the file ``path`` names (through links), or None if it does not exist."""
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    return st.st_dev, st.st_ino


def _input_files(path: str) -> tuple[str, set]:
    """The resolved path of input ``path`` and the identities of what reading it opens: the file,
    or the files directly inside a folder (a COLMAP model)."""
    real = os.path.realpath(path)
    ids = set()
    if os.path.isdir(real):
        try:
            with os.scandir(real) as it:
                for entry in it:
                    ident = _identity(entry.path)
                    if ident is not None:
                        ids.add(ident)
        except OSError:
            pass
    ident = _identity(real)
    if ident is not None:
        ids.add(ident)
    return real, ids


def _writable_folder(path: str, what: str) -> None:
    """OutputError unless a file can be created in the existing folder ``path`` (tried with a
    temporary file, removed at once: permissions alone do not tell, e.g. for ``/proc``)."""
    try:
        fd, tmp = _create_temp(Path(path), "probe")
    except OSError as err:
        raise OutputError(what, f"cannot write here: {err.strerror or err}") from None
    os.close(fd)
    try:
        os.unlink(tmp)
    except OSError:
        pass


def check_outputs(inputs, outputs, folders=()) -> None:
    """Refuse (:class:`OutputError`) an output that names an input or another output, or that
    cannot be written (module docstring). ``inputs`` are paths read (None entries are skipped),
    ``outputs`` files to write, ``folders`` folders to write files into (created if needed:
    ``analyze --csv DIR``; the files meant to go there belong in ``outputs``)."""
    ins = [(str(p), *_input_files(str(p))) for p in inputs if p is not None]
    seen: dict[str, str] = {}
    new_folders = set()
    for folder in folders:
        folder = str(folder)
        real = os.path.realpath(folder)
        if not os.path.exists(real):
            new_folders.add(real)
        if os.path.exists(real) and not os.path.isdir(real):
            raise OutputError(folder, "exists and is not a folder")
        for name, rin, _ in ins:
            if real == rin and not os.path.isdir(rin):
                raise OutputError(folder, f"refusing to write into an input ({printable(name)})")
        parent = real
        while not os.path.exists(parent):
            parent = os.path.dirname(parent)
        if not os.path.isdir(parent):
            raise OutputError(folder, f"cannot create the folder: {printable(parent)} is not a folder")
        _writable_folder(parent, folder)
    for out in outputs:
        if out is None:
            continue
        out = str(out)
        real = os.path.realpath(out)
        if real in seen:
            raise OutputError(out, f"named twice as an output (also as {printable(seen[real])})")
        seen[real] = out
        ident = _identity(real)
        for name, rin, ids in ins:
            if real == rin:
                raise OutputError(out, f"refusing to overwrite the input {printable(name)}")
            if os.path.isdir(rin) and real.startswith(rin + os.sep):
                raise OutputError(out, f"refusing to write into the input folder {printable(name)}")
            if ident is not None and ident in ids:
                raise OutputError(out, f"refusing to overwrite the input {printable(name)} (the same file, "
                                       f"through a link)")
        if os.path.isdir(real):
            raise OutputError(out, "is a folder, not a file")
        parent = os.path.dirname(real)
        if parent in new_folders:
            continue                     # a folder to be created (checked above)
        if not os.path.isdir(parent):
            raise OutputError(out, "cannot write: no such folder")
        if not os.path.exists(real) or os.path.isfile(real):
            _writable_folder(parent, out)
        else:
            raise OutputError(out, "is not a regular file")


def _create_temp(folder: Path, name: str) -> tuple[int, str]:
    """A new file ``.NAME.RANDOM.part`` in ``folder``, created exclusively with the mode a new
    file gets (0666 less the umask)."""
    while True:
        tmp = str(folder / f".{name}.{secrets.token_hex(4)}.part")
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666), tmp
        except FileExistsError:
            continue


@contextmanager
def atomic_write(path, binary: bool = False, encoding: str = "utf-8", newline: str | None = None):
    """A file object to write ``path`` with, atomically: the text (or bytes) goes to a temporary
    file beside ``path`` (beside the file a symbolic link names, so the link stays), which
    replaces ``path`` only when the ``with`` block ends without an exception; on an exception
    (SIGINT, SIGTERM, a full disk) it is removed and ``path`` is left as it was. An existing
    file's permissions are kept. OSError while writing is an :class:`OutputError`."""
    target = Path(os.path.realpath(path))
    try:
        fd, tmp = _create_temp(target.parent, target.name)
    except OSError as err:
        raise OutputError(path, f"cannot write: {err.strerror or err}") from None
    try:
        try:
            with (os.fdopen(fd, "wb") if binary else
                  os.fdopen(fd, "w", encoding=encoding, newline=newline)) as fh:
                yield fh
                fh.flush()
                os.fsync(fh.fileno())
            try:
                os.chmod(tmp, stat.S_IMODE(os.stat(target).st_mode))
            except FileNotFoundError:
                pass
            os.replace(tmp, target)
        except OSError as err:
            raise OutputError(path, f"cannot write: {err.strerror or err}") from None
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def write_text(path, text: str, encoding: str = "utf-8") -> None:
    """``text`` written to ``path`` with :func:`atomic_write`."""
    with atomic_write(path, encoding=encoding) as fh:
        fh.write(text)


#: what a spreadsheet takes for the start of a formula in a text cell (CSV injection, OWASP)
_FORMULA = ("=", "+", "-", "@", "\t", "\r")


def csv_cell(x):
    """A CSV cell safe for spreadsheets: a text cell with every non-printable character shown as
    an escape (:func:`baarda.text.printable`: controls, bidi overrides, zero-width characters)
    and a leading apostrophe when a spreadsheet would read it as a formula (starting with
    ``= + - @``, a tab or a carriage return); other values (numbers) unchanged."""
    if isinstance(x, str):
        x = printable(x)
        return "'" + x if x.startswith(_FORMULA) else x
    return x
