"""IES LM-63 photometric files: reading, symmetry unfolding, evaluation, writing.

An IES file tabulates a luminaire's luminous intensity (candela) over a grid of
*vertical* and *horizontal* angles. Only **type C** photometry is supported,
which is what interior and street luminaires use:

* The vertical angle ``theta`` is measured from the **nadir**: 0 deg points
  straight down, 90 deg is horizontal, 180 deg points straight up.
* The horizontal angle ``phi`` is the azimuth about the luminaire's vertical
  axis.

Luminaire frame
---------------
Directions "in the luminaire frame" (:meth:`IESProfile.intensity_dir`) use a
right-handed frame whose **-Z axis is the nadir** (``theta = 0``), whose **+X
axis is** ``phi = 0`` and in which ``phi`` increases towards **+Y**
(``phi = 90`` deg is +Y). With the identity luminaire-to-world rotation a
downlight therefore shines down the world's -Z axis (world +Z is up).

Formats accepted by :func:`read_ies`
------------------------------------
LM-63-1986 (no identifier line), LM-63-1991 (``IESNA91``), LM-63-1995 and
LM-63-2002 (``IESNA:LM-63-...``) and LM-63-2019 (``IES:LM-63-2019``), with CRLF, LF or CR line endings, numbers
separated by blanks or commas and wrapped over any number of lines. The lamp
tilt must be ``TILT=NONE``: ``TILT=INCLUDE`` and tilt files are rejected, as
are type A and type B photometry.

Horizontal symmetry (type C) is unfolded to a full 0..360 deg table when the
file is read:

==================  =========================================================
Horizontal angles   Meaning
==================  =========================================================
``0``               axially symmetric (one plane for all azimuths)
``0 .. 90``         quadrant symmetry (mirrored about the 0-180 and 90-270 planes)
``0 .. 180``        bilateral symmetry about the 0-180 plane
``90 .. 270``       bilateral symmetry about the 90-270 plane
``0 .. 360``        no symmetry (a ``0, 360`` pair of equal rows is axial)
==================  =========================================================

Candela values are stored with the file's candela multiplier and ballast
factor (and, in pre-2002 files, the ballast-lamp photometric factor) already
applied, so ``IESProfile.candela`` is the luminaire's actual intensity.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from reroom.errors import ScanError
from reroom.io.atomic import atomic_path

__all__ = ["IESProfile", "IntensityGrid", "read_ies", "write_ies", "parse_ies"]

#: Keywords that LM-63-2002 requires; :func:`write_ies` adds placeholders for missing ones.
REQUIRED_KEYWORDS_2002 = ("TEST", "TESTLAB", "ISSUEDATE", "MANUFAC")

_UNITS = {1: "feet", 2: "meters"}
_UNIT_CODES = {v: k for k, v in _UNITS.items()}
_ANGLE_TOL = 1e-6
_KEYWORD_RE = re.compile(r"^\s*\[([^\]]*)\]\s?(.*)$")
_TILT_RE = re.compile(r"^\s*TILT\s*=\s*(.*?)\s*$", re.IGNORECASE)


@dataclass(frozen=True, eq=False)
class IntensityGrid:
    """Intensity sampled on a regular ``(theta, phi)`` node grid (see :meth:`IESProfile.to_tabulated`).

    Attributes
    ----------
    theta_deg:
        ``(n_theta,)`` vertical angles from nadir, ``0 .. 180`` inclusive, evenly spaced.
    phi_deg:
        ``(n_phi,)`` azimuths, ``0 .. 360`` inclusive, evenly spaced; the last
        column repeats the first so that interpolation wraps without special cases.
    values:
        ``(n_theta, n_phi)`` intensity at the nodes (candela for a profile;
        row 0 is the nadir). Between nodes the intensity is bilinear in
        ``(theta, phi)``, which is how the goniometric emitter evaluates it.
    """

    theta_deg: np.ndarray
    phi_deg: np.ndarray
    values: np.ndarray

    def total_flux(self) -> float:
        """Integral of the bilinearly interpolated grid over the sphere (lumens for candela)."""
        return _sphere_integral(self.theta_deg, self.phi_deg, self.values.T)


@dataclass(frozen=True, eq=False)
class IESProfile:
    """A type C luminous intensity distribution, unfolded to the full sphere of azimuths.

    Attributes
    ----------
    vertical_angles:
        ``(V,)`` strictly increasing vertical angles in degrees, within
        ``[0, 180]``; 0 is the nadir (luminaire frame -Z). Intensity outside
        ``[vertical_angles[0], vertical_angles[-1]]`` is zero.
    horizontal_angles:
        ``(H,)`` strictly increasing azimuths in degrees from 0 to 360
        inclusive (``H >= 2``; the 360 row equals the 0 row for any file
        that was symmetric or closed).
    candela:
        ``(H, V)`` intensity in candela, multiplier and ballast factor applied.
    keywords:
        LM-63 keywords without brackets (``{"MANUFAC": "...", ...}``);
        ``[MORE]`` continuation lines are joined to the previous value with a
        newline. Unbracketed header lines of 1986 files go to ``"_NOTES"``.
    lamp_lumens:
        Rated lumens per lamp, or ``-1`` for absolute photometry (the
        candela values are then the luminaire's measured output, not relative
        to a lamp rating).
    num_lamps:
        Number of lamps.
    units:
        ``"feet"`` or ``"meters"``: the unit of the luminous opening dimensions.
    width, length, height:
        Luminous opening dimensions in ``units`` (0 = point source; negative
        values encode round/spherical openings as in LM-63).
    input_watts:
        Input electrical power in watts (0 when unknown).
    symmetry:
        How the file stored its horizontal angles: ``"axial"``, ``"quadrant"``,
        ``"bilateral"``, ``"bilateral90"`` or ``"full"``. Informational.
    source_format:
        ``"LM-63-1986"``, ``"LM-63-1991"``, ``"LM-63-1995"``, ``"LM-63-2002"``,
        or the identifier line of a newer file.
    """

    vertical_angles: np.ndarray
    horizontal_angles: np.ndarray
    candela: np.ndarray
    keywords: dict[str, str] = field(default_factory=dict)
    lamp_lumens: float = -1.0
    num_lamps: int = 1
    units: str = "meters"
    width: float = 0.0
    length: float = 0.0
    height: float = 0.0
    input_watts: float = 0.0
    symmetry: str = "full"
    source_format: str = "LM-63-2002"

    def __post_init__(self) -> None:
        v = np.asarray(self.vertical_angles, dtype=np.float64)
        h = np.asarray(self.horizontal_angles, dtype=np.float64)
        c = np.asarray(self.candela, dtype=np.float64)
        if v.ndim != 1 or v.size < 2 or np.any(np.diff(v) <= 0) or v[0] < 0 or v[-1] > 180:
            raise ValueError("vertical_angles must be >= 2 increasing values within [0, 180]")
        if (
            h.ndim != 1
            or h.size < 2
            or np.any(np.diff(h) <= 0)
            or abs(h[0]) > _ANGLE_TOL
            or abs(h[-1] - 360.0) > _ANGLE_TOL
        ):
            raise ValueError("horizontal_angles must be increasing values from 0 to 360 inclusive")
        if c.shape != (h.size, v.size):
            raise ValueError(f"candela has shape {c.shape}; expected {(h.size, v.size)}")
        if not np.all(np.isfinite(c)) or np.any(c < 0):
            raise ValueError("candela values must be finite and non-negative")
        if self.units not in _UNIT_CODES:
            raise ValueError(f"units must be 'feet' or 'meters', not {self.units!r}")
        # Frozen dataclass: normalise the arrays in place of the caller's objects.
        object.__setattr__(self, "vertical_angles", v)
        object.__setattr__(self, "horizontal_angles", h)
        object.__setattr__(self, "candela", c)
        object.__setattr__(self, "keywords", dict(self.keywords))

    # ------------------------------------------------------------------ queries
    @property
    def is_absolute(self) -> bool:
        """True when the file used absolute photometry (lamp lumens = -1)."""
        return self.lamp_lumens < 0

    @property
    def is_axially_symmetric(self) -> bool:
        """True when every azimuth has the same vertical profile."""
        return bool(np.allclose(self.candela, self.candela[:1], rtol=1e-9, atol=1e-12))

    @property
    def peak_candela(self) -> float:
        """The largest tabulated intensity (cd)."""
        return float(self.candela.max())

    def intensity(
        self, theta: np.ndarray | float, phi: np.ndarray | float, degrees: bool = True
    ) -> np.ndarray:
        """Bilinearly interpolated intensity (cd) for directions given as angles.

        Parameters
        ----------
        theta:
            Vertical angle(s) from the nadir (0 = down, 180 = up).
        phi:
            Azimuth(s) in the luminaire frame (0 = +X, 90 = +Y); wrapped
            modulo 360. Broadcast against ``theta``.
        degrees:
            Whether the angles are in degrees (default) or radians.

        Returns
        -------
        numpy.ndarray
            Intensity in candela with the broadcast shape of the inputs; zero
            outside the tabulated vertical range.
        """
        th = np.asarray(theta, dtype=np.float64)
        ph = np.asarray(phi, dtype=np.float64)
        if not degrees:
            th, ph = np.degrees(th), np.degrees(ph)
        th, ph = np.broadcast_arrays(th, ph)
        return _bilinear(self.vertical_angles, self.horizontal_angles, self.candela, th, ph)

    def intensity_dir(self, dirs_local: np.ndarray) -> np.ndarray:
        """Intensity (cd) for direction vectors in the luminaire frame.

        Parameters
        ----------
        dirs_local:
            ``(..., 3)`` directions (normalised here) in the luminaire frame:
            -Z is the nadir (``theta = 0``), +X is ``phi = 0``, +Y is ``phi = 90``.

        Returns
        -------
        numpy.ndarray
            ``(...)`` intensity in candela.
        """
        d = np.asarray(dirs_local, dtype=np.float64)
        if d.shape[-1] != 3:
            raise ValueError(f"expected (..., 3) directions, got {d.shape}")
        n = np.linalg.norm(d, axis=-1)
        n = np.where(n > 0, n, 1.0)
        theta = np.degrees(np.arccos(np.clip(-d[..., 2] / n, -1.0, 1.0)))
        phi = np.degrees(np.arctan2(d[..., 1], d[..., 0]))
        return self.intensity(theta, phi)

    def total_flux(self) -> float:
        """Luminous flux (lm): the bilinear intensity integrated exactly over the sphere."""
        return _sphere_integral(self.vertical_angles, self.horizontal_angles, self.candela)

    def scaled_to_flux(self, lumens: float) -> IESProfile:
        """Return a copy whose candela table is scaled so that :meth:`total_flux` is ``lumens``.

        Raises
        ------
        ValueError
            If the profile emits no light or ``lumens`` is negative.
        """
        if lumens < 0:
            raise ValueError("lumens must be non-negative")
        flux = self.total_flux()
        if flux <= 0:
            raise ValueError("cannot rescale a profile that emits no light")
        return replace(self, candela=self.candela * (lumens / flux))

    def to_tabulated(self, n_theta: int = 361, n_phi: int = 145) -> IntensityGrid:
        """Resample the intensity onto a regular node grid for an emitter texture.

        Parameters
        ----------
        n_theta:
            Number of vertical nodes; ``theta_i = 180 i / (n_theta - 1)`` deg.
        n_phi:
            Number of azimuth nodes; ``phi_j = 360 j / (n_phi - 1)`` deg, so
            the last column repeats the first. Use 2 for axially symmetric
            profiles.

        Returns
        -------
        IntensityGrid
            ``values`` has shape ``(n_theta, n_phi)`` in candela, row 0 at the nadir.
        """
        if n_theta < 2 or n_phi < 2:
            raise ValueError("n_theta and n_phi must be at least 2")
        theta = np.linspace(0.0, 180.0, n_theta)
        phi = np.linspace(0.0, 360.0, n_phi)
        values = self.intensity(theta[:, None], phi[None, :])
        values[:, -1] = values[:, 0]
        return IntensityGrid(theta, phi, values)

    def allclose(self, other: IESProfile, rtol: float = 1e-9, atol: float = 1e-9) -> bool:
        """True when both profiles have the same angles and candela table (within tolerance)."""
        return (
            self.vertical_angles.shape == other.vertical_angles.shape
            and self.horizontal_angles.shape == other.horizontal_angles.shape
            and np.allclose(self.vertical_angles, other.vertical_angles, rtol=rtol, atol=atol)
            and np.allclose(self.horizontal_angles, other.horizontal_angles, rtol=rtol, atol=atol)
            and np.allclose(self.candela, other.candela, rtol=rtol, atol=atol)
        )


# ---------------------------------------------------------------------- numerics
def _bilinear(
    v_deg: np.ndarray, h_deg: np.ndarray, table: np.ndarray, th: np.ndarray, ph: np.ndarray
) -> np.ndarray:
    """Bilinear interpolation of ``table[h, v]`` at ``(th, ph)`` degrees (zero outside ``v``)."""
    ph = np.mod(ph, 360.0)
    iv = np.clip(np.searchsorted(v_deg, th, side="right") - 1, 0, v_deg.size - 2)
    ih = np.clip(np.searchsorted(h_deg, ph, side="right") - 1, 0, h_deg.size - 2)
    tv = np.clip((th - v_deg[iv]) / (v_deg[iv + 1] - v_deg[iv]), 0.0, 1.0)
    th_ = np.clip((ph - h_deg[ih]) / (h_deg[ih + 1] - h_deg[ih]), 0.0, 1.0)
    row0 = table[ih, iv] * (1 - tv) + table[ih, iv + 1] * tv
    row1 = table[ih + 1, iv] * (1 - tv) + table[ih + 1, iv + 1] * tv
    out = row0 * (1 - th_) + row1 * th_
    inside = (th >= v_deg[0] - _ANGLE_TOL) & (th <= v_deg[-1] + _ANGLE_TOL)
    return np.where(inside, out, 0.0)


def _sphere_integral(v_deg: np.ndarray, h_deg: np.ndarray, table: np.ndarray) -> float:
    """Exact integral of the bilinear interpolant of ``table[h, v]`` times ``sin(theta)``.

    Bilinear in ``(theta, phi)`` means linear in ``phi`` (trapezoid weights are
    exact) and linear in ``theta`` on each interval, for which
    ``int (a + b t) sin t dt`` has a closed form. Computing the flux this way
    makes it consistent with :func:`_bilinear` to rounding error, whatever the
    grid spacing.
    """
    t = np.radians(np.asarray(v_deg, dtype=np.float64))
    p = np.radians(np.asarray(h_deg, dtype=np.float64))
    t0, t1 = t[:-1], t[1:]
    dt = t1 - t0
    # For f(t) = f0 (t1 - t)/dt + f1 (t - t0)/dt: int f sin = f0 w0 + f1 w1.
    w1 = (np.sin(t1) - np.sin(t0) - dt * np.cos(t1)) / dt
    w0 = (np.cos(t0) - np.cos(t1)) - w1
    wv = np.zeros_like(t)
    wv[:-1] += w0
    wv[1:] += w1
    dp = np.diff(p)
    wh = np.zeros_like(p)
    wh[:-1] += dp / 2
    wh[1:] += dp / 2
    return float(wh @ np.asarray(table, dtype=np.float64) @ wv)


# ---------------------------------------------------------------------- reading
def read_ies(path: str | Path) -> IESProfile:
    """Read an IES LM-63 file (1986 to 2002 formats) into an :class:`IESProfile`.

    Raises
    ------
    ScanError
        If the file is missing or malformed: no ``TILT=`` line, a lamp tilt
        table (``TILT=INCLUDE`` or a file name), type A/B photometry, the
        wrong count of numbers, non-numeric values, angles that are not
        increasing or out of range, unsupported horizontal symmetry, or
        negative candela.
    """
    path = Path(path)
    if not path.is_file():
        raise ScanError(path, "IES file is missing")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ScanError(path, f"cannot be read ({exc})") from exc
    return parse_ies(data, path)


def parse_ies(data: bytes | str, path: str | Path = "<ies>") -> IESProfile:
    """Parse the contents of an IES file; ``path`` only names the source in errors."""
    # Latin-1 maps every byte, and keyword text in the wild is often Windows-1252.
    text = data.decode("latin-1") if isinstance(data, bytes) else data
    text = text.replace("\x1a", "")  # DOS end-of-file markers left by old tools
    lines = text.splitlines()  # handles CRLF, LF and CR alike

    def fail(problem: str) -> ScanError:
        return ScanError(path, problem)

    source_format = "LM-63-1986"
    start = 0
    first = lines[0].strip().upper() if lines else ""
    if first.startswith("IESNA") or first.startswith("IES:"):
        ident = lines[0].strip()
        start = 1
        up = ident.upper()
        if up.startswith("IESNA91"):
            source_format = "LM-63-1991"
        elif "LM-63-1995" in up:
            source_format = "LM-63-1995"
        elif "LM-63-2002" in up:
            source_format = "LM-63-2002"
        else:
            source_format = ident.split(":", 1)[-1].strip() or ident

    keywords: dict[str, str] = {}
    last_key: str | None = None
    tilt_index = None
    for i in range(start, len(lines)):
        line = lines[i]
        m_tilt = _TILT_RE.match(line)
        if m_tilt:
            tilt_index = i
            tilt = m_tilt.group(1)
            break
        m_kw = _KEYWORD_RE.match(line)
        if m_kw:
            key, value = m_kw.group(1).strip().upper(), m_kw.group(2).rstrip()
            if key == "MORE" and last_key is not None:
                keywords[last_key] += "\n" + value
            elif key in keywords:
                keywords[key] += "\n" + value
                last_key = key
            else:
                keywords[key] = value
                last_key = key
        elif line.strip():
            keywords["_NOTES"] = (keywords.get("_NOTES", "") + "\n" + line.strip()).lstrip("\n")
    if tilt_index is None:
        raise fail("has no TILT= line (not an IES LM-63 file?)")
    if tilt.upper() != "NONE":
        what = "TILT=INCLUDE" if tilt.upper() == "INCLUDE" else f"a tilt file ({tilt!r})"
        raise fail(f"uses {what}; lamp-tilt tables are not supported (only TILT=NONE)")

    tokens = re.split(r"[\s,]+", "\n".join(lines[tilt_index + 1 :]).strip())
    tokens = [t for t in tokens if t]
    try:
        numbers = np.array([float(t) for t in tokens], dtype=np.float64)
    except ValueError as exc:
        raise fail(f"has a non-numeric value after TILT=NONE ({exc})") from exc
    if numbers.size < 13:
        raise fail(f"has only {numbers.size} numbers after TILT=NONE; the header alone needs 13")
    if not np.all(np.isfinite(numbers)):
        raise fail("has non-finite numbers")
    (num_lamps, lumens, multiplier, n_v, n_h, ptype, units, width, length, height) = numbers[:10]
    ballast, blp_factor, watts = numbers[10:13]
    for name, val in (("vertical", n_v), ("horizontal", n_h)):
        if val != int(val) or val < 1 or val > 100000:
            raise fail(f"has an invalid number of {name} angles ({val:g})")
    n_v, n_h = int(n_v), int(n_h)
    if int(ptype) != 1 or ptype != int(ptype):
        kind = {2: "type B", 3: "type A"}.get(int(ptype), f"unknown type {ptype:g}")
        raise fail(f"uses {kind} photometry; only type C (1) is supported")
    if int(units) not in _UNITS or units != int(units):
        raise fail(f"has unknown units type {units:g} (expected 1 = feet or 2 = meters)")
    expected = 13 + n_v + n_h + n_v * n_h
    if numbers.size != expected:
        raise fail(
            f"has {numbers.size} numbers after TILT=NONE; expected {expected} "
            f"for {n_v} vertical x {n_h} horizontal angles"
        )
    if n_v < 2:
        raise fail("has fewer than 2 vertical angles")
    off = 13
    v = numbers[off : off + n_v]
    off += n_v
    h = numbers[off : off + n_h]
    off += n_h
    cd = numbers[off:].reshape(n_h, n_v)
    if np.any(np.diff(v) <= 0):
        raise fail("has vertical angles that are not strictly increasing")
    if n_h > 1 and np.any(np.diff(h) <= 0):
        raise fail("has horizontal angles that are not strictly increasing")
    if v[0] < -_ANGLE_TOL or v[-1] > 180 + _ANGLE_TOL:
        raise fail(f"has vertical angles outside 0..180 ({v[0]:g} to {v[-1]:g})")
    if np.any(cd < 0):
        raise fail("has negative candela values")
    v = np.clip(v, 0.0, 180.0)

    factor = multiplier * ballast
    if source_format in ("LM-63-1986", "LM-63-1991", "LM-63-1995") and blp_factor > 0:
        # Before 2002 this field was the ballast-lamp photometric factor (a multiplier);
        # LM-63-2002 reserves it ("future use") and tells readers to ignore it.
        factor *= blp_factor
    if factor < 0:
        raise fail(f"has a negative candela multiplier ({factor:g})")
    try:
        h_full, cd_full, symmetry = _unfold(h, cd * factor)
    except ValueError as exc:
        raise fail(str(exc)) from exc
    return IESProfile(
        vertical_angles=v,
        horizontal_angles=h_full,
        candela=cd_full,
        keywords=keywords,
        lamp_lumens=float(lumens),
        num_lamps=int(num_lamps),
        units=_UNITS[int(units)],
        width=float(width),
        length=float(length),
        height=float(height),
        input_watts=float(watts),
        symmetry=symmetry,
        source_format=source_format,
    )


def _unfold(h: np.ndarray, cd: np.ndarray) -> tuple[np.ndarray, np.ndarray, str]:
    """Unfold type C horizontal symmetry to a 0..360 table (the 360 row repeats the 0 row)."""

    def close(a: float, b: float) -> bool:
        return abs(a - b) <= 1e-4

    first, last = float(h[0]), float(h[-1])
    if h.size == 1:
        if not close(first, 0.0) and not (0.0 <= first <= 360.0):
            raise ValueError(f"has a single horizontal angle {first:g} outside 0..360")
        return np.array([0.0, 360.0]), np.vstack([cd, cd]), "axial"
    if close(first, 0.0) and close(last, 90.0):
        # Quadrant: 0..90 -> mirror to 90..180 -> mirror to 180..360.
        h180 = np.concatenate([h, 180.0 - h[-2::-1]])
        cd180 = np.vstack([cd, cd[-2::-1]])
        h360 = np.concatenate([h180, 360.0 - h180[-2::-1]])
        return h360, np.vstack([cd180, cd180[-2::-1]]), "quadrant"
    if close(first, 0.0) and close(last, 180.0):
        return np.concatenate([h, 360.0 - h[-2::-1]]), np.vstack([cd, cd[-2::-1]]), "bilateral"
    if close(first, 90.0) and close(last, 270.0):
        # Mirror about the 90-270 plane: I(phi) = I(180 - phi) (mod 360).
        lo = h <= 180.0 + 1e-9  # 90..180 mirrors to 90..0
        hi = h >= 180.0 - 1e-9  # 180..270 mirrors to 270..360
        h_lo = 180.0 - h[lo][::-1]
        cd_lo = cd[lo][::-1]
        h_hi = 540.0 - h[hi][::-1]
        cd_hi = cd[hi][::-1]
        hh = np.concatenate([h_lo[:-1], h, h_hi[1:]])
        cc = np.vstack([cd_lo[:-1], cd, cd_hi[1:]])
        return hh, cc, "bilateral90"
    if close(first, 0.0) and last > 180.0 and last <= 360.0 + 1e-4:
        hh, cc = h.copy(), cd.copy()
        hh[0] = 0.0
        if close(last, 360.0):
            hh[-1] = 360.0
            symmetric = np.allclose(cc, cc[:1])
            return hh, cc, "axial" if symmetric else "full"
        # An open 0..<360 table: close it periodically.
        return np.append(hh, 360.0), np.vstack([cc, cc[:1]]), "full"
    raise ValueError(
        f"has horizontal angles {first:g}..{last:g}, which is no type C symmetry "
        "(expected 0, 0..90, 0..180, 90..270 or 0..360)"
    )


# ---------------------------------------------------------------------- writing
def _fmt(x: float) -> str:
    """Shortest decimal that reads back to the same float64, without exponents."""
    return np.format_float_positional(float(x), unique=True, trim="-")


def _wrap(values: np.ndarray, per_line: int = 10) -> list[str]:
    vals = [_fmt(x) for x in np.ravel(values)]
    return [" ".join(vals[i : i + per_line]) for i in range(0, len(vals), per_line)]


def format_ies(profile: IESProfile) -> str:
    """Serialise ``profile`` as LM-63-2002 text (CRLF line endings, as the standard asks)."""
    lines = ["IESNA:LM-63-2002"]
    keywords = dict(profile.keywords)
    for key in REQUIRED_KEYWORDS_2002:
        # The standard requires these; placeholders keep strict readers happy.
        keywords.setdefault(key, "unknown")
    for key, value in keywords.items():
        key_text = key.upper().strip() or "_NOTES"
        parts = str(value).split("\n")
        lines.append(f"[{key_text}] {parts[0]}".rstrip())
        lines.extend(f"[MORE] {p}".rstrip() for p in parts[1:])
    lines.append("TILT=NONE")
    if profile.is_axially_symmetric:
        h = np.array([0.0])
        cd = profile.candela[:1]
    else:
        h = profile.horizontal_angles
        cd = profile.candela
    v = profile.vertical_angles
    lines.append(
        " ".join(
            [
                str(int(profile.num_lamps)),
                _fmt(profile.lamp_lumens),
                "1",  # candela multiplier: already applied to the table
                str(v.size),
                str(h.size),
                "1",  # photometric type C
                str(_UNIT_CODES[profile.units]),
                _fmt(profile.width),
                _fmt(profile.length),
                _fmt(profile.height),
            ]
        )
    )
    lines.append(f"1 1 {_fmt(profile.input_watts)}")  # ballast factor: already applied
    lines.extend(_wrap(v))
    lines.extend(_wrap(h))
    for row in cd:
        lines.extend(_wrap(row))
    return "\r\n".join(lines) + "\r\n"


def write_ies(path: str | Path, profile: IESProfile) -> Path:
    """Write ``profile`` as an LM-63-2002 IES file, atomically.

    The multiplier and ballast factor are written as 1 (the table already
    includes them); an axially symmetric profile is written as a single
    horizontal plane, anything else as the full 0..360 table. Missing
    required keywords (``TEST``, ``TESTLAB``, ``ISSUEDATE``, ``MANUFAC``) are
    written as ``unknown``.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    text = format_ies(profile)
    with atomic_path(path) as tmp:
        tmp.write_bytes(text.encode("latin-1", errors="replace"))
    return Path(path)
