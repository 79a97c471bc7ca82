"""LUT: load/validate, interpolation inside coverage, flagged (not silent) extrapolation."""

import numpy as np
import pymap3d
import pytest

from blendgen.errors import UserError
from blendgen.sync.lut import LUT_COLUMNS, Lut, write_lut

ORIGIN = (48.137, 11.575, 520.0)


def _table(rot_deg=30.0, shift=(100.0, -50.0, 2.0), n=40, spacing=5.0):
    """A surveyed road along a gentle arc; twin = ENU rotated by rot_deg and shifted."""
    s = np.arange(n) * spacing
    e, nn = s * np.cos(0.3), s * np.sin(0.3) + 0.002 * s**2
    u = 0.01 * s
    lat, lon, alt = pymap3d.enu2geodetic(e, nn, u, *ORIGIN)
    head_enu = np.arctan2(np.gradient(nn), np.gradient(e))
    heading_deg = 90.0 - np.degrees(head_enu)
    a = np.radians(rot_deg)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    xy = (R @ np.stack([e, nn])).T + shift[:2]
    z = u + shift[2]
    yaw_deg = np.degrees(head_enu + a)
    return np.column_stack([lat, lon, alt, heading_deg, xy, z, yaw_deg]), R, np.array(shift)


def test_load_and_query_interpolates(tmp_path):
    rows, R, shift = _table()
    write_lut(tmp_path / "lut.csv", rows)
    assert (tmp_path / "lut.csv").read_text().splitlines()[0] == ",".join(LUT_COLUMNS)
    lut = Lut.load(tmp_path / "lut.csv")
    # a fix between surveyed rows, 1.5 m to the side of the road
    e, n, u = 52.0 * np.cos(0.3) - 1.5 * np.sin(0.3), 52.0 * np.sin(0.3) + 0.002 * 52**2 + 1.5 * np.cos(0.3), 0.52
    lat, lon, alt = pymap3d.enu2geodetic(e, n, u, *ORIGIN)
    q = lut.query(lat, lon, alt, heading_deg=45.0)
    want = R @ np.array([e, n]) + shift[:2]
    assert q.inside
    assert np.linalg.norm(q.xyz[:2] - want) < 0.05
    assert q.xyz[2] == pytest.approx(u + shift[2], abs=0.05)
    # heading 45 deg (north-east) -> ENU yaw 45 deg -> twin yaw 45 + 30 deg
    assert np.degrees(q.yaw) == pytest.approx(75.0, abs=0.2)


def test_outside_coverage_is_flagged(tmp_path):
    rows, R, shift = _table()
    lut = Lut(rows)
    lat, lon, alt = pymap3d.enu2geodetic(-300.0, 400.0, 0.0, *ORIGIN)
    q = lut.query(lat, lon, alt)
    assert not q.inside and q.distance_m > lut.coverage_m and q.yaw is None
    assert np.all(np.isfinite(q.xyz))
    xyz, inside, rot = lut.query_many(rows[:, 0], rows[:, 1], rows[:, 2])
    assert inside.all()
    assert np.allclose(xyz, rows[:, 4:7], atol=0.02)
    assert np.allclose(rot, np.radians(30.0), atol=1e-3)


def test_yaw_wraps_at_180(tmp_path):
    rows, _, _ = _table(rot_deg=170.0)
    lut = Lut(rows)
    q = lut.query(*rows[10, :3], heading_deg=0.0)  # north -> ENU 90 deg -> twin 260 = -100 deg
    assert np.degrees(q.yaw) == pytest.approx(-100.0, abs=0.2)


def test_coincident_rows_use_heading_pairs():
    rows, _, _ = _table(rot_deg=-20.0)
    rows = np.vstack([rows[:1], rows[:1]])  # two rows at the same place: no baseline
    lut = Lut(rows)
    q = lut.query(*rows[0, :3], heading_deg=rows[0, 3])
    assert np.degrees(q.yaw) == pytest.approx(rows[0, 7], abs=1e-6)


@pytest.mark.parametrize("text, match", [
    ("lat,lon,alt\n1,2,3\n", r"missing column\(s\) \['heading_deg'"),
    (",".join(LUT_COLUMNS) + "\n1,2,3,4,5,6,7,x\n1,2,3,4,5,6,7,8\n", "row 2: not all"),
    (",".join(LUT_COLUMNS) + "\n1,2,3,4,5,6,7,nan\n1,2,3,4,5,6,7,8\n", "row 2: NaN"),
    (",".join(LUT_COLUMNS) + "\n95,2,3,4,5,6,7,8\n1,2,3,4,5,6,7,8\n", "row 2: lat/lon out of range"),
    (",".join(LUT_COLUMNS) + "\n1,2,3,4,5,6,7,8\n", "at least 2 rows"),
    ("", "empty LUT"),
])
def test_bad_files(tmp_path, text, match):
    p = tmp_path / "lut.csv"
    p.write_text(text)
    with pytest.raises(UserError, match=match):
        Lut.load(p)


def test_missing_file(tmp_path):
    with pytest.raises(UserError, match="LUT file not found"):
        Lut.load(tmp_path / "nope.csv")


def test_one_row_per_heading_keeps_spacing_and_coverage():
    """Rows sharing a position (one per heading) must not make the spacing 0 (issue 14)."""
    rows, R, shift = _table(spacing=10.0)
    rep = np.repeat(rows, 4, axis=0)
    rep[:, 3] = np.tile([0.0, 90.0, 180.0, 270.0], len(rows))  # receiver headings
    rep[:, 7] = rep[:, 3] * 0 + np.tile([90.0, 0.0, -90.0, 180.0], len(rows)) + 30.0  # same rotation
    lut = Lut(rep)
    assert lut.spacing_m == pytest.approx(Lut(rows).spacing_m, rel=1e-6) and lut.spacing_m > 9.0
    # a fix 12 m from the nearest position (between rows, beside the road) is inside coverage
    e, n = 45.0 * np.cos(0.3) - 12.0 * np.sin(0.3), 45.0 * np.sin(0.3) + 0.002 * 45**2 + 12.0 * np.cos(0.3)
    lat, lon, alt = pymap3d.enu2geodetic(e, n, 0.45, *ORIGIN)
    assert lut.query(lat, lon, alt).inside
