"""IES LM-63 reader/writer: the shared real files, symmetry unfolding, round trips, errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from reroom.errors import ScanError
from reroom.io.ies import IESProfile, parse_ies, read_ies, write_ies

IES_DIR = Path("/work/shared/data/ies")

# (file, format, symmetry, n_vertical, n_horizontal_unfolded, peak cd, (V, H) of the peak,
#  nadir cd, flux in lm from shared/data/README.md)
SHARED = [
    ("ASA_15M_R2.ies", "LM-63-2002", "bilateral", 37, 145, 6019.0, (62.5, 65.0), 1666.0, 9559.0),
    ("ies_light_1.ies", "LM-63-1991", "axial", 269, 2, 48.28, (4.04, 0.0), None, 18.0),
    ("ies_light_2.ies", "LM-63-1991", "axial", 181, 2, 54.47, (15.0, 0.0), None, 25.0),
]


def _needs_shared(name: str) -> Path:
    path = IES_DIR / name
    if not path.is_file():
        pytest.skip(f"shared data file {path} is not available")
    return path


def _ies_text(
    v: list[float],
    h: list[float],
    rows: list[list[float]],
    *,
    header: str = "IESNA:LM-63-2002",
    tilt: str = "TILT=NONE",
    ptype: int = 1,
    lumens: float = -1,
    multiplier: float = 1.0,
    ballast: float = 1.0,
    newline: str = "\n",
    extra: str = "",
) -> str:
    lines = [header, "[TEST] unit", "[MANUFAC] reroom", "[MORE] tests", tilt]
    lines.append(f"1 {lumens} {multiplier} {len(v)} {len(h)} {ptype} 2 0 0 0")
    lines.append(f"{ballast} 1 10")
    lines.append(" ".join(map(str, v)))
    lines.append(" ".join(map(str, h)))
    lines.extend(" ".join(map(str, r)) for r in rows)
    return newline.join(lines) + newline + extra


# ---------------------------------------------------------------------- real files
@pytest.mark.parametrize("case", SHARED, ids=[c[0] for c in SHARED])
def test_shared_files_parse_with_readme_numbers(case: tuple) -> None:
    name, fmt, symmetry, n_v, n_h, peak, (pv, ph), nadir, flux = case
    prof = read_ies(_needs_shared(name))
    assert prof.source_format == fmt
    assert prof.symmetry == symmetry
    assert prof.vertical_angles.shape == (n_v,)
    assert prof.horizontal_angles.shape == (n_h,)
    assert prof.horizontal_angles[0] == 0.0 and prof.horizontal_angles[-1] == 360.0
    assert prof.peak_candela == pytest.approx(peak, rel=1e-9)
    ih, iv = np.unravel_index(np.argmax(prof.candela), prof.candela.shape)
    assert prof.vertical_angles[iv] == pytest.approx(pv)
    assert prof.horizontal_angles[ih] == pytest.approx(ph)
    if nadir is not None:
        assert prof.intensity(0.0, 0.0) == pytest.approx(nadir)
    assert prof.total_flux() == pytest.approx(flux, rel=0.02)


def test_asa_header_keywords_and_units() -> None:
    path = _needs_shared("ASA_15M_R2.ies")
    assert b"\r\n" in path.read_bytes()  # the reader must cope with CRLF
    prof = read_ies(path)
    assert prof.keywords["MANUFAC"] == "American Electric Lighting"
    assert prof.keywords["_LAMPLUMENS"] == "13000"
    assert prof.keywords["LAMP"].endswith("\nPOS.")  # [MORE] continuation joined
    assert prof.lamp_lumens == 13000.0 and not prof.is_absolute
    assert prof.units == "feet"
    assert prof.width == pytest.approx(1.24) and prof.input_watts == pytest.approx(185.0)
    # Full cut-off: nothing above the horizontal; the table stops at 90 deg.
    assert prof.vertical_angles[-1] == 90.0
    assert float(prof.intensity(120.0, 30.0)) == 0.0


def test_rpr_files_are_absolute_metres() -> None:
    for name in ("ies_light_1.ies", "ies_light_2.ies"):
        prof = read_ies(_needs_shared(name))
        assert prof.is_absolute and prof.units == "meters"
        assert prof.is_axially_symmetric
        assert prof.keywords == {}


def test_bilateral_unfolding_mirrors_about_0_180_plane() -> None:
    prof = read_ies(_needs_shared("ASA_15M_R2.ies"))
    theta = np.linspace(0, 90, 19)
    for phi in (10.0, 65.0, 100.0, 170.0):
        np.testing.assert_allclose(prof.intensity(theta, phi), prof.intensity(theta, 360.0 - phi))
        np.testing.assert_allclose(prof.intensity(theta, phi), prof.intensity(theta, -phi))
    # The file's own rows are reproduced at its angles (H = 65 is row 26 of 0..180 by 2.5).
    raw = parse_ies((IES_DIR / "ASA_15M_R2.ies").read_bytes())
    np.testing.assert_allclose(prof.intensity(prof.vertical_angles, 65.0), raw.candela[26])
    np.testing.assert_allclose(prof.intensity(prof.vertical_angles, 295.0), raw.candela[26])


def test_intensity_dir_frame_convention() -> None:
    prof = read_ies(_needs_shared("ASA_15M_R2.ies"))
    # Nadir is local -Z.
    assert prof.intensity_dir(np.array([0.0, 0.0, -1.0])) == pytest.approx(1666.0)
    # theta = 62.5 deg from nadir, phi = 65 deg from +X towards +Y: the peak.
    t, p = np.radians(62.5), np.radians(65.0)
    d = np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), -np.cos(t)])
    assert prof.intensity_dir(d) == pytest.approx(6019.0)
    assert prof.intensity_dir(d * [1, -1, 1]) == pytest.approx(6019.0)  # bilateral
    assert prof.intensity_dir(5.0 * d) == pytest.approx(6019.0)  # not normalised on input
    # Upward directions receive nothing from a full cut-off luminaire.
    assert prof.intensity_dir(np.array([0.0, 0.0, 1.0])) == 0.0
    # Radians and degrees agree.
    assert prof.intensity(t, p, degrees=False) == pytest.approx(6019.0)


# ---------------------------------------------------------------------- synthetic files
def test_quadrant_symmetry_unfolds_to_four_mirrored_quadrants() -> None:
    v = [0, 45, 90]
    h = [0, 30, 90]
    rows = [[10, 20, 30], [11, 21, 31], [12, 22, 32]]
    prof = parse_ies(_ies_text(v, h, rows))
    assert prof.symmetry == "quadrant"
    for phi, row in ((30, 1), (150, 1), (210, 1), (330, 1), (90, 2), (270, 2), (180, 0)):
        np.testing.assert_allclose(prof.intensity(np.array(v), phi), rows[row], err_msg=str(phi))
    # Linear between 0 and 30 deg in azimuth, and mirrored.
    assert prof.intensity(45.0, 15.0) == pytest.approx(20.5)
    assert prof.intensity(45.0, 345.0) == pytest.approx(20.5)
    assert prof.intensity(45.0, 165.0) == pytest.approx(20.5)


def test_bilateral_90_270_symmetry() -> None:
    v = [0, 90, 180]
    h = [90, 180, 270]
    rows = [[1, 2, 3], [4, 5, 6], [7, 8, 9]]
    prof = parse_ies(_ies_text(v, h, rows))
    assert prof.symmetry == "bilateral90"
    # Mirror about the 90-270 plane: I(phi) = I(180 - phi).
    np.testing.assert_allclose(prof.intensity(np.array(v), 0.0), rows[1])
    np.testing.assert_allclose(prof.intensity(np.array(v), 360.0), rows[1])
    np.testing.assert_allclose(prof.intensity(np.array(v), 90.0), rows[0])
    np.testing.assert_allclose(prof.intensity(np.array(v), 270.0), rows[2])
    assert prof.intensity(90.0, 45.0) == pytest.approx(prof.intensity(90.0, 135.0))
    assert prof.intensity(90.0, 315.0) == pytest.approx(prof.intensity(90.0, 225.0))


def test_single_plane_is_axially_symmetric_and_full_table_is_kept() -> None:
    axial = parse_ies(_ies_text([0, 90, 180], [0], [[5, 6, 7]]))
    assert axial.symmetry == "axial" and axial.is_axially_symmetric
    np.testing.assert_allclose(axial.intensity([0, 90, 180], 123.0), [5, 6, 7])
    full = parse_ies(_ies_text([0, 180], [0, 120, 240, 360], [[1, 1], [2, 2], [3, 3], [1, 1]]))
    assert full.symmetry == "full"
    assert full.intensity(0.0, 60.0) == pytest.approx(1.5)
    assert full.intensity(0.0, 300.0) == pytest.approx(2.0)


def test_open_full_table_wraps_periodically() -> None:
    prof = parse_ies(_ies_text([0, 180], [0, 90, 180, 270], [[1, 1], [2, 2], [3, 3], [4, 4]]))
    assert prof.horizontal_angles[-1] == 360.0
    assert prof.intensity(0.0, 315.0) == pytest.approx(2.5)  # between 270 (4) and 360 (= 0: 1)


def test_multiplier_and_ballast_factor_are_applied() -> None:
    plain = parse_ies(_ies_text([0, 90], [0], [[10, 20]]))
    scaled = parse_ies(_ies_text([0, 90], [0], [[10, 20]], multiplier=2.0, ballast=0.5))
    np.testing.assert_allclose(scaled.candela, plain.candela)
    scaled = parse_ies(_ies_text([0, 90], [0], [[10, 20]], multiplier=3.0))
    np.testing.assert_allclose(scaled.candela, 3 * plain.candela)


@pytest.mark.parametrize("newline", ["\n", "\r\n", "\r"])
def test_line_endings_and_commas(newline: str) -> None:
    text = _ies_text([0, 45, 90], [0, 180], [[1, 2, 3], [4, 5, 6]], newline=newline)
    prof = parse_ies(text.encode("latin-1"))
    np.testing.assert_allclose(prof.intensity([0, 45, 90], 180.0), [4, 5, 6])
    assert prof.keywords["MANUFAC"] == "reroom\ntests"
    comma = parse_ies(text.replace("4 5 6", "4,5, 6"))
    np.testing.assert_allclose(comma.candela, prof.candela)


def test_1986_file_without_identifier() -> None:
    text = "Some luminaire\nmade by someone\nTILT=NONE\n1 1000 1 2 1 1 1 0 0 0\n1 1 0\n0 90\n0\n100 50\n"
    prof = parse_ies(text)
    assert prof.source_format == "LM-63-1986"
    assert prof.keywords["_NOTES"] == "Some luminaire\nmade by someone"
    assert prof.units == "feet"


# ---------------------------------------------------------------------- flux and grids
def test_total_flux_of_isotropic_and_hemispherical_sources() -> None:
    iso = IESProfile(np.array([0.0, 60.0, 180.0]), np.array([0.0, 360.0]), np.full((2, 3), 100.0))
    assert iso.total_flux() == pytest.approx(4 * np.pi * 100.0, rel=1e-12)
    down = IESProfile(np.array([0.0, 90.0]), np.array([0.0, 360.0]), np.full((2, 2), 100.0))
    assert down.total_flux() == pytest.approx(2 * np.pi * 100.0, rel=1e-12)
    # A cosine (Lambertian) downlight: I = I0 cos(theta) -> pi I0, approximated by a fine grid.
    t = np.linspace(0, 90, 901)
    lam = IESProfile(t, np.array([0.0, 360.0]), np.tile(np.cos(np.radians(t)), (2, 1)))
    assert lam.total_flux() == pytest.approx(np.pi, rel=1e-5)


def test_scaled_to_flux_and_tabulated_grid() -> None:
    prof = read_ies(_needs_shared("ASA_15M_R2.ies"))
    scaled = prof.scaled_to_flux(1000.0)
    assert scaled.total_flux() == pytest.approx(1000.0, rel=1e-12)
    assert scaled.peak_candela == pytest.approx(6019.0 * 1000.0 / prof.total_flux())
    grid = prof.to_tabulated()
    assert grid.values.shape == (361, 145)
    np.testing.assert_allclose(grid.values[:, 0], grid.values[:, -1])
    t, p = np.meshgrid(grid.theta_deg, grid.phi_deg, indexing="ij")
    np.testing.assert_allclose(grid.values, prof.intensity(t, p))
    # Nodes every 0.5 x 2.5 deg contain the file's 2.5 deg grid: the same interpolant, so
    # the same flux and the same values between nodes.
    assert grid.total_flux() == pytest.approx(prof.total_flux(), rel=1e-12)
    as_profile = IESProfile(grid.theta_deg, grid.phi_deg, grid.values.T)
    tt, pp = np.random.default_rng(0).uniform([0, 0], [180, 360], (500, 2)).T
    np.testing.assert_allclose(as_profile.intensity(tt, pp), prof.intensity(tt, pp), atol=1e-9)
    # A coarser grid that misses the file's nodes only approximates it.
    assert prof.to_tabulated(181, 145).total_flux() == pytest.approx(prof.total_flux(), rel=1e-3)
    irregular = read_ies(_needs_shared("ies_light_1.ies"))
    assert irregular.to_tabulated(361, 2).total_flux() == pytest.approx(
        irregular.total_flux(), rel=0.01
    )


# ---------------------------------------------------------------------- writing
@pytest.mark.parametrize("name", [c[0] for c in SHARED])
def test_round_trip_shared_files(tmp_path: Path, name: str) -> None:
    prof = read_ies(_needs_shared(name))
    out = write_ies(tmp_path / "out.ies", prof)
    data = out.read_bytes()
    assert data.startswith(b"IESNA:LM-63-2002\r\n") and b"\r\nTILT=NONE\r\n" in data
    assert max(len(line) for line in data.split(b"\r\n")) <= 256
    back = read_ies(out)
    assert back.allclose(prof, rtol=0, atol=0)
    assert back.source_format == "LM-63-2002"
    for key, value in prof.keywords.items():
        assert back.keywords[key] == value
    for attr in ("lamp_lumens", "num_lamps", "units", "width", "length", "height", "input_watts"):
        assert getattr(back, attr) == getattr(prof, attr)
    assert back.total_flux() == pytest.approx(prof.total_flux(), rel=1e-12)
    assert [p.name for p in tmp_path.iterdir()] == ["out.ies"]  # no temporary left behind


def test_round_trip_asymmetric_profile(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    v = np.array([0.0, 10.0, 33.3, 90.0, 135.0, 180.0])
    h = np.array([0.0, 45.0, 100.0, 200.0, 360.0])
    cd = rng.uniform(0, 500, (h.size, v.size)) / 7.0  # non-terminating decimals
    cd[-1] = cd[0]
    prof = IESProfile(v, h, cd, keywords={"MANUFAC": "x", "_NOTE": "a\nb"}, lamp_lumens=-1)
    back = read_ies(write_ies(tmp_path / "asym.ies", prof))
    assert back.allclose(prof, rtol=0, atol=0)
    assert back.keywords["_NOTE"] == "a\nb"
    assert back.keywords["TESTLAB"] == "unknown"  # required by LM-63-2002


# ---------------------------------------------------------------------- errors
GOOD = dict(v=[0, 90], h=[0], rows=[[1, 2]])


def _good_text(**kw: object) -> str:
    args = dict(GOOD)
    args.update(kw)
    return _ies_text(args.pop("v"), args.pop("h"), args.pop("rows"), **args)  # type: ignore[arg-type]


CORRUPT = {
    "no_tilt": (_good_text().replace("TILT=NONE\n", ""), "TILT"),
    "tilt_include": (_good_text(tilt="TILT=INCLUDE"), "TILT=INCLUDE"),
    "tilt_file": (_good_text(tilt="TILT=lamp.tlt"), "tilt file"),
    "type_b": (_good_text(ptype=2), "type B"),
    "type_a": (_good_text(ptype=3), "type A"),
    "too_few": (_good_text(rows=[[1]]), "expected 18"),
    "too_many": (_good_text(rows=[[1, 2, 3]]), "expected 18"),
    "non_numeric": (_good_text(rows=[["1", "x"]]), "non-numeric"),
    "vertical_not_increasing": (_good_text(v=[90, 0]), "vertical angles"),
    "horizontal_not_increasing": (
        _good_text(h=[0, 180, 90], rows=[[1, 2], [1, 2], [1, 2]]),
        "horizontal angles",
    ),
    "bad_symmetry": (_good_text(h=[0, 45], rows=[[1, 2], [1, 2]]), "symmetry"),
    "negative_candela": (_good_text(rows=[[1, -2]]), "negative"),
    "header_only": ("IESNA:LM-63-2002\nTILT=NONE\n1 2 3\n", "13"),
    "empty": ("", "TILT"),
}


@pytest.mark.parametrize("case", sorted(CORRUPT))
def test_corrupt_files_raise_scan_error(tmp_path: Path, case: str) -> None:
    text, needle = CORRUPT[case]
    path = tmp_path / f"{case}.ies"
    path.write_text(text, encoding="latin-1")
    with pytest.raises(ScanError) as info:
        read_ies(path)
    assert info.value.path == path
    assert needle.lower() in info.value.problem.lower(), info.value.problem


def test_missing_file_raises_scan_error(tmp_path: Path) -> None:
    with pytest.raises(ScanError, match="missing"):
        read_ies(tmp_path / "nope.ies")


def test_profile_validation() -> None:
    with pytest.raises(ValueError):
        IESProfile(np.array([0.0, 90.0]), np.array([0.0, 180.0]), np.ones((2, 2)))
    with pytest.raises(ValueError):
        IESProfile(np.array([0.0, 90.0]), np.array([0.0, 360.0]), -np.ones((2, 2)))
