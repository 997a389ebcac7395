"""Uploads of the served dashboard: the upload widget's server side, the checks of an uploaded
file and its temporary copy on the server, and what a session's uploads hold once it ends.

:class:`BoundedDropper` holds at most :data:`MAX_UPLOAD_MB` of chunks whatever the page sends;
:class:`Uploads` checks a file (size, empty, whitespace), writes it under a name of its own
(:func:`upload_name`) into a temporary directory removed as soon as it has been read, reads it
with :meth:`baarda.dashboard.state.State.load` (its decompressed content bounded by
:data:`UPLOAD_MAX_CONTENT`) and, when the session ends (:meth:`Uploads.close`), removes what is
left and drops the data the session's state holds (:meth:`~baarda.dashboard.state.State.release`),
so the server's memory does not grow with every page closed. File names are shown as plain
text (:func:`baarda.dashboard.text.plain`), never as the browser's raw name.
"""

from __future__ import annotations

import re
import shutil
import tempfile
import threading
from pathlib import Path

import panel as pn
import param

from baarda.io.source import ceiling

from .text import plain

#: The largest upload (MB): refused in the browser before anything is sent, and by the server.
MAX_UPLOAD_MB = 50


#: An uploaded file keeps its own name on the server only if the name is this simple.
SAFE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._ -]{0,100}")
SAFE_SUFFIX = re.compile(r"\.[A-Za-z0-9]{1,8}")
#: Uploads travel in chunks of this size (well under the server's websocket message limit).
UPLOAD_CHUNK = 4 * 1024 * 1024
#: The most an upload may hold once decompressed (a .bz2, .gz or .xz upload; a tighter
#: :func:`baarda.io.source.ceiling` while it is read).
UPLOAD_MAX_CONTENT = 256 * 1024 * 1024


class BoundedDropper(pn.widgets.FileDropper):
    """:class:`panel.widgets.FileDropper` whose server side holds at most ``max_bytes`` of
    upload chunks at a time, whatever the page sends (a page script can raise the widget's own
    limit or send chunks itself): the chunk that would pass it, a chunk out of order or a
    chunk count that announces more is refused at once, everything held is dropped, and
    ``on_refused(name)`` is called. Panel's widget holds every chunk until the last arrives."""

    receiving = param.String(default="", doc="The name of the file arriving now, as plain text "
                             "(baarda.dashboard.text.plain): shown by the panel instead of the browser's raw name.")

    _rename = {**pn.widgets.FileDropper._rename, "receiving": None}     # server side only

    #: the upload widget's own list shows no file name (it would show the browser's raw name,
    #: bidi and control characters included): the panel shows :attr:`receiving` instead
    HIDE_NAMES = ".filepond--file-info-main { display: none !important; }"

    def __init__(self, max_bytes: int, on_refused=None, **params):
        params["stylesheets"] = [*params.get("stylesheets", []), self.HIDE_NAMES]
        super().__init__(**params)
        self._max_bytes = int(max_bytes)
        self._on_refused = on_refused
        self._held = {}              # name -> bytes held for it
        self._refused = set()        # names whose remaining chunks are ignored

    def held_bytes(self) -> int:
        return sum(self._held.values())

    def _refuse(self, name) -> None:
        self._file_buffer.clear()
        self._held.clear()
        self._refused.add(name)
        if self._on_refused is not None:
            self._on_refused(name)

    def _process_event(self, event):
        if event.event_name != "upload_event":
            return super()._process_event(event)
        data = event.data if isinstance(event.data, dict) else {}
        name, chunk, total, payload = (data.get("name"), data.get("chunk"), data.get("total_chunks"),
                                       data.get("data"))
        if not isinstance(name, str):
            return None
        if chunk == 1:
            self.receiving = plain(name)
            self._refused.discard(name)
            self._file_buffer.pop(name, None)
            self._held.pop(name, None)
        elif name in self._refused:
            return None
        size = len(payload) if isinstance(payload, (bytes, bytearray, memoryview, str)) else -1
        ok = (isinstance(chunk, int) and isinstance(total, int) and 1 <= chunk <= total and size >= 0
              and len(self._file_buffer.get(name, ())) == chunk - 1
              and (total - 1) * min(self.chunk_size, UPLOAD_CHUNK) <= self._max_bytes
              and self.held_bytes() + size <= self._max_bytes)
        if not ok:
            self._refuse(name)
            return None
        self._held[name] = self._held.get(name, 0) + size
        if chunk == total:
            self._held.pop(name, None)
        return super()._process_event(event)


def upload_name(name) -> str:
    """A file name for an upload on the server: its own name when it is plain
    (:data:`SAFE_NAME`; never ``.``, ``..``, a path or control characters), else ``upload``
    with the name's extension if that is plain (the format is recognised by it)."""
    name = str(name or "")
    base = name.replace("\\", "/").rsplit("/", 1)[-1]
    if SAFE_NAME.fullmatch(base) and base not in (".", ".."):
        return base
    suffix = Path(base).suffix if base not in (".", "..") else ""
    return "upload" + (suffix.lower() if SAFE_SUFFIX.fullmatch(suffix) else "")


class Uploads:
    """The uploads of one session (module docstring): ``state`` the session's State."""

    def __init__(self, state):
        self.state = state
        self._dirs: list[Path] = []
        self._lock = threading.Lock()

    def refused(self, name) -> None:
        """Say that the upload ``name`` was refused while it arrived (too large)."""
        shown = plain(name) if name not in (None, "") else "the upload"
        self.state.error = f"{shown} is larger than {MAX_UPLOAD_MB} MB; run `baarda` on it instead."

    def receive(self, name, data) -> bool:
        """Check an uploaded file and read it (on a worker thread when served); False and a
        message in ``state.error`` if it is refused."""
        shown = plain(name) if name not in (None, "") else "the upload"
        if isinstance(data, str):
            data = data.encode("utf-8")
        data = b"" if data is None else bytes(data)
        if len(data) > MAX_UPLOAD_MB * 1024 * 1024:
            self.refused(name)
            return False
        if not data:
            self.state.error = f"{shown} is empty (0 bytes)."
            return False
        if not data.strip():
            self.state.error = f"{shown} contains only whitespace ({len(data)} bytes)."
            return False
        folder = Path(tempfile.mkdtemp(prefix="baarda-upload-"))
        with self._lock:
            self._dirs.append(folder)
        tmp = folder / upload_name(name)
        tmp.write_bytes(data)
        del data

        def read():
            try:
                with ceiling(UPLOAD_MAX_CONTENT):        # a compressed upload's content, bounded
                    return self.state.load(tmp, name=shown)
            finally:
                self._remove(folder)

        started = self.state.submit(f"reading {shown}", read)
        if started is None:
            self._remove(folder)
            self.state.error = f"{shown}: wait until the running computation ends, or cancel it."
            return False
        return bool(started) if isinstance(started, bool) else True

    def _remove(self, folder: Path) -> None:
        shutil.rmtree(folder, ignore_errors=True)
        with self._lock:
            if folder in self._dirs:
                self._dirs.remove(folder)

    def cleanup(self) -> None:
        """Remove every temporary upload directory (a read still running, the session ended)."""
        for folder in list(self._dirs):
            self._remove(folder)

    def close(self) -> None:
        """The session ended: its temporary files removed, its data dropped."""
        self.cleanup()
        self.state.release()
