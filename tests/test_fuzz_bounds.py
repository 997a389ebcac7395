"""Hostile inputs that cost time or memory rather than confuse a parser (issue 25, item 4):
decompression bombs (bzip2, gzip and xz, as Gama XML, native JSON and BAL), one endless token,
whitespace without end, deep nesting, millions of elements, a device, pipes.

Each case runs ``baarda analyze`` in a child process with an address-space limit
(:data:`ADDRESS_SPACE`, ``RLIMIT_AS``) and a timeout (:data:`TIMEOUT`); the contract is that of
``test_fuzz_contract.py``: exit status 2 and one line ``baarda: error: FILE:LINE: what``. The
bombs are made here, in memory, from concatenated compressed streams (a 45 MB run compresses to
a few dozen bytes, a 1 MB pattern a little more; decompressors read concatenated streams as one), never kept as files in the
repository. The ceilings (``BAARDA_MAX_INPUT_BYTES``, ``BAARDA_MAX_DOCUMENT_BYTES``) are lowered
for the unmarked tests so that a case takes seconds; the ``slow`` test runs the largest bombs
against the default ceilings.
"""

from __future__ import annotations

import bz2
import gzip
import lzma
import os
import resource
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from tests.test_fuzz_contract import CONTROL, ERROR_LINE

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
VALID = HERE / "malformed" / "valid"
ADDRESS_SPACE = 4 << 30
TIMEOUT = 180
SMALL = {"BAARDA_MAX_INPUT_BYTES": str(64 << 20), "BAARDA_MAX_DOCUMENT_BYTES": str(16 << 20)}

_RUN = 45_000_000


def _stream(kind: str, data: bytes) -> bytes:
    if kind == "bz2":
        return bz2.compress(data, 9)
    if kind == "gz":
        return gzip.compress(data, 9, mtime=0)
    return lzma.compress(data)


def bomb(kind: str, head: bytes, fill: bytes, nbytes: int, tail: bytes = b"") -> bytes:
    """``head`` then ``fill`` repeated to about ``nbytes``, then ``tail``, compressed with
    ``kind`` (bz2, gz, xz) as concatenated streams."""
    piece = fill * max(1, (_RUN if len(fill) == 1 else 1 << 20) // len(fill))
    one = _stream(kind, piece)
    return (_stream(kind, head) + one * (nbytes // len(piece) + 1)
            + (_stream(kind, tail) if tail else b""))


def _limit():
    resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE, ADDRESS_SPACE))


def run_child(args, env=None, cwd=None, timeout=TIMEOUT):
    """``baarda ARGS`` in a child with an address-space limit and a timeout: (status, stderr,
    seconds)."""
    full = dict(os.environ, OPENBLAS_NUM_THREADS="1", **(env or {}))
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "baarda.cli", *args], capture_output=True, text=True,
                          env=full, cwd=cwd, timeout=timeout, preexec_fn=_limit)
    return proc.returncode, proc.stderr, time.perf_counter() - t0


def assert_refused(args, env=None, cwd=None, contains: str = ""):
    code, err, secs = run_child(args, env=env, cwd=cwd)
    where = f"{args}: exit {code} after {secs:.1f} s, stderr {err[-500:]!r}"
    assert code == 2, where
    assert ERROR_LINE.fullmatch(err), where
    assert not CONTROL.search(err[:-1]), where
    assert contains in err, where
    return err


GAMA_HEAD = b'<?xml version="1.0"?>\n<gama-local>\n<network>\n'

BOMBS = {
    # name: (file name, kind, head, fill, bytes, what the message says)
    "gkf-description-bz2": ("a.gkf.bz2", "bz2", GAMA_HEAD + b"<description>", b"a", 10 << 30,
                            "BAARDA_MAX_DOCUMENT_BYTES"),
    "json-string-bz2": ("a.json.bz2", "bz2", b'{"format": "baarda-block", "title": "', b"a", 10 << 30,
                        "BAARDA_MAX_DOCUMENT_BYTES"),
    "json-string-xz": ("a.json.xz", "xz", b'{"format": "baarda-block", "title": "', b"a", 2 << 30,
                       "BAARDA_MAX_DOCUMENT_BYTES"),
    "gkf-gzip": ("a.gkf.gz", "gz", GAMA_HEAD + b"<description>", b"a", 200 << 20,
                 "BAARDA_MAX_DOCUMENT_BYTES"),
    "bal-token-bz2": ("a.txt.bz2", "bz2", b"1 1 1\n", b"9", 1 << 30, "token longer than"),
    "bal-whitespace-bz2": ("a.txt.bz2", "bz2", b"2 2 2\n", b" ", 2 << 30, "BAARDA_MAX_INPUT_BYTES"),
    "gkf-nesting-bz2": ("a.gkf.bz2", "bz2", GAMA_HEAD, b"<a>", 1 << 20, "nested more than"),
    "gkf-elements-bz2": ("a.gkf.bz2", "bz2", GAMA_HEAD, b"<a/>", 9 << 20, "more than 2,000,000 elements"),
}


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n == "gkf-elements-bz2" else n
                                  for n in sorted(BOMBS)])      # 2 M elements: ~10-45 s
def test_bombs_refused_within_bounds(tmp_path, name):
    fname, kind, head, fill, nbytes, says = BOMBS[name]
    data = bomb(kind, head, fill, nbytes)
    assert len(data) < 1 << 20             # small files: the size is in the decompressed content
    (tmp_path / fname).write_bytes(data)
    assert_refused(["analyze", fname], env=SMALL, cwd=tmp_path, contains=says)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["gkf-description-bz2", "json-string-bz2", "bal-token-bz2",
                                  "gkf-nesting-bz2"])
def test_bombs_refused_at_the_default_ceilings(tmp_path, name):
    fname, kind, head, fill, nbytes, says = BOMBS[name]
    (tmp_path / fname).write_bytes(bomb(kind, head, fill, nbytes))
    env = {k: "" for k in SMALL}
    assert_refused(["analyze", fname], env=env, cwd=tmp_path, contains=says)


def test_number_reader_gathers_a_long_token_linearly(tmp_path):
    """A 64 MB token without whitespace (plain file): refused at its line, quickly (the reader
    appended each chunk to the whole token before: quadratic)."""
    from baarda.errors import InputError
    from baarda.io.source import MAX_TOKEN_BYTES, numbers

    p = tmp_path / "t.txt"
    with open(p, "wb") as f:
        f.write(b"1 2 3\n4 ")
        f.write(b"7" * (64 << 20))
    reader = numbers(p, chunk=1 << 16)
    t0 = time.perf_counter()
    with pytest.raises(InputError) as err:
        reader.take(10)
    reader.stream.close()
    assert time.perf_counter() - t0 < 20
    assert f"t.txt:2: a token longer than {MAX_TOKEN_BYTES >> 20} MiB" in str(err.value)


def test_a_device_is_refused(tmp_path):
    (tmp_path / "z.gkf").symlink_to("/dev/zero")
    assert_refused(["analyze", "z.gkf"], cwd=tmp_path, contains="is a character device, not a file")


def test_a_directory_named_like_a_file_is_refused(tmp_path):
    (tmp_path / "d.json").mkdir()
    assert_refused(["analyze", "d.json"], cwd=tmp_path, contains="directory")


def _feed(fifo: Path, data: bytes | None, stop: threading.Event):
    """Write ``data`` into the named pipe (None: zeros until the reader goes away or ``stop``)."""
    try:
        with open(fifo, "wb") as f:
            if data is not None:
                f.write(data)
                return
            block = b"0" * (1 << 20)
            while not stop.is_set():
                f.write(block)
    except (BrokenPipeError, OSError):
        pass


@pytest.mark.parametrize("compressed", [False, True])
def test_a_named_pipe_is_read_once(tmp_path, compressed):
    """A FIFO (no extension, compressed or not) is sniffed and read from one reading of it."""
    fifo = tmp_path / "plan"
    os.mkfifo(fifo)
    data = (REPO / "data" / "demo-levelling.gkf").read_bytes()
    stop = threading.Event()
    t = threading.Thread(target=_feed, args=(fifo, bz2.compress(data) if compressed else data, stop),
                         daemon=True)
    t.start()
    code, err, _ = run_child(["analyze", str(fifo)], cwd=tmp_path)
    stop.set()
    assert code == 0, err


def test_an_endless_pipe_is_refused_at_the_ceiling(tmp_path):
    fifo = tmp_path / "endless"
    os.mkfifo(fifo)
    stop = threading.Event()
    t = threading.Thread(target=_feed, args=(fifo, None, stop), daemon=True)
    t.start()
    try:
        assert_refused(["analyze", str(fifo)], env=SMALL, cwd=tmp_path, contains="the pipe holds more than 16 MiB")
    finally:
        stop.set()
        try:                      # unblock a writer still waiting for a reader
            os.close(os.open(fifo, os.O_RDONLY | os.O_NONBLOCK))
        except OSError:
            pass
        t.join(10)


def test_process_substitution(tmp_path):
    """``baarda analyze <(cat plan.gkf)``: the shell gives a pipe /dev/fd/N."""
    gkf = REPO / "data" / "demo-levelling.gkf"
    proc = subprocess.run(["bash", "-c", f'"{sys.executable}" -m baarda.cli analyze <(cat "{gkf}")'],
                          capture_output=True, text=True, timeout=TIMEOUT, cwd=tmp_path,
                          env=dict(os.environ, OPENBLAS_NUM_THREADS="1"))
    assert proc.returncode == 0, proc.stderr
    assert "levelling network" in proc.stdout


def test_ceiling_settings_are_checked(tmp_path):
    gkf = REPO / "data" / "demo-levelling.gkf"
    code, err, _ = run_child(["analyze", str(gkf)], env={"BAARDA_MAX_INPUT_BYTES": "lots"}, cwd=tmp_path)
    assert code == 2 and err.endswith(": BAARDA_MAX_INPUT_BYTES must be a positive number of bytes (got 'lots')\n"), err
    assert err.count("\n") == 1
    # a plain file over the document ceiling is refused while it is read
    code, err, _ = run_child(["analyze", str(gkf)], env={"BAARDA_MAX_DOCUMENT_BYTES": "1000"}, cwd=tmp_path)
    assert code == 2 and "more than 1,000 bytes of content, the ceiling (BAARDA_MAX_DOCUMENT_BYTES)" in err, err


def test_ceiling_context_is_tighter_only():
    from baarda.io.source import ceiling, max_document_bytes, max_input_bytes

    base = max_input_bytes()
    with ceiling(1000):
        assert max_input_bytes() == 1000 and max_document_bytes() == 1000
        with ceiling(10 ** 12):
            assert max_input_bytes() == 1000
    assert max_input_bytes() == base


# small files read beside an input (a truth file, a hypothesis file, a simulation recipe): at most
# BAARDA_MAX_SMALL_BYTES (16 MiB) decompressed, so the default ceiling is cheap to reach
LEVELLING = VALID / "levelling-valid.json"
SMALL_FILES = {
    # name: (argv, file name, compression, head, fill)
    "truth-beside-bz2": (["analyze", "a.json"], "a.truth.json", "bz2",
                         b'{"format": "baarda-truth", "title": "', b"a"),
    "truth-given-xz": (["analyze", "a.json", "--truth", "t.json.xz"], "t.json.xz", "xz",
                       b'{"format": "baarda-truth", "errors": [{"kind": "', b"a"),
    "hypothesis-lines-gz": (["test", "a.json", "-H", "file:h.txt"], "h.txt", "gz", b"", b"0 0 1\n"),
    "recipe-bz2": (["simulate", "s.json", "--recipe", "r.json.bz2"], "r.json.bz2", "bz2", b'{"title": "', b"a"),
}


@pytest.mark.parametrize("name", sorted(SMALL_FILES))
def test_small_file_bombs_refused_at_the_default_ceiling(tmp_path, name):
    """A 2 GB (64 MB of lines) truth, hypothesis or recipe file in a few KB: refused at 16 MiB of decompressed
    text, one line naming the file and the setting, within the child's 4 GiB and seconds."""
    argv, fname, kind, head, fill = SMALL_FILES[name]
    data = bomb(kind, head, fill, 2 << 30 if len(fill) == 1 else 64 << 20)
    assert len(data) < 1 << 20
    (tmp_path / "a.json").write_bytes(LEVELLING.read_bytes())
    (tmp_path / fname).write_bytes(data)
    env = {k: "" for k in (*SMALL, "BAARDA_MAX_SMALL_BYTES")}
    err = assert_refused(argv, env=env, cwd=tmp_path,
                         contains="more than 16 MiB of decompressed content, the ceiling (BAARDA_MAX_SMALL_BYTES)")
    assert err.startswith(f"baarda: error: {fname}:0: "), err


@pytest.mark.parametrize("kind", ["truth", "hypothesis", "recipe"])
def test_small_file_over_its_ceiling_plain(tmp_path, kind, monkeypatch, capsys):
    """An uncompressed file over BAARDA_MAX_SMALL_BYTES (here 1,000 bytes) is refused as it is read."""
    from baarda.cli import main

    (tmp_path / "a.json").write_bytes(LEVELLING.read_bytes())
    (tmp_path / "f.txt").write_bytes(b" " * 5000)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("BAARDA_MAX_SMALL_BYTES", "1000")
    argv = {"truth": ["analyze", "a.json", "--truth", "f.txt"], "hypothesis": ["test", "a.json", "-H", "file:f.txt"],
            "recipe": ["simulate", "s.json", "--recipe", "f.txt"]}[kind]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err == ("baarda: error: f.txt:0: more than 1,000 bytes of content, the ceiling "
                   "(BAARDA_MAX_SMALL_BYTES)\n"), err
    assert not (tmp_path / "s.json").exists()


def test_small_files_may_come_compressed(tmp_path):
    """The bound reading is the inputs' own: a gzip hypothesis file reads as its text."""
    (tmp_path / "a.json").write_bytes(LEVELLING.read_bytes())
    (tmp_path / "h.txt.gz").write_bytes(gzip.compress(b"0 0 1\n"))
    code, err, _ = run_child(["test", "a.json", "-H", "file:h.txt.gz"], cwd=tmp_path)
    assert code == 0, err


def test_small_ceiling_is_at_most_the_document_ceiling(monkeypatch):
    from baarda.io.source import MAX_SMALL_BYTES, max_small_bytes

    monkeypatch.delenv("BAARDA_MAX_SMALL_BYTES", raising=False)
    monkeypatch.setenv("BAARDA_MAX_DOCUMENT_BYTES", "5000")
    assert MAX_SMALL_BYTES == 16 << 20 and max_small_bytes() == 5000
    monkeypatch.setenv("BAARDA_MAX_SMALL_BYTES", "300")
    assert max_small_bytes() == 300
