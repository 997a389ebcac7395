"""Rows of the CSV files of ``--csv`` whose JSON records nest lists: each list spread over columns
(:func:`baarda.io.results.write_csv`)."""

from __future__ import annotations

#: the centre covariance's entries as CSV columns (``images.csv``)
CENTRE_COV_COLUMNS = (("cov_XX", 0, 0), ("cov_XY", 0, 1), ("cov_XZ", 0, 2), ("cov_YY", 1, 1), ("cov_YZ", 1, 2),
                      ("cov_ZZ", 2, 2))


def image_row(row: dict) -> dict:
    """An image record with its ``centre_cov`` as the six columns of :data:`CENTRE_COV_COLUMNS`."""
    out = {k: v for k, v in row.items() if k != "centre_cov"}
    C = row.get("centre_cov")
    if C is not None:
        out.update({name: C[a][b] for name, a, b in CENTRE_COV_COLUMNS})
    return out


def check_point_row(row: dict) -> dict:
    """A check point of ``check_points.points`` as one CSV row: ``id``, known ``x_ref`` …,
    adjusted ``x`` …, residual ``dx`` … (adjusted − known) and ``sx`` …, per axis; ``line``."""
    out = {"id": row["id"]}
    for key, fmt in (("ref", "{}_ref"), ("adjusted", "{}"), ("diff", "d{}"), ("sigma", "s{}")):
        out.update({fmt.format(a): v for a, v in zip("xyz", row[key])})
    out["line"] = row.get("line", "")
    return out
