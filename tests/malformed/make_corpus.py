"""Recipe of the bad-input corpus: ``python tests/malformed/make_corpus.py`` rewrites it.

``valid/`` holds small valid blocks (BAL, Bundler, COLMAP text, a control CSV, a levelling
loop as Gama XML and native JSON) simulated here with noise; every other file is one of them
with one thing broken. What each file must make baarda say is listed in ``README.md``.
"""

from __future__ import annotations

import shutil
import struct
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
VALID = HERE / "valid"


def rodrigues_R(rho):
    th = np.linalg.norm(rho)
    if th < 1e-12:
        return np.eye(3)
    k = rho / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


def simulate(sign: float, seed: int = 1, ncam: int = 3, npt: int = 8):
    """Cameras along x at height ∓6 looking at points in a cube (±2); pixel noise σ = 0.5.

    sign −1: BAL/Bundler (camera looks down −z), +1: COLMAP (down +z). Returns the cameras
    (ρ, t, R), noisy approximate points and the image points (camera, point, x, y) relative
    to the principal point, f = 500 px, k1 = 0.01.
    """
    rng = np.random.default_rng(seed)
    X = rng.uniform(-2, 2, (npt, 3))
    cams = []
    for c in range(ncam):
        rho = rng.normal(0, 0.03, 3)
        R = rodrigues_R(rho)
        C = np.array([-1.0 + c, 0.2 * c, 6.0 * -sign])
        cams.append((rho, -R @ C, R))
    obs = []
    for c, (rho, t, R) in enumerate(cams):
        for p in range(npt):
            P = R @ X[p] + t
            u = sign * P[:2] / P[2]
            r2 = u @ u
            obs.append((c, p, *(500.0 * (1 + 0.01 * r2) * u + rng.normal(0, 0.5, 2))))
    Xn = X + rng.normal(0, 0.01, X.shape)
    return cams, Xn, obs


def bal_text(cams, X, obs, header=None) -> str:
    lines = [header or f"{len(cams)} {len(X)} {len(obs)}"]
    lines += [f"{c} {p} {x:.6f} {y:.6f}" for c, p, x, y in obs]
    for rho, t, _ in cams:
        lines += [f"{v:.12g}" for v in (*rho, *t, 500.0, 0.01, 0.0)]
    lines += [f"{v:.12g}" for v in X.ravel()]
    return "\n".join(lines) + "\n"


def bundler_text(cams, X, obs) -> str:
    lines = ["# Bundle file v0.3", f"{len(cams)} {len(X)}"]
    for rho, t, R in cams:
        lines.append("500 0.01 0")
        lines += [" ".join(f"{v:.12g}" for v in row) for row in R]
        lines.append(" ".join(f"{v:.12g}" for v in t))
    for p in range(len(X)):
        lines.append(" ".join(f"{v:.12g}" for v in X[p]))
        lines.append("255 255 255")
        views = [(c, x, y) for c, q, x, y in obs if q == p]
        lines.append(f"{len(views)} " + " ".join(f"{c} {p} {x:.6f} {y:.6f}" for c, x, y in views))
    return "\n".join(lines) + "\n"


def colmap_files(cams, X, obs) -> dict[str, str]:
    def quat(R):
        w = np.sqrt(max(1 + np.trace(R), 1e-12)) / 2
        return np.array([w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w),
                         (R[1, 0] - R[0, 1]) / (4 * w)])

    camera = "# Camera list\n1 SIMPLE_RADIAL 640 480 500 320 240 0.01\n"
    images = ["# Image list"]
    slots = {}
    for c, (rho, t, R) in enumerate(cams):
        images.append(f"{c + 1} " + " ".join(f"{v:.12g}" for v in (*quat(R), *t)) + f" 1 img{c + 1}.jpg")
        mine = [(p, x, y) for cc, p, x, y in obs if cc == c]
        images.append(" ".join(f"{x + 320:.6f} {y + 240:.6f} {p + 1}" for p, x, y in mine))
        for j, (p, _, _) in enumerate(mine):
            slots[(c, p)] = j
    points = ["# 3D point list"]
    for p in range(len(X)):
        track = " ".join(f"{c + 1} {slots[(c, p)]}" for c in range(len(cams)) if (c, p) in slots)
        points.append(f"{p + 1} " + " ".join(f"{v:.12g}" for v in X[p]) + f" 128 128 128 0.5 {track}")
    return {"cameras.txt": camera, "images.txt": "\n".join(images) + "\n",
            "points3D.txt": "\n".join(points) + "\n"}


GKF = """<?xml version="1.0"?>
<gama-local xmlns="http://www.gnu.org/software/gama/gama-local">
<network><parameters sigma-apr="1" sigma-act="apriori"/>
<points-observations>
<point id="A" z="100" fix="z"/><point id="B" z="101" adj="z"/><point id="C" z="102" adj="z"/>
<height-differences>
<dh from="A" to="B" val="1.002" stdev="1"/>
<dh from="B" to="C" val="0.999" stdev="1"/>
<dh from="C" to="A" val="-2.003" stdev="1"/>
</height-differences>
</points-observations></network></gama-local>
"""

NATIVE = """{
 "format": "baarda-block",
 "version": 1,
 "kind": "levelling",
 "points": [
  {"id": "A", "H": 100.0, "status": "fixed"},
  {"id": "B", "H": 101.0, "status": "adjusted"},
  {"id": "C", "H": 102.0, "status": "adjusted"}
 ],
 "observations": [
  {"from": "A", "to": "B", "dh": 1.002, "sigma": 0.001},
  {"from": "B", "to": "C", "dh": 0.999, "sigma": 0.001},
  {"from": "C", "to": "A", "dh": -2.003, "sigma": 0.001}
 ]
}
"""


def write(name: str, text: str):
    (HERE / name).write_text(text)


def write_defect(name: str, text: str):
    """Local defects are findings, not bad input: these files go to tests/defects/."""
    (HERE.parent / "defects" / name).write_text(text)


def write_dir(name: str, files: dict[str, str]):
    d = HERE / name
    if d.exists():
        shutil.rmtree(d)
    d.mkdir()
    for f, t in files.items():
        (d / f).write_text(t)


def edited(lines: list[str], changes: dict[int, str]) -> str:
    out = list(lines)
    for k, v in changes.items():
        out[k] = v
    return "\n".join(out) + "\n"


def token_changed(line: str, k: int, value: str) -> str:
    t = line.split()
    t[k] = value
    return " ".join(t)


def main():
    VALID.mkdir(exist_ok=True)
    cams, X, obs = simulate(-1.0, npt=16)
    bal = bal_text(cams, X, obs)
    (VALID / "bal-valid.txt").write_text(bal)
    bun = bundler_text(cams, X, obs)
    (VALID / "bundler-valid.out").write_text(bun)
    ccams, cX, cobs = simulate(+1.0, seed=2)
    col = colmap_files(ccams, cX, cobs)
    write_dir("valid/colmap-valid", col)
    (VALID / "control-valid.csv").write_text(
        "id,X,Y,Z,sx,sy,sz\n" + "".join(f"{p},{X[p, 0]:.6f},{X[p, 1]:.6f},{X[p, 2]:.6f},0.01,0.01,0.02\n"
                                        for p in range(4)))
    (VALID / "levelling-valid.gkf").write_text(GKF)
    (VALID / "levelling-valid.json").write_text(NATIVE)

    bl = bal.splitlines()
    n_obs = len(obs)

    # ---- BAL
    write("bal-empty.txt", "")
    write("bal-header-short.txt", f"3 {len(X)}\n")
    write("bal-header-float.txt", bal.replace(f"3 {len(X)} {n_obs}", f"3 {len(X)} {n_obs}.5", 1))
    write("bal-empty-block.txt", "0 0 0\n")
    write("bal-truncated-params.txt", "\n".join(bl[:1 + n_obs + 12]) + "\n")
    write("bal-truncated-points.txt", "\n".join(bl[:-5]) + "\n")
    write("bal-nan.txt", edited(bl, {5: "1 4 nan 12.5"}))
    write("bal-inf-point.txt", edited(bl, {len(bl) - 2: "inf"}))
    write("bal-garbage.txt", edited(bl, {7: "0 6 12.0x 3.5"}))
    write("bal-camera-range.txt", edited(bl, {3: "7 2 10.0 20.0"}))
    write("bal-point-range.txt", edited(bl, {4: f"0 {len(X)} 10.0 20.0"}))
    write("bal-duplicate-obs.txt", edited(bl, {3: bl[2]}))
    write("bal-focal-zero.txt", edited(bl, {1 + n_obs + 6: "0"}))
    write("bal-extra.txt", bal + "1.0\n2.0\n")
    first = bl[2].split()
    write("bal-split-obs.txt", "\n".join(bl[:2] + [" ".join(first[:3]), first[3]] + bl[3:]) + "\n")
    # point 5 seen by image 0 only
    write_defect("bal-one-view.txt", bal_text(cams, X, [o for o in obs if not (o[1] == 5 and o[0] > 0)]))
    # image 2 sees two points only
    write_defect("bal-camera-two-points.txt", bal_text(cams, X, [o for o in obs if not (o[0] == 2 and o[1] > 1)]))
    # two blocks sharing no point: images 0, 1 see points 0-3, images 2, 3 points 4-7
    c4, X4, o4 = simulate(-1.0, seed=3, ncam=4)
    write("bal-disconnected.txt", bal_text(c4, X4, [o for o in o4 if (o[0] < 2) == (o[1] < 4)]))
    # the pattern of GTSAM's dubrovnik-3-7: 19 image points, 38 equations for 48 unknowns
    pattern = {(0, 0), (1, 0), (2, 0), (0, 1), (1, 1), (0, 2), (1, 2), (2, 2), (0, 3), (1, 3), (2, 3),
               (0, 4), (1, 4), (2, 4), (0, 5), (1, 5), (0, 6), (1, 6), (2, 6)}
    c3, X7, o3 = simulate(-1.0, seed=4, npt=7)
    write_defect("bal-underdetermined.txt", bal_text(c3, X7, [o for o in o3 if (o[0], o[1]) in pattern]))

    # ---- Bundler
    ul = bun.splitlines()
    write("bundler-version.out", bun.replace("v0.3", "v0.2", 1))
    write("bundler-truncated.out", "\n".join(ul[:-4]) + "\n")
    write("bundler-not-rotation.out", edited(ul, {3: "1.5 0 0"}))
    write("bundler-view-range.out", edited(ul, {len(ul) - 1: token_changed(ul[-1], 1, "9")}))
    write("bundler-nan.out", edited(ul, {2 + 3 * 5: "nan 0.1 0.2"}))
    write_defect("bundler-one-view.out", edited(ul, {len(ul) - 1: "1 " + " ".join(ul[-1].split()[1:5])}))
    write("bundler-unreconstructed-view.out", edited(ul, {k: "0 0 0" for k in range(2, 7)}))
    write("bundler-empty.out", "# Bundle file v0.3\n0 0\n")

    # ---- COLMAP text
    cl = {k: v.splitlines() for k, v in col.items()}
    write_dir("colmap-unknown-model", {**col, "cameras.txt": col["cameras.txt"].replace("SIMPLE_RADIAL",
                                                                                        "EQUIRECTANGULAR")})
    write_dir("colmap-param-count", {**col, "cameras.txt": col["cameras.txt"].replace("SIMPLE_RADIAL", "RADIAL")
                                     .replace(" 0.01\n", "\n")})
    il = cl["images.txt"]
    write_dir("colmap-duplicate-image", {**col, "images.txt": edited(il, {3: "1" + il[3][il[3].index(" "):]})})
    write_dir("colmap-quaternion", {**col, "images.txt": edited(
        il, {1: token_changed(il[1], 1, str(2 * float(il[1].split()[1]) + 1))})})
    pl = cl["points3D.txt"]
    write_dir("colmap-track-mismatch", {**col, "points3D.txt": edited(
        pl, {2: token_changed(pl[2], -1, str(int(pl[2].split()[-1]) + 1))})})
    write_dir("colmap-missing-camera", {**col, "images.txt": edited(il, {5: token_changed(il[5], 8, "7")})})
    write_dir("colmap-missing-file", {k: v for k, v in col.items() if k != "points3D.txt"})
    write_dir("colmap-nan", {**col, "points3D.txt": edited(pl, {4: token_changed(pl[4], 2, "NaN")})})
    write_dir("colmap-truncated-images", {**col, "images.txt": "\n".join(il[:-1]) + "\n"})
    write_dir("colmap-duplicate-point", {**col, "points3D.txt": col["points3D.txt"] + pl[3] + "\n"})
    # binary: a cameras.bin cut short in its parameters
    bdir = HERE / "colmap-bin-truncated"
    if bdir.exists():
        shutil.rmtree(bdir)
    bdir.mkdir()
    (bdir / "cameras.bin").write_bytes(struct.pack("<QIiQQ", 1, 1, 2, 640, 480) + struct.pack("<2d", 500.0, 320.0))
    (bdir / "images.bin").write_bytes(struct.pack("<Q", 0))
    (bdir / "points3D.bin").write_bytes(struct.pack("<Q", 0))

    # ---- control CSV (analysed with valid/bal-valid.txt)
    write("control-sigma-zero.csv", "id,X,Y,Z,sx,sy,sz\n0,0.1,0.2,0.3,0.01,0,0.02\n")
    write("control-unknown-point.csv", "id,X,Y,Z,sx,sy,sz\n0,0.1,0.2,0.3,0.01,0.01,0.02\n99,0,0,0,1,1,1\n")
    write("control-header.csv", "name,E,N,H\n0,0.1,0.2,0.3\n")
    write("control-duplicate.csv", "id,X,Y,Z,sx,sy,sz\n1,0,0,0,1,1,1\n2,0,0,0,1,1,1\n1,0,0,0,1,1,1\n")

    # ---- native JSON and Gama
    write("native-syntax.json", NATIVE.replace('"H": 101.0,', '"H": 101.0'))
    write("native-version.json", NATIVE.replace('"version": 1', '"version": 2'))
    write("native-sigma-zero.json", NATIVE.replace('"dh": 0.999, "sigma": 0.001', '"dh": 0.999, "sigma": 0'))
    write("native-unknown-point.json", NATIVE.replace('"to": "C", "dh": 0.999', '"to": "Q", "dh": 0.999'))
    write("gama-stdev-zero.gkf", GKF.replace('val="0.999" stdev="1"', 'val="0.999" stdev="0"'))
    write("gama-nan.gkf", GKF.replace('val="-2.003"', 'val="nan"'))
    write("gama-unknown-point.gkf", GKF.replace('to="C" val="0.999"', 'to="Q" val="0.999"'))
    write("gama-free-defect.gkf", GKF.replace('fix="z"', 'adj="z"'))
    write("gama-truncated.gkf", GKF[:200])
    issue12(bl, ul, col)


def issue12(bl: list[str], ul: list[str], col: dict[str, str]):
    """The minimal causes of issue 12's fuzzing (tests/test_fuzz_contract.py): overflow, huge
    and Unicode digits, deep nesting, control characters in ids, σ and values double precision
    cannot adjust, a singular normal matrix, unreadable CSV."""
    nl = NATIVE.splitlines()
    # JSON nested 1,000 deep (the decoder's RecursionError)
    write("native-nested.json", NATIVE.replace('"dh": 0.999', '"dh": ' + "[" * 1000 + "0.999" + "]" * 1000))
    # integers of 400 and 5,000 digits (Python's int-from-string limit, int → float overflow)
    write("native-int-400.json", NATIVE.replace('"dh": 0.999', '"dh": ' + "9" * 400))
    write("native-int-5000.json", NATIVE.replace('"dh": 0.999', '"dh": 1' + "0" * 5000))
    write("native-sigma-tiny.json", NATIVE.replace('"dh": 0.999, "sigma": 0.001', '"dh": 0.999, "sigma": 1e-300'))
    write("native-value-huge.json", NATIVE.replace('"dh": 0.999', '"dh": 1e308'))
    # an id with a newline and an escape sequence: the message must stay one line
    write("native-id-control.json", NATIVE.replace('"to": "C", "dh": 0.999',
                                                   '"to": "Q\\n\\u001b[2Jforged", "dh": 0.999'))
    assert len(nl) > 10
    write("gama-value-huge.gkf", GKF.replace('val="0.999"', 'val="1e308"'))
    write("gama-sigma-apr-tiny.gkf", GKF.replace('sigma-apr="1"', 'sigma-apr="1e-300"'))
    write("native-sigma0-huge.json", NATIVE.replace('"version": 1,', '"version": 1,\n "sigma0": 1e300,'))
    write("gama-stdev-tiny.gkf", GKF.replace('val="0.999" stdev="1"', 'val="0.999" stdev="1e-300"'))
    write("gama-int-5000.gkf", GKF.replace('val="0.999"', 'val="1' + "0" * 5000 + '"'))
    write("gama-unicode-digit.gkf", GKF.replace('val="0.999"', 'val="\u2460"'))
    write("gama-id-newline.gkf", GKF.replace('to="C" val="0.999"', 'to="Q&#10;forged line" val="0.999"'))
    # BAL and Bundler: Unicode digits (str.isdigit accepts them, int() does not), huge numbers
    write("bal-unicode-digit.txt", edited(bl, {3: token_changed(bl[3], 0, "\u00b2")}))
    write("bal-int-400.txt", edited(bl, {3: token_changed(bl[3], 1, "9" * 400)}))
    write("bal-value-huge.txt", edited(bl, {len(bl) - 2: "1e308"}))
    # a rotation angle of 2⁶⁴ rad: finite, but its derivatives vanish (refused by the reader at its line)
    write("bal-singular.txt", edited(bl, {60: "18446744073709551616"}))
    write("bundler-unicode-digit.out", edited(ul, {len(ul) - 1: "\u2460 " + " ".join(ul[-1].split()[1:])}))
    cl = {k: v.splitlines() for k, v in col.items()}
    il, pl = cl["images.txt"], cl["points3D.txt"]
    write_dir("colmap-unicode-digit", {**col, "images.txt": edited(il, {3: token_changed(il[3], 8, "\u00b2")})})
    write_dir("colmap-int-5000", {**col, "points3D.txt": edited(pl, {2: token_changed(pl[2], 0, "1" * 5000)})})
    write_dir("colmap-quaternion-huge", {**col, "images.txt": edited(il, {1: token_changed(il[1], 1, "1e200")})})
    write_dir("colmap-value-huge", {**col, "points3D.txt": edited(pl, {4: token_changed(pl[4], 1, "1e308")})})
    # control CSV: a 200,000-character field (csv's field size limit), σ = 1e-300, an id with ESC
    write("control-long-field.csv", "id,X,Y,Z,sx,sy,sz\n\"" + "7" * 200_000 + "\",0.1,0.2,0.3,0.01,0.01,0.02\n")
    write("control-sigma-tiny.csv", "id,X,Y,Z,sx,sy,sz\n0,0.1,0.2,0.3,0.01,1e-300,0.02\n")
    write("control-id-escape.csv", "id,X,Y,Z,sx,sy,sz\n\"9\x1b]0;owned\x07\r\",0.1,0.2,0.3,0.01,0.01,0.02\n")
    # control CSV as spreadsheets write it: valid, must give the same result as control-valid.csv
    plain = (VALID / "control-valid.csv").read_text()
    quoted = "\n".join(",".join(f'"{c}"' for c in row.split(",")) for row in plain.splitlines()) + "\n"
    (VALID / "control-spreadsheet-bom-crlf.csv").write_bytes(("\ufeff" + plain.replace("\n", "\r\n")).encode())
    (VALID / "control-spreadsheet-cr-quoted.csv").write_bytes(quoted.replace("\n", "\r").encode())


if __name__ == "__main__":
    main()
