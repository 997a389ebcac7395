"""Options of the command line parsed outside :mod:`baarda.cli`: the GNSS options (``baarda
analyze|test --gnss CSV ...``: their arguments and the :class:`baarda.io.gnss.GnssOptions` they
make; docs/formats.md, "GNSS projection centres") and ``baarda simulate``'s ``--error`` specs."""

from __future__ import annotations

import argparse
import math
from typing import TYPE_CHECKING

from .errors import BaardaError, UsageError
from .lazy import lazy

if TYPE_CHECKING:
    from .io.gnss import GnssOptions, ImuOptions

#: the GNSS reader's options, loaded when a command makes them (``baarda --help`` loads no numpy)
gnss_io = lazy("baarda.io.gnss")


def lever_arm(text: str) -> tuple[float, float, float]:
    """``DX,DY,DZ`` (metres, camera frame) as three finite numbers below 1 km."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        vals = ()
    if len(vals) != 3 or not all(math.isfinite(v) and abs(v) <= 1e3 for v in vals):
        raise argparse.ArgumentTypeError(f"expected DX,DY,DZ, three numbers in metres within ±1000, got {text!r}")
    return vals


def angles(text: str) -> tuple[float, float, float]:
    """``DO,DP,DK`` (degrees) as three finite numbers within ±180."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        vals = ()
    if len(vals) != 3 or not all(math.isfinite(v) and abs(v) <= 180 for v in vals):
        raise argparse.ArgumentTypeError(f"expected three angles in degrees within ±180, got {text!r}")
    return vals


def imu_options(args) -> ImuOptions | None:
    """The :class:`ImuOptions` of parsed arguments, None without ``--imu`` (a usage error for a
    boresight option without it)."""
    if getattr(args, "imu", None) is None:
        if getattr(args, "fix_boresight", False) or tuple(getattr(args, "boresight", (0.0,) * 3)) != (0.0,) * 3:
            raise UsageError("--boresight / --fix-boresight need --imu CSV")
        return None
    return gnss_io.ImuOptions(args.imu, tuple(args.boresight), bool(args.fix_boresight))


def add_gnss_arguments(p) -> None:
    """The GNSS options of a subcommand that reads a block."""
    p.add_argument("--gnss", metavar="CSV",
                   help="GNSS projection centres image,x,y,z,sx,sy,sz[,strip,time,rxy,rxz,ryz] observed "
                        "(bundle blocks, SfM models converted; metres, the block's frame); also a Metashape or "
                        "Pix4D camera-position export with accuracies, or a COLMAP database.db")
    p.add_argument("--lever-arm", type=lever_arm, default=(0.0, 0.0, 0.0), metavar="DX,DY,DZ",
                   help="lever arm from the projection centre to the antenna, camera frame, metres (default 0,0,0)")
    p.add_argument("--estimate-lever-arm", action="store_true",
                   help="estimate the lever arm (one for the block, starting at --lever-arm)")
    p.add_argument("--gnss-shift", action="store_true", help="a GNSS shift per strip (3 unknowns each, tested)")
    p.add_argument("--gnss-drift", action="store_true",
                   help="a GNSS drift per strip (3 unknowns each, per time unit of the CSV's time column)")
    p.add_argument("--georeference", action="store_true",
                   help="bring the block into the frame of its GNSS centres first (a robust similarity)")
    p.add_argument("--imu", metavar="CSV",
                   help="IMU attitudes image,omega,phi,kappa,somega,sphi,skappa in degrees (bundle blocks)")
    p.add_argument("--boresight", type=angles, default=(0.0, 0.0, 0.0), metavar="DO,DP,DK",
                   help="boresight ω, φ, κ in degrees: the start of its estimate, or its value with --fix-boresight")
    p.add_argument("--fix-boresight", action="store_true", help="hold the boresight at --boresight")


def add_simulate_gnss_arguments(p) -> None:
    """``baarda simulate``'s GNSS options (:mod:`baarda.simulate_gnss`)."""
    p.add_argument("--gnss-sigma", type=float, default=None, metavar="M",
                   help="simulate GNSS projection centres with this σ per component (m), written to OUT.gnss.csv")
    p.add_argument("--gnss-lever-arm", type=lever_arm, default=(0.0, 0.0, 0.0), metavar="DX,DY,DZ",
                   help="the simulated lever arm (m, camera frame; analyse with --lever-arm)")
    p.add_argument("--imu-sigma", type=float, default=None, metavar="DEG",
                   help="simulate IMU attitudes with this σ per angle (degrees), written to OUT.imu.csv")
    p.add_argument("--imu-boresight", type=angles, default=(0.0, 0.0, 0.0), metavar="DO,DP,DK",
                   help="the simulated boresight ω, φ, κ (degrees, each within ±10)")


def gnss_recipe(args) -> dict:
    """The recipe keys of ``baarda simulate``'s GNSS options (none without --gnss-sigma)."""
    out = {}
    if getattr(args, "gnss_sigma", None) is not None:
        out.update(gnss_sigma=args.gnss_sigma, gnss_lever=list(args.gnss_lever_arm))
    if getattr(args, "imu_sigma", None) is not None:
        out.update(imu_sigma=args.imu_sigma, imu_boresight=list(args.imu_boresight))
    return out


def gnss_options(args) -> GnssOptions | None:
    """The :class:`GnssOptions` of parsed arguments, None without ``--gnss``; a usage error for
    a GNSS option without ``--gnss``."""
    path = getattr(args, "gnss", None)
    if path is None:
        used = [f for f, on in (("--estimate-lever-arm", getattr(args, "estimate_lever_arm", False)),
                                ("--gnss-shift", getattr(args, "gnss_shift", False)),
                                ("--gnss-drift", getattr(args, "gnss_drift", False)),
                                ("--georeference", getattr(args, "georeference", False)),
                                ("--lever-arm", tuple(getattr(args, "lever_arm", (0.0,) * 3)) != (0.0,) * 3)) if on]
        if used:
            raise UsageError(f"{', '.join(used)} need(s) --gnss CSV")
        return None
    return gnss_io.GnssOptions(path, tuple(args.lever_arm), bool(args.estimate_lever_arm), bool(args.gnss_shift),
                       bool(args.gnss_drift), bool(args.georeference))


#: keys of a --error spec that name things by id: kept as text, as the reader keeps ids
_ID_KEYS = ("point", "image", "strip", "component", "axis")


def parse_error(spec: str) -> dict:
    """A --error KIND:SIZE[:K=V...] as a recipe's error (its numbers checked by check_recipe)."""
    parts = spec.split(":")
    d = {"kind": parts[0]}
    if len(parts) > 1 and parts[1]:
        try:
            d["size"] = float(parts[1])
        except ValueError:
            raise BaardaError(f"--error {spec!r}: SIZE must be a number, not {parts[1]!r}") from None
    for kv in parts[2:]:
        k, eq, v = kv.partition("=")
        if not (k and eq):
            raise BaardaError(f"--error {spec!r}: expected KIND:SIZE[:K=V...], not {kv!r}")
        if k in _ID_KEYS:                  # ids, even when they look like numbers
            d[k] = v
            continue
        try:
            d[k] = int(v)
        except ValueError:
            try:
                d[k] = float(v)
            except ValueError:
                d[k] = v
    return d
