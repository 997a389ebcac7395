"""Opening input files: transparent decompression and chunked reading of numbers.

Every reader opens its file through :func:`open_binary`, :func:`read_bytes` or
:func:`read_text`, so each format may come compressed with gzip (``.gz``), bzip2 (``.bz2``)
or xz (``.xz``). The compression is recognised by the file's first bytes (gzip ``1f 8b``,
bzip2 ``BZh``, xz ``fd 37 7a 58 5a 00``), so a ``problem.txt`` that is really bzip2 reads too;
a file whose extension says compressed but whose content is not is refused. Errors name the
file as the user gave it (``problem.txt.bz2:12: ...``) with the line of the decompressed text;
corrupt or truncated compressed data is an :class:`~baarda.errors.InputError`.

Bounds, checked while reading (never after): the content of an input, decompressed, may hold at
most :func:`max_input_bytes` (``BAARDA_MAX_INPUT_BYTES``, default 4 GiB); a file read as a whole
(Gama XML, native JSON, COLMAP text and binary, control CSV) or arriving through a pipe at most
:func:`max_document_bytes` (``BAARDA_MAX_DOCUMENT_BYTES``, default 1 GiB). Whitespace-separated
number text allows a token (a run without whitespace) of at most :data:`MAX_TOKEN_BYTES` and a
line of at most :data:`MAX_LINE_BYTES` where it has comments. A pipe (a FIFO, ``<(cat f)``) is
read once into memory and every later opening of it reads that copy; a device, socket or other
special file is refused.

:class:`Numbers` reads the whitespace-separated numbers of a text stream in chunks of a few
megabytes, parsed by numpy, so that a reader never holds the file's text and its numbers at
the same time: only the numbers asked for (float64) and the line of each group of them.
"""

from __future__ import annotations

import bz2
import collections
import contextlib
import contextvars
import gzip
import io
import lzma
import os
import re
import stat
import zlib
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from ..errors import BaardaError, InputError, OptionError
from ..solve.compiled import njit

#: compression → (first bytes, file extension, name used in messages)
COMPRESSIONS = {"gzip": (b"\x1f\x8b", ".gz"), "bzip2": (b"BZh", ".bz2"), "xz": (b"\xfd7zXZ\x00", ".xz")}
EXTENSIONS = {ext: name for name, (_, ext) in COMPRESSIONS.items()}
_OPENERS = {"gzip": lambda f, mode: gzip.GzipFile(fileobj=f, mode=mode), "bzip2": bz2.BZ2File,
            "xz": lzma.LZMAFile}
_CORRUPT = (OSError, EOFError, lzma.LZMAError, zlib.error)


#: default ceiling of an input's (decompressed) content, bytes (BAARDA_MAX_INPUT_BYTES)
MAX_INPUT_BYTES = 4 << 30
#: default ceiling of content read as a whole or through a pipe, bytes (BAARDA_MAX_DOCUMENT_BYTES)
MAX_DOCUMENT_BYTES = 1 << 30
#: default ceiling of a small file read beside an input (a truth file, a hypothesis file, a
#: simulation recipe), bytes (BAARDA_MAX_SMALL_BYTES)
MAX_SMALL_BYTES = 16 << 20
#: the longest run without whitespace in number text (no number is longer)
MAX_TOKEN_BYTES = 1 << 20
#: the longest line of number text with comments (a COLMAP points3D.txt line)
MAX_LINE_BYTES = 64 << 20
_CEILING = contextvars.ContextVar("baarda_input_ceiling", default=None)
_CHECK = contextvars.ContextVar("baarda_read_check", default=None)
_PIPES: dict = {}                   # (device, inode) of a pipe -> its bytes, read once


def _env_bytes(name: str, default: int) -> int:
    text = os.environ.get(name, "").strip()
    if not text:
        return default
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (1 <= value < 2 ** 62):
        raise BaardaError(f"{name} must be a positive number of bytes (got '{text[:40]}')")
    return int(value)


def max_input_bytes() -> int:
    """The ceiling of an input's decompressed content in bytes: ``BAARDA_MAX_INPUT_BYTES``
    (default :data:`MAX_INPUT_BYTES`), or a tighter one set by :func:`ceiling` here."""
    n = _env_bytes("BAARDA_MAX_INPUT_BYTES", MAX_INPUT_BYTES)
    tighter = _CEILING.get()
    return n if tighter is None else min(n, tighter)


def max_document_bytes() -> int:
    """The ceiling of content read as a whole or through a pipe: ``BAARDA_MAX_DOCUMENT_BYTES``
    (default :data:`MAX_DOCUMENT_BYTES`), at most :func:`max_input_bytes`."""
    return min(_env_bytes("BAARDA_MAX_DOCUMENT_BYTES", MAX_DOCUMENT_BYTES), max_input_bytes())


def max_small_bytes() -> int:
    """The ceiling of a small file read beside an input (a truth, hypothesis or recipe file):
    ``BAARDA_MAX_SMALL_BYTES`` (default :data:`MAX_SMALL_BYTES`), at most :func:`max_document_bytes`.
    Such a file is parsed into Python objects, tens of bytes for each byte of text."""
    return min(_env_bytes("BAARDA_MAX_SMALL_BYTES", MAX_SMALL_BYTES), max_document_bytes())


@contextlib.contextmanager
def ceiling(nbytes: int):
    """Within the block (this thread or task), inputs may hold at most ``nbytes`` decompressed
    bytes (the served app's uploads); never raises a ceiling already lower."""
    old = _CEILING.get()
    token = _CEILING.set(int(nbytes) if old is None else min(old, int(nbytes)))
    try:
        yield
    finally:
        _CEILING.reset(token)


@contextlib.contextmanager
def checking(check):
    """Within the block (this thread or task), ``check()`` is called before each piece of an
    input is read; what it raises ends the reading (the served app stops reading the file of a
    page that was closed)."""
    token = _CHECK.set(check)
    try:
        yield
    finally:
        _CHECK.reset(token)


def _size_text(n: int) -> str:
    for unit, k in (("GiB", 30), ("MiB", 20), ("KiB", 10)):
        if n >= 1 << k and n % (1 << k) == 0:
            return f"{n >> k} {unit}"
    return f"{n:,} bytes"


def _open_raw(path):
    """(binary file object, size) of ``path``'s raw bytes: the file itself, or a pipe's bytes
    read once (module docstring); InputError for what cannot or must not be read."""
    try:
        st = os.stat(path)
    except OSError as err:
        raise InputError(path, 0, f"cannot read: {err.strerror or err}") from None
    mode = st.st_mode
    if stat.S_ISFIFO(mode):
        key = (st.st_dev, st.st_ino)
        if key not in _PIPES:
            _PIPES[key] = _read_pipe(path)
        data = _PIPES[key]
        return io.BytesIO(data), len(data)
    if stat.S_ISDIR(mode):
        raise InputError(path, 0, "is a directory, not a file")
    if not stat.S_ISREG(mode):
        kind = ("a character device" if stat.S_ISCHR(mode) else "a block device" if stat.S_ISBLK(mode)
                else "a socket" if stat.S_ISSOCK(mode) else "a special file")
        raise InputError(path, 0, f"is {kind}, not a file (give a regular file or a pipe)")
    try:
        return open(path, "rb"), st.st_size
    except OSError as err:
        raise InputError(path, 0, f"cannot read: {err.strerror or err}") from None


def _read_pipe(path) -> bytes:
    """The whole content of a pipe, at most :func:`max_document_bytes`."""
    limit = max_document_bytes()
    pieces, n = [], 0
    try:
        with open(path, "rb", buffering=0) as f:
            while True:
                piece = f.read(min(1 << 20, limit + 1 - n))
                if not piece:
                    break
                pieces.append(piece)
                n += len(piece)
                if n > limit:
                    raise InputError(path, 0, f"the pipe holds more than {_size_text(limit)} "
                                     "(BAARDA_MAX_DOCUMENT_BYTES); give a regular file")
    except OSError as err:
        raise InputError(path, 0, f"cannot read: {err.strerror or err}") from None
    return b"".join(pieces)


def compression(path) -> str | None:
    """``"gzip"``, ``"bzip2"``, ``"xz"`` or None for a plain file, from its first bytes.

    InputError when the file cannot be read, or when its extension names a compression its
    content does not have."""
    p = Path(path)
    f, _ = _open_raw(p)
    try:
        magic = f.read(6)
    except OSError as err:
        raise InputError(path, 0, f"cannot read: {err.strerror or err}") from None
    finally:
        f.close()
    for name, (head, _) in COMPRESSIONS.items():
        if magic.startswith(head):
            return name
    claimed = EXTENSIONS.get(p.suffix.lower())
    if claimed is not None:
        raise InputError(path, 1, f"the name says {claimed}-compressed ({p.suffix}) but the content is not")
    return None


def logical_path(path) -> Path:
    """The path without a compression extension: ``problem.txt.bz2`` → ``problem.txt``."""
    p = Path(path)
    return p.with_suffix("") if p.suffix.lower() in EXTENSIONS else p


class Source(io.RawIOBase):
    """A readable binary stream of a file's (decompressed) content.

    Read errors of the decompressor become InputError naming the file; ``nread`` counts the
    decompressed bytes delivered so far; ``size`` is the file's size in bytes when it is not
    compressed (None otherwise). More than ``limit`` bytes (default :func:`max_input_bytes`;
    ``limit_name`` names the setting) is an InputError as soon as they are read."""

    def __init__(self, path, kind: str | None, limit: int | None = None,
                 limit_name: str = "BAARDA_MAX_INPUT_BYTES"):
        super().__init__()
        self.path = str(path)
        self.kind = kind
        self.nread = 0
        self.limit = max_input_bytes() if limit is None else int(limit)
        self.limit_name = limit_name
        self._check = _CHECK.get()
        raw, size = _open_raw(path)
        self.size = None if kind else size
        self._f = raw if kind is None else _OPENERS[kind](raw, mode="rb")
        self._raw = raw

    def readable(self):
        return True

    def readinto(self, b):
        if self._check is not None:
            self._check()
        try:
            n = self._f.readinto(b)
        except _CORRUPT as err:
            what = f"{self.kind} data" if self.kind else "file"
            raise InputError(self.path, 0, f"corrupt or truncated {what} after {self.nread} bytes of "
                             f"decompressed text ({err})") from None
        self.nread += n or 0
        if self.nread > self.limit:
            what = "decompressed content" if self.kind else "content"
            raise InputError(self.path, 0, f"more than {_size_text(self.limit)} of {what}, the ceiling "
                             f"({self.limit_name})")
        return n

    def close(self):
        if not self.closed:
            try:
                if self._f is not self._raw:
                    self._f.close()
            finally:
                self._raw.close()
        super().close()


def open_binary(path, whole: bool | str = False) -> io.BufferedReader:
    """The content of ``path`` as a buffered binary stream, decompressed (module docstring).

    whole: the content is held as a whole (a document): at most :func:`max_document_bytes`;
    ``"small"``: a small file beside an input, at most :func:`max_small_bytes`."""
    limit, name = ((max_small_bytes(), "BAARDA_MAX_SMALL_BYTES") if whole == "small"
                   else (max_document_bytes(), "BAARDA_MAX_DOCUMENT_BYTES") if whole
                   else (max_input_bytes(), "BAARDA_MAX_INPUT_BYTES"))
    src = Source(path, compression(path), limit=limit, limit_name=name)
    buf = io.BufferedReader(src, buffer_size=1 << 20)
    buf.source = src
    return buf


def read_bytes(path, small: bool = False) -> bytes:
    """The whole (decompressed) content of ``path``, at most :func:`max_document_bytes` (small:
    at most :func:`max_small_bytes`)."""
    pieces = []
    with open_binary(path, whole="small" if small else True) as f:
        while True:
            piece = f.read(1 << 22)
            if not piece:
                break
            pieces.append(piece)
    return pieces[0] if len(pieces) == 1 else b"".join(pieces)


def head(path, n: int = 4096) -> bytes:
    """The first ``n`` bytes of the (decompressed) content of ``path``."""
    with open_binary(path) as f:
        return f.read(n)


def decode(path, data: bytes, first_line: int = 1) -> str:
    """``data`` as UTF-8 text, or InputError at the line of the first bad byte."""
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as err:
        line = first_line + data[:err.start].count(b"\n")
        raise InputError(path, line, f"not UTF-8 text (byte {err.start})") from None


def read_text(path, small: bool = False) -> str:
    """The (decompressed) text of ``path`` as UTF-8, or InputError (small: :func:`read_bytes`)."""
    return decode(path, read_bytes(path, small=small))


# --------------------------------------------------------------------------------------------
# numbers in chunks
# --------------------------------------------------------------------------------------------
_AHEAD = 2
_POOL = None


def _pool() -> ThreadPoolExecutor:
    global _POOL
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=max(1, min(4, os.cpu_count() or 1)),
                                   thread_name_prefix="baarda-read")
    return _POOL


def parse_chunk(buf: bytes, first: int, comment: bytes | None = None, compiled: bool | None = None):
    """(values, line of each, offset of each, the chunk without its comment lines) of a chunk
    of whole lines numbered from ``first``, or None when it cannot all be read as numbers (then
    :class:`Numbers` reads it line by line to say why).

    ``compiled``: True takes the exact fast path compiled by numba (:class:`OptionError` without
    numba), False numpy's ``fromstring``, None (what :class:`Numbers` uses) the compiled one
    where numba is installed. Both give Python's ``float`` of every token.
    """
    if comment is not None and comment in buf:
        # comment lines become empty lines (the line numbers stay); a comment elsewhere fails below
        buf = b"\n".join(b"" if ln.lstrip().startswith(comment) else ln for ln in buf.split(b"\n"))
    b = np.frombuffer(buf, dtype=np.uint8)
    kernel = None if compiled is False else _compiled_scan()
    if compiled and kernel is None:
        raise OptionError("compiled", compiled, (False, None), "the compiled chunk parser needs numba")
    if kernel is not None:
        ws = WHITESPACE[b]
        m = int(np.count_nonzero(ws[:-1] & ~ws[1:])) + int(b.size > 0 and not ws[0])
        del ws
        vals, lines, starts = np.empty(m), np.empty(m, dtype=np.int64), np.empty(m, dtype=np.int64)
        ends, odd = np.empty(m, dtype=np.int32), np.empty(m, dtype=np.int32)
        n, nodd = kernel(b, first, _P10, vals, lines, starts, ends, odd)
        if n != m:
            return None
        if nodd == 0:
            return vals, lines, starts, buf
        if nodd <= 4096:                 # a few tokens beyond the exact fast path: Python's float
            for j in odd[:nodd].tolist():
                try:
                    vals[j] = float(buf[starts[j]:ends[j]].decode("ascii"))
                except (ValueError, UnicodeDecodeError):
                    return None
            return vals, lines, starts, buf
        try:                             # many (17-digit numbers): the C library's, for all
            full = np.fromstring(buf, dtype=float, sep=" ")
        except ValueError:
            return None
        return (full, lines, starts, buf) if full.size == n else None
    ws = WHITESPACE[b]
    start = ~ws
    start[1:] &= ws[:-1]
    starts = np.flatnonzero(start)
    if not starts.size:
        return np.zeros(0), np.zeros(0, dtype=np.int64), starts, buf
    try:
        vals = np.fromstring(buf, dtype=float, sep=" ")
    except ValueError:
        return None
    if vals.size != starts.size:
        return None
    lines = first + np.searchsorted(np.flatnonzero(b == 10), starts)
    return vals, lines.astype(np.int64), starts, buf


#: 10⁰ … 10²², all exact in double precision
_P10 = np.array([10.0 ** k for k in range(23)])
_KERNEL = {}


def _compiled_scan():
    """:func:`_scan` compiled by numba (optional; None without it)."""
    if "scan" not in _KERNEL:
        jit = njit(cache=True, nogil=True)
        _KERNEL["scan"] = None if jit is None else jit(_scan)
    return _KERNEL["scan"]


def _scan(b, first, p10, vals, lines, starts, ends, odd):
    """Tokens of a chunk of whole lines (bytes b): value, line, start, end of each; returns
    (count, count of the odd ones, listed in ``odd``).

    A token of the form [±]digits[.digits][e[±]digits] whose significand w (the digits as an
    integer) is below 2⁵³ and whose decimal exponent q is within ±22 is converted as w·10^q or
    w / 10^−q: both factors are exact doubles, so the one rounding gives the correctly rounded
    value, the same as the C library's strtod (Clinger 1990, "How to read floating point
    numbers accurately", the fast path). Every other token is odd: the caller converts it with
    Python's float (or refuses it).
    """
    n, nodd, line, i, size = 0, 0, first, 0, b.size
    limit = 9007199254740992                   # 2⁵³
    while i < size:
        c = b[i]
        if c == 10:
            line += 1
            i += 1
            continue
        if c == 32 or (c >= 9 and c <= 13):
            i += 1
            continue
        if n >= vals.size:                     # (cannot happen: the caller counted the tokens)
            return -1, 0
        starts[n] = i
        lines[n] = line
        neg = False
        if c == 45:
            neg = True
            i += 1
        elif c == 43:
            i += 1
        w, q, digits, ok = 0, 0, 0, True
        while i < size and b[i] >= 48 and b[i] <= 57:
            d = b[i] - 48
            if w <= (limit - d) // 10:
                w = w * 10 + d
            else:
                ok = False
            digits += 1
            i += 1
        if i < size and b[i] == 46:
            i += 1
            while i < size and b[i] >= 48 and b[i] <= 57:
                d = b[i] - 48
                if w <= (limit - d) // 10:
                    w = w * 10 + d
                    q -= 1
                else:
                    ok = False
                digits += 1
                i += 1
        if digits == 0:
            ok = False
        if i < size and (b[i] == 101 or b[i] == 69):
            i += 1
            eneg = False
            if i < size and b[i] == 45:
                eneg = True
                i += 1
            elif i < size and b[i] == 43:
                i += 1
            e, ed = 0, 0
            while i < size and b[i] >= 48 and b[i] <= 57:
                if e < 100000:
                    e = e * 10 + (b[i] - 48)
                ed += 1
                i += 1
            if ed == 0:
                ok = False
            q += -e if eneg else e
        while i < size and not (b[i] == 32 or (b[i] >= 9 and b[i] <= 13)):
            ok = False                         # something else in the token: not for the fast path
            i += 1
        ends[n] = i
        v = 0.0
        if ok:
            if w == 0:
                v = 0.0
            elif q >= 0 and q <= 22:
                v = w * p10[q]
            elif q < 0 and q >= -22:
                v = w / p10[-q]
            else:
                ok = False
        if not ok:
            odd[nodd] = n
            nodd += 1
            v = np.nan
        vals[n] = -v if neg else v
        n += 1
    return n, nodd


class Truncated(Exception):
    """The stream ended before the numbers asked for: ``have`` of them were there."""

    def __init__(self, have: int):
        super().__init__(have)
        self.have = have


_TOKEN_END = re.compile(rb"[ \t\n\r\x0b\x0c]")
WHITESPACE = np.zeros(256, dtype=bool)
WHITESPACE[[9, 10, 11, 12, 13, 32]] = True


class Numbers:
    """Whitespace-separated numbers of a binary text stream, read in chunks (module docstring).

    Each chunk (whole lines, about ``chunk`` bytes) is parsed at once by numpy; only a chunk
    numpy refuses (a word, a comment, bad UTF-8) goes through Python token by token, where an
    unreadable token becomes NaN and its text is kept for the message. ``comment``: lines
    starting with it (after blanks) are skipped. ``line`` is the line of the next number.
    """

    def __init__(self, path, stream, first_line: int = 1, comment: str | None = None, chunk: int = 1 << 21,
                 prefix: bytes = b""):
        self.path = str(path)
        self.stream = stream
        self.comment = comment
        self.chunk = chunk
        self.next_line = first_line      # line number at the start of the next chunk
        self.last_line = max(first_line - 1, 1)
        self.tail = prefix               # text read ahead by the caller
        self.eof = False
        self.consumed = 0                # numbers taken so far
        self.odd = {}                    # global index → text of a non-finite or unreadable token
        self._pending = None
        self._set_chunk(np.zeros(0), np.zeros(0, dtype=np.int64), [])

    # -- chunks ------------------------------------------------------------------------------
    def _set_chunk(self, vals, lines, texts, buf=b"", starts=None):
        self.vals, self.lines, self.texts, self.i = vals, lines, texts, 0
        self.base = self.consumed        # global index of vals[0]
        self.buf, self.starts = buf, starts

    def _raw_chunks(self):
        """(bytes of whole lines, its first line, its last line), in order.

        Text without a place to cut (a newline; without comments also a blank) is gathered in
        one buffer, linearly: more than :data:`MAX_TOKEN_BYTES` of it (:data:`MAX_LINE_BYTES`
        with comments) is a token (a line) too long, refused at its line."""
        held = bytearray()               # text read since the last place to cut
        while not self.eof:
            data = self.stream.read(self.chunk)
            if not data:
                self.eof = True
                buf, self.tail = bytes(self.tail) + bytes(held), b""
                held = bytearray()
            else:
                cut = data.rfind(b"\n")
                if cut < 0 and not self.comment:   # one long line: cut between two numbers instead
                    cut = max(data.rfind(b" "), data.rfind(b"\t"))
                if cut < 0:
                    held += data
                    if len(held) > (MAX_LINE_BYTES if self.comment else MAX_TOKEN_BYTES):
                        line = self.next_line + bytes(self.tail).count(b"\n")
                        what = (f"a line longer than {_size_text(MAX_LINE_BYTES)}" if self.comment else
                                f"a token longer than {_size_text(MAX_TOKEN_BYTES)} (not a number)")
                        raise InputError(self.path, line, what)
                    continue
                data = bytes(self.tail) + bytes(held) + data if (self.tail or held) else data
                held = bytearray()
                cut = data.rfind(b"\n")
                if cut < 0 and not self.comment:
                    cut = max(data.rfind(b" "), data.rfind(b"\t"))
                buf, self.tail = data[:cut + 1], data[cut + 1:]
            if not buf:
                return
            first = self.next_line
            nl = buf.count(b"\n")
            self.next_line += nl
            yield buf, first, first + nl - (1 if buf.endswith(b"\n") else 0)

    def _read_chunk(self) -> bool:
        """Parse the next chunk of whole lines; False at the end of the stream.

        Chunks are parsed ahead in a small thread pool (numpy releases the GIL while it
        parses), while this thread reads, and perhaps decompresses, the next ones."""
        if self._pending is None:
            self._pending = collections.deque()
            self._source = self._raw_chunks()
        comment = self.comment.encode() if self.comment else None
        while True:
            while len(self._pending) < _AHEAD:
                nxt = next(self._source, None)
                if nxt is None:
                    break
                buf, first, last = nxt
                self._pending.append((_pool().submit(parse_chunk, buf, first, comment), buf, first, last))
            if not self._pending:
                return False
            fut, buf, first, last = self._pending.popleft()
            res = fut.result()
            self.last_line = max(last, 1)
            if res is None:
                self._parse_slow(buf, first)
            else:
                vals, lines, starts, buf = res
                self._set_chunk(vals, lines, None, buf, starts)
                if not np.isfinite(vals).all():
                    for j in np.flatnonzero(~np.isfinite(vals))[:1000]:
                        self._note(self.base + int(j), self._raw(int(j)))
            if self.vals.size:
                return True

    def _raw(self, j: int) -> str:
        """Text of token j of the current (fast-parsed) chunk."""
        a = int(self.starts[j])
        m = _TOKEN_END.search(self.buf, a)
        return self.buf[a:m.start() if m else len(self.buf)].decode("utf-8", "replace")

    def _note(self, index, text):
        if len(self.odd) < 10000:
            self.odd[index] = text

    def _parse_slow(self, buf: bytes, first: int):
        """A chunk numpy refused, token by token: an unreadable token becomes NaN (its text is
        kept for the message); the checks of the caller then say what is wrong."""
        try:
            buf.decode("utf-8")
        except UnicodeDecodeError:
            decode(self.path, buf, first)                   # bad UTF-8: refused at its line
        if self.comment:
            c = self.comment.encode()
            buf = b"\n".join(b"" if ln.lstrip().startswith(c) else ln for ln in buf.split(b"\n"))
        b = np.frombuffer(buf, dtype=np.uint8)
        ws = WHITESPACE[b]
        start = ~ws
        start[1:] &= ws[:-1]
        starts = np.flatnonzero(start)
        end = ~ws
        end[:-1] &= ws[1:]
        ends = np.flatnonzero(end) + 1
        vals = np.empty(starts.size)
        nan = float("nan")
        for k in range(0, starts.size, 4096):
            for j, a, e in zip(range(k, k + 4096), starts[k:k + 4096].tolist(), ends[k:k + 4096].tolist()):
                try:
                    vals[j] = float(buf[a:e])
                except ValueError:
                    vals[j] = nan
        lines = first + np.searchsorted(np.flatnonzero(b == 10), starts)
        self._set_chunk(vals, lines.astype(np.int64), None, buf, starts)
        for j in np.flatnonzero(~np.isfinite(vals))[:1000]:
            self._note(self.base + int(j), self._raw(int(j)))

    # -- reading -----------------------------------------------------------------------------
    @property
    def line(self) -> int:
        """Line of the next number (the last line at the end of the stream)."""
        if self.i < self.vals.size or self._read_chunk():
            return int(self.lines[self.i])
        return self.last_line

    def text(self, index: int, value: float | None = None) -> str:
        """The text of number ``index`` (global) as the file has it, as far as it is known."""
        if index in self.odd:
            return self.odd[index]
        j = index - self.base
        if 0 <= j < self.vals.size:
            return self.texts[j] if self.texts is not None else self._raw(j)
        return "" if value is None else f"{value:.17g}".replace("e+", "e")

    def take(self, n: int, group: int = 1, what=None):
        """The next ``n`` numbers: (values (n,), the line of the first and of the last number of
        each group of ``group``, (n // group,) each). Raises :class:`Truncated` at the end.

        what(k) → (description, "finite" or "int") of number k: then a number that is not
        finite (or not a number at all) is refused in the chunk where it is, before the rest of
        the file is read.

        A plain file whose size can hold the n numbers gets its arrays allocated once and
        filled chunk by chunk (memory is taken only as they fill); otherwise — compressed
        input, whose size says nothing — the arrays grow with what the file really holds.
        """
        size = getattr(getattr(self.stream, "source", None), "size", None)
        ng = n // group
        whole = size is not None and n <= (size + 1) // 2
        if whole:
            vals, first = np.empty(n), np.empty(ng, dtype=np.int64)
            last = first if group == 1 else np.empty(ng, dtype=np.int64)
        pieces, firsts, lasts = [], [], []
        got, base = 0, self.consumed
        while got < n:
            if self.i >= self.vals.size and not self._read_chunk():
                raise Truncated(got)
            k = min(n - got, self.vals.size - self.i)
            v, ln = self.vals[self.i:self.i + k], self.lines[self.i:self.i + k]
            if what is not None and not np.isfinite(v).all():
                j = int(np.flatnonzero(~np.isfinite(v))[0])
                desc, kind = what(got + j)
                self._fail(v[j:j + 1], ln[j:j + 1], lambda _: base + got + j, lambda _: desc, 0, kind)
            j0, j1 = (-got) % group, (group - 1 - got) % group     # first and last of a group here
            f, la = ln[j0::group], ln[j1::group]
            if whole:
                vals[got:got + k] = v
                g0 = (got + j0) // group
                first[g0:g0 + f.size] = f
                if group > 1:
                    g1 = (got + j1) // group
                    last[g1:g1 + la.size] = la
            else:
                pieces.append(v)
                firsts.append(f)
                lasts.append(la)
            self.i += k
            self.consumed += k
            got += k
        if whole:
            return vals, first, last
        vals = np.concatenate(pieces) if pieces else np.zeros(0)
        del pieces
        first = np.concatenate(firsts) if firsts else np.zeros(0, dtype=np.int64)
        last = first if group == 1 else (np.concatenate(lasts) if lasts else np.zeros(0, dtype=np.int64))
        return vals, first, last

    def take_rest(self):
        """All numbers left: (values, line of each)."""
        pieces, lines = [], []
        while self.i < self.vals.size or self._read_chunk():
            pieces.append(self.vals[self.i:])
            lines.append(self.lines[self.i:])
            self.consumed += self.vals.size - self.i
            self.i = self.vals.size
        if not pieces:
            return np.zeros(0), np.zeros(0, dtype=np.int64)
        return np.concatenate(pieces), np.concatenate(lines)

    def peek(self) -> tuple[str, int] | None:
        """(text, line) of the next number, or None at the end of the stream."""
        if self.i >= self.vals.size and not self._read_chunk():
            return None
        return self.text(self.consumed), int(self.lines[self.i])

    def end(self, what: str):
        """InputError unless the stream has no more numbers."""
        nxt = self.peek()
        if nxt is not None:
            raise InputError(self.path, nxt[1], f"unexpected '{nxt[0][:40]}' after {what} (the counts in "
                             "the header do not match the file)")

    # -- checks on what was taken --------------------------------------------------------------
    def check_finite(self, vals, lines, where, what):
        """InputError at the first non-finite value of ``vals``. lines: the line of each value,
        or of each group of len(vals) // len(lines); where(j): the global index of value j;
        what(j): what value j is."""
        bad = ~np.isfinite(vals)
        if bad.any():
            self._fail(vals, lines, where, what, int(np.flatnonzero(bad)[0]), "finite")

    def check_ints(self, vals, lines, where, what):
        """InputError at the first value that is not a non-negative integer below 10¹⁷."""
        ok = np.isfinite(vals) & (vals >= 0) & (vals == np.floor(vals)) & (vals < 1e17)
        if not ok.all():
            self._fail(vals, lines, where, what, int(np.flatnonzero(~ok)[0]), "int")

    def _fail(self, vals, lines, where, what, j, kind):
        v = float(vals[j])
        t = self.text(int(where(j)), v)
        group = max(vals.size // max(lines.size, 1), 1)
        line = int(lines[j // group])
        if kind == "int":
            if (np.isfinite(v) and v >= 1e17) or (t.isascii() and t.isdigit()):
                raise InputError(self.path, line, f"{what(j)}: {t[:40]}{'...' if len(t) > 40 else ''} is too large")
            raise InputError(self.path, line, f"{what(j)}: '{t[:40]}' is not a non-negative integer")
        if np.isnan(v) and t.strip().lower() not in ("nan", "+nan", "-nan"):
            raise InputError(self.path, line, f"{what(j)}: '{t[:40]}' is not a number")
        raise InputError(self.path, line, f"{what(j)}: {t[:40]} is not a finite number")


def numbers(path, comment: str | None = None, chunk: int = 1 << 22) -> Numbers:
    """A :class:`Numbers` reader of ``path`` (close it with ``.stream.close()``)."""
    return Numbers(path, open_binary(path), comment=comment, chunk=chunk)
