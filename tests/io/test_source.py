"""Compressed input (gzip, bzip2, xz) for every format, recognised by extension and by content.

Reference: the same file uncompressed — the problem read from the compressed copy must be the
same, number for number. Errors name the file as given, with the line of the decompressed text.
"""

from __future__ import annotations

import bz2
import gzip
import lzma
import shutil
from pathlib import Path

import numpy as np
import pytest

from baarda.build import read_problem
from baarda.cli import main
from baarda.errors import InputError
from baarda.io import detect_format
from baarda.io.source import Numbers, compression, open_binary, read_text
from baarda.model.sfm import initial_cost

from tests.extdata import EXTDATA, require_extdata

HERE = Path(__file__).resolve().parents[1]
VALID = HERE / "malformed" / "valid"
DATA = HERE.parent / "data"
COMPRESS = {".gz": gzip.compress, ".bz2": bz2.compress, ".xz": lzma.compress}
SEEDS = {"bal": VALID / "bal-valid.txt", "bundler": VALID / "bundler-valid.out",
         "gama": DATA / "demo-levelling.gkf", "native": DATA / "demo-block.json"}


def compressed_copy(src: Path, dest: Path, ext: str) -> Path:
    dest.write_bytes(COMPRESS[ext](src.read_bytes()))
    return dest


def same_problem(a, b):
    assert a.params.labels == b.params.labels
    assert np.array_equal(a.params.x0, b.params.x0)
    assert np.array_equal(a.l, b.l)
    assert np.array_equal(a.cov.sigma(), b.cov.sigma())
    assert a.info.ids == b.info.ids
    assert np.array_equal(a.info.line, b.info.line)


@pytest.mark.parametrize("ext", list(COMPRESS))
@pytest.mark.parametrize("fmt", list(SEEDS))
def test_each_format_compressed_each_way(tmp_path, fmt, ext):
    src = SEEDS[fmt]
    plain = read_problem(src)
    named = compressed_copy(src, tmp_path / (src.name + ext), ext)
    assert detect_format(named) == fmt
    assert compression(named) == {".gz": "gzip", ".bz2": "bzip2", ".xz": "xz"}[ext]
    same_problem(read_problem(named), plain)
    # by content alone: the name says nothing about the compression
    hidden = compressed_copy(src, tmp_path / src.name, ext)
    assert detect_format(hidden) == fmt
    same_problem(read_problem(hidden), plain)


@pytest.mark.parametrize("ext", list(COMPRESS))
def test_colmap_text_model_compressed(tmp_path, ext):
    src = VALID / "colmap-valid"
    plain = read_problem(src)
    d = tmp_path / "model"
    d.mkdir()
    for f in src.iterdir():
        compressed_copy(f, d / (f.name + ext), ext)
    assert detect_format(d) == "colmap"
    same_problem(read_problem(d), plain)
    assert detect_format(d / f"images.txt{ext}") == "colmap"
    same_problem(read_problem(d / f"points3D.txt{ext}"), plain)


@pytest.mark.parametrize("ext", list(COMPRESS))
def test_control_csv_compressed(tmp_path, ext):
    ctrl = VALID / "control-valid.csv"
    plain = read_problem(SEEDS["bal"], control=ctrl)
    same_problem(read_problem(SEEDS["bal"], control=compressed_copy(ctrl, tmp_path / ("c.csv" + ext), ext)), plain)
    same_problem(read_problem(SEEDS["bal"], control=compressed_copy(ctrl, tmp_path / "c.csv", ext)), plain)


def test_error_names_the_file_as_given_with_the_decompressed_line(tmp_path, capsys):
    lines = SEEDS["bal"].read_text().splitlines()
    lines[7] = lines[7].rsplit(" ", 1)[0] + " 12.0x"
    bad = tmp_path / "problem.txt.bz2"
    bad.write_bytes(bz2.compress(("\n".join(lines) + "\n").encode()))
    with pytest.raises(InputError) as exc:
        read_problem(bad)
    assert exc.value.path == str(bad) and exc.value.line == 8
    assert str(exc.value).startswith(f"{bad}:8: observation 7: image coordinates: '12.0x' is not a number")
    assert main(["analyze", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"baarda: error: {bad}:8: ") and err.count("\n") == 1


@pytest.mark.parametrize("ext", list(COMPRESS))
@pytest.mark.parametrize("damage", ["truncate", "flip"])
def test_corrupt_compressed_file_is_an_input_error(tmp_path, capsys, ext, damage):
    data = bytearray(COMPRESS[ext](SEEDS["bal"].read_bytes()))
    if damage == "truncate":
        data = data[:len(data) // 2]
    else:
        for k in range(len(data) // 3, len(data) // 3 + 40):
            data[k] ^= 0x5A
    bad = tmp_path / ("problem.txt" + ext)
    bad.write_bytes(bytes(data))
    with pytest.raises(InputError) as exc:
        read_problem(bad)
    assert exc.value.path == str(bad)
    assert main(["analyze", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"baarda: error: {bad}:") and err.count("\n") == 1 and "Traceback" not in err


def test_extension_that_lies_about_compression(tmp_path):
    fake = tmp_path / "problem.txt.gz"
    shutil.copy(SEEDS["bal"], fake)
    with pytest.raises(InputError, match="gzip-compressed"):
        read_problem(fake)


def test_numbers_across_chunk_boundaries_and_comments(tmp_path):
    """Tiny chunks: every number and line comes out as Python reads them."""
    text = "# a comment\n1 2.5\n\n  -3e2\t4\n# another 7\n5 nan\n6"
    f = tmp_path / "n.txt"
    f.write_text(text)
    with open_binary(f) as s:
        num = Numbers(f, s, comment="#", chunk=3)
        vals, lines = num.take_rest()
    assert vals[:5].tolist() == [1, 2.5, -300, 4, 5]
    assert np.isnan(vals[5]) and vals[6] == 6 and vals.size == 7
    assert lines.tolist() == [2, 2, 4, 4, 6, 6, 7]
    assert num.text(5) == "nan"
    assert read_text(f) == text
    # all on one line, longer than a chunk: cut between numbers
    one = tmp_path / "one.txt"
    one.write_text(" ".join(f"{k}.25" for k in range(3000)))
    with open_binary(one) as s:
        vals, lines = Numbers(one, s, chunk=100).take_rest()
    assert vals.tolist() == [k + 0.25 for k in range(3000)] and set(lines.tolist()) == {1}


@pytest.mark.parametrize("name,ncam,npt,nobs,cost", [
    ("problem-21-11315-pre.txt.bz2", 21, 11315, 36455, 4413239.314),
    ("problem-16-22106-pre.txt.bz2", 16, 22106, 83718, 4185659.518),
])
def test_real_bal_files_as_distributed(name, ncam, npt, nobs, cost):
    path = require_extdata(EXTDATA / "bal" / name)
    assert detect_format(path) == "bal"
    p = read_problem(path)
    blk = p.geometry.as_dict()
    assert len(blk["images"]) == ncam and len(p.points.ids) == npt and p.n == 2 * nobs
    assert initial_cost(p) == pytest.approx(cost, rel=1e-9)
    # the same numbers as Python's own parser of the decompressed text
    toks = bz2.decompress(path.read_bytes()).split()
    assert np.array_equal(p.l, np.array(toks[3:3 + 4 * nobs], dtype=float).reshape(nobs, 4)[:, 2:].ravel())
