"""GNSS centres and IMU attitudes in the native block format (gnss, gnss_centres, imu,
imu_attitudes): written and read back exactly, the same adjustment as with --gnss/--imu, bad
entries refused with file and line."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

import baarda
from baarda.cli import main
from baarda.errors import InputError
from baarda.io.gnss import GnssOptions, ImuOptions
from baarda.io.native import read_native, write_native
from baarda.simulate import simulate_to_files


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    d = tmp_path_factory.mktemp("nativegnss")
    block, _ = simulate_to_files({"seed": 4, "strips": 2, "images_per_strip": 4, "control": "corners",
                                  "gnss_sigma": 0.05, "imu_sigma": 0.01}, d / "b.json", d / "b.truth.json")
    return d, block


def test_round_trip_is_exact(sim, tmp_path):
    _, block = sim
    g = block.gnss
    c0 = g.centres[0]
    C = np.array([[0.0025, 0.001, 0.0], [0.001, 0.0016, 0.0002], [0.0, 0.0002, 0.01]])
    centres = (dataclasses.replace(c0, cov=tuple(map(tuple, C.tolist())), strip="A", time=12.25), *g.centres[1:])
    block = block.replace(gnss=dataclasses.replace(g, centres=centres, lever_arm=(0.1, -0.2, 0.3), shift=True),
                          datum="control")
    p = tmp_path / "b.json"
    write_native(block, p)
    back = read_native(p)
    for a, b in zip(back.gnss.centres, block.gnss.centres):
        assert (a.image, a.xyz, a.cov, a.strip) == (b.image, b.xyz, b.cov, b.strip)
        assert a.time == b.time or (np.isnan(a.time) and np.isnan(b.time))
    assert (back.gnss.lever_arm, back.gnss.shift, back.gnss.drift, back.gnss.estimate_lever_arm) == \
           ((0.1, -0.2, 0.3), True, False, False)
    for a, b in zip(back.imu.attitudes, block.imu.attitudes):
        assert (a.image, a.angles, a.cov) == (b.image, b.angles, b.cov)
    assert (back.imu.boresight, back.imu.boresight_fixed) == (block.imu.boresight, block.imu.boresight_fixed)
    assert back.datum == "control"
    write_native(back, tmp_path / "again.json")
    assert (tmp_path / "again.json").read_bytes() == p.read_bytes()


def test_native_file_gives_the_adjustment_of_the_csvs(sim, tmp_path):
    d, block = sim
    with_csv = baarda.analyze(d / "b.json", gnss=GnssOptions(d / "b.gnss.csv"), imu=ImuOptions(d / "b.imu.csv"))
    p = tmp_path / "all.json"
    write_native(with_csv.problem.notes.local_model, p)
    native = baarda.analyze(p)
    assert native.adjustment.n == with_csv.adjustment.n
    assert native.adjustment.vPv == pytest.approx(with_csv.adjustment.vPv, rel=1e-12)
    np.testing.assert_allclose(native.adjustment.x, with_csv.adjustment.x, rtol=0, atol=1e-9)


def test_convert_writes_the_centres_and_attitudes(sim, tmp_path):
    d, _ = sim
    out = tmp_path / "with-gnss.json"
    assert main(["convert", str(d / "b.json"), str(out), "-q", "--gnss", str(d / "b.gnss.csv"), "--imu",
                 str(d / "b.imu.csv"), "--gnss-shift"]) == 0
    back = read_native(out)
    assert len(back.gnss.centres) == 8 and len(back.imu.attitudes) == 8 and back.gnss.shift
    a = baarda.analyze(out)
    b = baarda.analyze(d / "b.json", gnss=GnssOptions(d / "b.gnss.csv", shift=True), imu=ImuOptions(d / "b.imu.csv"))
    assert a.adjustment.vPv == pytest.approx(b.adjustment.vPv, rel=1e-12)


def _doc(sim):
    d, _ = sim
    return json.loads((d / "b.json").read_text())


@pytest.mark.parametrize("key, value, needle", [
    ("gnss_centres", [{"image": "nope", "xyz": [0, 0, 1500], "sigma": [0.05, 0.05, 0.05]}], "unknown image 'nope'"),
    ("gnss_centres", [{"image": "101", "xyz": [0, 0], "sigma": 0.05}], "'xyz' must be a list of 3 numbers"),
    ("gnss_centres", [{"image": "101", "xyz": [0, 0, 1500], "cov": [[1, 2, 0], [2, 1, 0], [0, 0, 1]]}],
     "not symmetric positive definite"),
    ("gnss_centres", [{"image": "101", "xyz": [0, 0, 1500], "sigma": 0.05}] * 2, "image '101' twice"),
    ("gnss", {"lever": [0, 0, 0]}, "unknown field(s) 'lever'"),
    ("imu_attitudes", [{"image": "101", "angles": [0, 1.5708, 0], "sigma": 0.001}], "singular"),
])
def test_bad_entries_are_refused_with_their_line(sim, tmp_path, key, value, needle):
    doc = _doc(sim)
    if key == "gnss":
        doc["gnss_centres"] = [{"image": "101", "xyz": [0, 0, 1500], "sigma": 0.05}]
    doc[key] = value
    p = tmp_path / "bad.json"
    write = "{\n" + ",\n".join(f" {json.dumps(k)}: {json.dumps(v)}" for k, v in doc.items()) + "\n}\n"
    p.write_text(write)
    line = next(n for n, t in enumerate(write.splitlines(), 1) if t.startswith(f' "{key}"'))
    with pytest.raises(InputError) as err:
        read_native(p)
    assert needle in str(err.value)
    assert str(err.value).startswith(f"{p}:{line}: ")
