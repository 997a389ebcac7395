"""Bundler files as Bundler-like tools write them (issue 26, item 3): rotations printed to 6
significant digits (printf's %g) and one point listed twice in one image under two keys.

The peer is pycolmap's Ceres on the same block (f, k1, k2 refined per camera, as Bundler and
BAL define the problem; the duplicate keys two residuals of their own, as COLMAP takes them).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from baarda.adjust import adjust
from baarda.build import build
from baarda.errors import InputError
from baarda.io.bundler import PRINT_TOL, read_bundler

F, K1, K2 = 800.0, -0.02, 0.003


def write_bundler(path, seed: int = 2, duplicate: bool = True, digits: str = "g", bend: float = 0.0):
    """Six cameras around a scene of 50 points, every number printed with ``%{digits}``; point 7
    listed in image 2 a second time under another key (3 px off) when ``duplicate``; camera 4's
    rotation bent by ``bend`` (an entry changed). Returns the rotations as printed."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(-2, 2, size=(50, 3))
    D = np.diag([1.0, -1.0, -1.0])
    cams, printed, views = [], [], {p: [] for p in range(50)}
    for k in range(6):
        Rc = Rotation.random(random_state=rng).as_matrix()
        C = Rc.T @ np.array([0.0, 0.0, -10.0])
        R, t = D @ Rc, D @ (-Rc @ C)
        R[0, 0] += bend if k == 4 else 0.0
        fmt = lambda v: format(float(v), digits)  # noqa: E731
        Rp = np.array([[float(fmt(v)) for v in row] for row in R])
        printed.append(Rp)
        cams.append(f"{fmt(F)} {fmt(K1)} {fmt(K2)}\n" + "\n".join(" ".join(fmt(v) for v in row) for row in R)
                    + "\n" + " ".join(fmt(v) for v in t))
        P = (R @ X.T).T + t
        p = -P[:, :2] / P[:, 2:3]
        r2 = (p ** 2).sum(1, keepdims=True)
        xy = F * (1 + K1 * r2 + K2 * r2 ** 2) * p + rng.normal(scale=0.5, size=p.shape)
        for i in range(50):
            views[i].append((k, 100 + i, xy[i]))
            if duplicate and k == 2 and i == 7:
                views[i].append((k, 900, xy[i] + 3.0))
    pts = []
    for i in range(50):
        v = views[i]
        pts.append(" ".join(format(c, "g") for c in X[i]) + "\n255 255 255\n" + f"{len(v)} "
                   + " ".join(f"{k} {key} {format(a, 'g')} {format(b, 'g')}" for k, key, (a, b) in v))
    path.write_text("# Bundle file v0.3\n6 50\n" + "\n".join(cams) + "\n" + "\n".join(pts) + "\n")
    return printed


def test_the_printing_bound_holds_and_is_reached():
    """|RᵀR − I| of rotations printed to 6 digits: never beyond PRINT_TOL (200,000 random
    rotations), and beyond the old 1e-6 for a good share of them (so the bound is needed)."""
    R = Rotation.random(200_000, random_state=1).as_matrix()
    e = np.floor(np.log10(np.abs(R), where=R != 0, out=np.zeros_like(R)))
    Rp = np.round(R / 10 ** (e - 5)) * 10 ** (e - 5)             # 6 significant digits
    err = np.abs(np.einsum("nki,nkj->nij", Rp, Rp) - np.eye(3)).max(axis=(1, 2))
    assert err.max() <= PRINT_TOL
    assert (err > 1e-6).mean() > 0.01
    assert PRINT_TOL == pytest.approx(2 * math.sqrt(3) * 5e-7, rel=1e-6)


def test_six_digit_rotations_and_duplicate_keys_adjust_as_ceres(tmp_path):
    """The file is read (rotations replaced by the nearest rotation, said so; the point twice in
    image 2 two observations told apart by their keys) and adjusts to Ceres's optimum."""
    pytest.importorskip("pycolmap")
    from bench.bench_solve import ceres

    path = tmp_path / "bundle.out"
    printed = write_bundler(path)
    errs = [np.abs(R.T @ R - np.eye(3)).max() for R in printed]
    assert max(errs) > 1e-6                                     # the class of the issue
    block = read_bundler(path)
    assert block.obs_image.size == 6 * 50 + 1
    assert block.extra["duplicate_keypoints"] == {"points": 1, "observations": 1}
    note = block.extra["reader_notes"][0]
    assert note.startswith("6 rotation matrix(es) orthonormal only to the printed digits")
    for im in block.images:
        from baarda.observations.rotation import R_from_rodrigues
        R = R_from_rodrigues(np.asarray(im.rodrigues))
        assert np.abs(R.T @ R - np.eye(3)).max() < 1e-14
        assert np.abs(R - printed[int(im.id)]).max() < 3e-6        # the nearest rotation: close
    problem = build(block)
    assert not problem.notes.local_defects
    adj = adjust(problem)
    assert adj.converged
    _, cost, _, n, _ = ceres(block)
    assert n == 6 * 50 + 1
    assert 0.5 * adj.vPv == pytest.approx(cost, rel=1e-8)


def test_same_key_twice_and_rotations_beyond_printing_are_refused(tmp_path):
    path = tmp_path / "bent.out"
    write_bundler(path, bend=1e-5)
    with pytest.raises(InputError, match=r"camera 4: not a rotation matrix .*beyond the 1.7e-06"):
        read_bundler(path)
    path = tmp_path / "same-key.out"
    write_bundler(path, duplicate=False)
    text = path.read_text().splitlines()
    k = next(j for j, s in enumerate(text) if s.startswith("6 0 100 "))   # point 0's views
    parts = text[k].split()
    text[k] = "7 " + " ".join(parts[1:]) + " 2 " + parts[10] + " 10 20"    # image 2, its key again
    path.write_text("\n".join(text) + "\n")
    with pytest.raises(InputError, match="twice"):
        read_bundler(path)


def test_full_precision_rotations_are_taken_as_they_are(tmp_path):
    path = tmp_path / "full.out"
    write_bundler(path, digits=".17g", duplicate=False)
    block = read_bundler(path)
    assert "reader_notes" not in block.extra


def test_cli_says_what_it_repaired(tmp_path, capsys):
    from baarda.cli import main

    path = tmp_path / "bundle.out"
    write_bundler(path)
    assert main(["analyze", str(path), "--top", "1"]) in (0, 1)
    err = capsys.readouterr().err
    assert f"baarda: warning: {path}: 6 rotation matrix(es) orthonormal only to the printed digits" in err
