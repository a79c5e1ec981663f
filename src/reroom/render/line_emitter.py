"""``reroom_line``: a generalized line light (thesis §5.5.4) as a Python Mitsuba emitter.

A straight emitter from ``p0`` to ``p1`` (a fluorescent tube, an LED strip, a cove
light) whose intensity varies around its axis and, optionally, with the angle out of
the plane perpendicular to it (a tube in a channel open at its ends), but not with the
position along it. Every element ``dx`` of the line emits in the unit direction ``e``
(from the line towards the receiver) the radiant intensity

``dI = scale * color * J(theta, phi) * cos(phi) * dx``  (W/sr),

where ``phi`` is the angle between ``e`` and the plane perpendicular to the line (so
``cos(phi) = |e_perp|``: the element's projected length, the ``a . a_perp`` factor of
eq. 5.11; ``sin(phi) = e . t`` with ``t`` the unit vector ``p0 -> p1``, so ``phi > 0``
towards ``p1``) and ``theta`` the angle between ``e_perp`` and ``up_perp``, the
component of ``up`` perpendicular to the line: ``theta = 0`` emits towards ``up``,
``theta = pi`` away from it (for a ceiling tube with ``up = +Z``: straight down). The
profile is symmetric about ``up_perp`` (the thesis's assumption; real tubes in housings
are). ``J`` (W/(sr m)) is a table ``profile`` of ``(n_theta,)`` values (the thesis's
separable ``J(theta)``) or ``(n_theta, n_phi)`` values: bins of equal width of ``theta``
in ``[0, pi]`` and of ``|phi|`` in ``[0, pi/2]`` (``phi_fold``, the default: both ends
alike) or of ``phi`` in ``[-pi/2, pi/2]``, as
:class:`reroom.invert.basis.LineBasis`. Either constant per bin
(``interpolation="constant"``, the basis the inverse renderer solves in) or linear
between bin centres, in each angle, clamped at the ends (``"linear"``; smoother
renders).

Irradiance on a receiver (normal ``n``) is therefore eq. 5.11 times ``J``:
``E = integral J(theta, phi) cos(phi) (n . -e) / r^2 dx``, and the emitted power is
``scale * color * length * integral J cos(phi) d omega`` (``d omega = cos(phi) dphi
dtheta``), ``scale * color * pi * length * integral_0^pi J(theta) dtheta`` for a
separable table (:func:`line_light_power`).

Sampling: next-event estimation picks a point uniformly along the line (pdf
``1 / length``) and returns ``dI / r^2 * length``; the light has no area, so it is
flagged as a delta position (BSDF-sampled rays never hit it, as with point lights).
``sample_ray`` (light tracing) picks a uniform point and a uniform direction.

Properties: ``p0``, ``p1`` (points), ``up`` (vector, default ``[0, 0, 1]``),
``profile`` (``TensorXf`` of ``n >= 1`` values >= 0 or of shape ``(n_theta, n_phi)``,
or a float for a uniform line), ``phi_fold`` (bool, default true), ``interpolation``
(``"linear"`` default, or ``"constant"``), ``color`` (3 floats), ``scale`` (float),
``clearance`` (metres, default 0).

``clearance`` makes the profile the light *as seen from outside a cylinder* of that radius
around the segment, as ``reroom invert`` solves it (``InvertOptions.line_clearance``):
nothing within the cylinder shadows the light, so the tube's own housing and baffles,
whose occlusion is already in the solved profile, do not block it a second time. Each
shadow ray ends where it enters the cylinder, ``clearance / sin(angle to the line)``
short of the sampled point on the line (as :func:`reroom.invert.direct.line_light_transfer`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from types import ModuleType
from typing import Any

import numpy as np

__all__ = ["LINE", "line_light", "line_light_power", "line_profile_value"]

LINE = "reroom_line"


def _perp_up(p0: np.ndarray, p1: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t = p1 - p0
    length = float(np.linalg.norm(t))
    if not np.isfinite(length) or length <= 0:
        raise ValueError(f"{LINE}: p0 and p1 must be distinct finite points")
    t = t / length
    u = up - (up @ t) * t
    n = float(np.linalg.norm(u))
    if n < 1e-6:
        raise ValueError(f"{LINE}: 'up' must not be parallel to the line")
    return t, u / n


def _interp_index(f: np.ndarray, n: int, interpolation: str) -> tuple[np.ndarray, np.ndarray]:
    """Lower node and weight of the upper one, for a bin coordinate ``f`` in ``[0, n]``."""
    if interpolation == "constant" or n == 1:
        return np.minimum(f.astype(np.int64), n - 1), np.zeros_like(f)
    x = np.clip(f - 0.5, 0.0, n - 1.0)
    i = np.minimum(x.astype(np.int64), n - 2)
    return i, x - i


def _phi_coordinate(phi: np.ndarray, n_phi: int, fold: bool) -> np.ndarray:
    """Bin coordinate in ``[0, n_phi]`` of signed ``phi`` (radians)."""
    p = np.clip(np.asarray(phi, np.float64), -math.pi / 2, math.pi / 2)
    if fold:
        return np.abs(p) * (n_phi / (math.pi / 2))
    return (p + math.pi / 2) * (n_phi / math.pi)


def line_profile_value(
    profile: np.ndarray,
    theta: np.ndarray,
    interpolation: str = "linear",
    phi: np.ndarray | None = None,
    fold: bool = True,
) -> np.ndarray:
    """``J(theta)`` or ``J(theta, phi)`` of a profile table (numpy twin of the emitter's lookup).

    ``profile`` is ``(n_theta,)``, or ``(n_theta, n_phi)`` with ``phi`` (signed, radians)
    given; ``fold`` as the emitter's ``phi_fold``.
    """
    if interpolation not in ("linear", "constant"):
        raise ValueError(f"interpolation must be 'linear' or 'constant', not {interpolation!r}")
    prof = np.asarray(profile, np.float64)
    if prof.ndim == 2 and prof.shape[1] == 1:
        prof = prof[:, 0]
    prof = np.atleast_1d(prof)
    f = np.clip(np.asarray(theta, np.float64), 0.0, math.pi) * (len(prof) / math.pi)
    if prof.ndim == 1:
        n = len(prof)
        i, w = _interp_index(f, n, interpolation)
        if interpolation == "constant" or n == 1:
            return prof[i]
        return (1.0 - w) * prof[i] + w * prof[i + 1]
    if phi is None:
        raise ValueError("a (theta, phi) profile needs phi")
    n_t, n_p = prof.shape
    f, g = np.broadcast_arrays(f, _phi_coordinate(phi, n_p, fold))
    it, wt = _interp_index(f, n_t, interpolation)
    ip, wp = _interp_index(g, n_p, interpolation)
    jt = np.minimum(it + 1, n_t - 1)
    jp = np.minimum(ip + 1, n_p - 1)
    return (1.0 - wt) * ((1.0 - wp) * prof[it, ip] + wp * prof[it, jp]) + wt * (
        (1.0 - wp) * prof[jt, ip] + wp * prof[jt, jp]
    )


def line_light_power(
    profile: np.ndarray | float,
    length: float,
    scale: float = 1.0,
    interpolation: str = "linear",
    samples: int = 20001,
    fold: bool = True,
) -> float:
    """Emitted power (W, per unit ``color``) of a line light: ``L scale int J cos(phi) d omega``.

    ``pi L scale int J dtheta`` for a separable ``(n_theta,)`` table; a ``(n_theta,
    n_phi)`` table is integrated over ``theta`` and ``phi`` with ``d omega = cos(phi)
    dphi dtheta`` on both sides of ``up``.
    """
    prof = np.asarray(profile, np.float64)
    theta = np.linspace(0.0, math.pi, samples)
    if prof.ndim < 2 or prof.shape[1] == 1:
        j = line_profile_value(np.atleast_1d(prof.reshape(-1)), theta, interpolation)
        return float(math.pi * length * scale * np.trapezoid(j, theta))
    # Midpoints in phi (the table is piecewise in phi), trapezoid in theta.
    m = max(64, 8 * prof.shape[1])
    phi = (np.arange(m) + 0.5) / m * math.pi - math.pi / 2
    j = line_profile_value(prof, theta[:, None], interpolation, phi[None, :], fold)
    inner = (j * np.cos(phi)[None, :] ** 2).sum(axis=1) * (math.pi / m)
    return float(2.0 * length * scale * np.trapezoid(inner, theta))


def line_light(
    p0: Sequence[float],
    p1: Sequence[float],
    profile: np.ndarray | float,
    up: Sequence[float] = (0.0, 0.0, 1.0),
    color: Sequence[float] = (1.0, 1.0, 1.0),
    scale: float = 1.0,
    interpolation: str = "linear",
    phi_fold: bool = True,
    clearance: float = 0.0,
) -> dict[str, Any]:
    """Build a ``reroom_line`` emitter dict for ``mi.load_dict`` (see the module docstring).

    ``clearance`` (metres): nothing within this distance of the line shadows it.

    ``profile``: ``(n_theta,)`` (separable) or ``(n_theta, n_phi)``; a ``(n_theta, 1)``
    table is the separable one.
    """
    from reroom.render.emitters import register_emitters

    mi = register_emitters()
    a, b, u = (np.asarray(x, np.float64) for x in (p0, p1, up))
    _perp_up(a, b, u)  # validates
    prof = _check_profile(profile)
    d = {
        "type": LINE,
        "p0": a.tolist(),
        "p1": b.tolist(),
        "up": u.tolist(),
        "profile": mi.TensorXf(prof.astype(np.float32)),
        "interpolation": interpolation,
        "color": [float(c) for c in color],
        "scale": float(scale),
    }
    if prof.ndim == 2:
        d["phi_fold"] = bool(phi_fold)
    if not (np.isfinite(clearance) and clearance >= 0):
        raise ValueError(f"{LINE}: clearance must be a distance >= 0, got {clearance!r}")
    if clearance > 0:
        d["clearance"] = float(clearance)
    return d


def _check_profile(profile: Any) -> np.ndarray:
    """The profile table as float64: ``(n,)``, or ``(n_theta, n_phi)`` with ``n_phi > 1``."""
    prof = np.atleast_1d(np.asarray(profile, np.float64))
    if prof.ndim == 2 and prof.shape[1] == 1:
        prof = prof[:, 0]
    if prof.ndim not in (1, 2) or prof.size == 0:
        raise ValueError(f"{LINE}: profile must be a 1D or (theta, phi) table, not {prof.shape}")
    if not np.all(np.isfinite(prof)) or np.any(prof < 0):
        raise ValueError(f"{LINE}: profile must be a table of finite values >= 0")
    return prof


def make_line_class(mi: ModuleType) -> type:
    """Define the ``reroom_line`` plugin class for the current (JIT, RGB) variant."""
    import drjit as dr

    from reroom.render.emitters import make_shadow_end

    shadow_end = make_shadow_end(mi)

    class LineEmitter(mi.Emitter):
        """Generalized line light (see :mod:`reroom.render.line_emitter`)."""

        def __init__(self, props: Any) -> None:
            super().__init__(props)

            def vec(name: str, default: Sequence[float] | None = None) -> np.ndarray:
                if name in props:
                    return np.array(props[name], dtype=np.float64).ravel()
                if default is None:
                    raise ValueError(f"{LINE}: missing property '{name}'")
                return np.asarray(default, np.float64)

            p0, p1 = vec("p0"), vec("p1")
            up = vec("up", (0.0, 0.0, 1.0))
            tangent, up_perp = _perp_up(p0, p1, up)
            prof = _check_profile(np.array(props["profile"]) if "profile" in props else 1.0)
            fold = bool(props["phi_fold"]) if "phi_fold" in props else True
            interp = str(props["interpolation"]) if "interpolation" in props else "linear"
            if interp not in ("linear", "constant"):
                raise ValueError(f"{LINE}: interpolation must be 'linear' or 'constant'")
            color = vec("color", (1.0, 1.0, 1.0))
            scale = float(props["scale"]) if "scale" in props else 1.0
            clearance = float(props["clearance"]) if "clearance" in props else 0.0
            if not math.isfinite(clearance) or clearance < 0:
                raise ValueError(f"{LINE}: 'clearance' must be a distance >= 0")
            self.clearance = clearance

            self._p0, self._p1 = p0, p1
            self.length = float(np.linalg.norm(p1 - p0))
            self.n_bins = prof.shape[0]
            self.n_phi = prof.shape[1] if prof.ndim == 2 else 1
            self.fold = fold
            self.linear = interp == "linear" and self.n_bins > 1
            self.linear_phi = interp == "linear" and self.n_phi > 1
            self.m_p0 = mi.Point3f(*map(float, p0))
            self.m_dir = mi.Vector3f(*map(float, p1 - p0))
            self.m_tangent = mi.Vector3f(*map(float, tangent))
            self.m_up = mi.Vector3f(*map(float, up_perp))
            self.m_side = mi.Vector3f(*map(float, np.cross(tangent, up_perp)))
            self.m_profile = mi.Float(prof.reshape(-1).astype(np.float32))  # theta-major
            self.m_color = mi.Color3f(*[float(c) for c in np.broadcast_to(color, (3,))])
            self.m_scale = mi.Float(scale * self.length)  # length = 1 / pdf of the point
            dr.make_opaque(self.m_p0, self.m_dir, self.m_tangent, self.m_up, self.m_side)
            dr.make_opaque(self.m_color, self.m_scale)
            self.m_flags = mi.EmitterFlags.DeltaPosition

        def _profile(self, e: Any, active: Any = True) -> Any:
            """``J(theta, phi) cos(phi)`` for unit emission directions ``e``."""
            along = dr.dot(e, self.m_tangent)
            cos_phi = dr.safe_sqrt(1.0 - dr.square(along))
            # theta from the components of e_perp in the (up, side) plane; symmetric
            # about up, so |side| suffices.
            theta = dr.atan2(dr.abs(dr.dot(e, self.m_side)), dr.dot(e, self.m_up))
            f = theta * (self.n_bins / math.pi)
            if self.n_phi == 1:
                if self.linear:
                    x = dr.clip(f - 0.5, 0.0, self.n_bins - 1.0)
                    i = dr.minimum(mi.UInt32(x), self.n_bins - 2)
                    w = x - mi.Float(i)
                    v0 = dr.gather(mi.Float, self.m_profile, i, active)
                    v1 = dr.gather(mi.Float, self.m_profile, i + 1, active)
                    value = dr.lerp(v0, v1, w)
                else:
                    i = dr.minimum(mi.UInt32(dr.maximum(f, 0.0)), self.n_bins - 1)
                    value = dr.gather(mi.Float, self.m_profile, i, active)
                return value * cos_phi
            # phi from sin(phi) = e . t, folded to |phi| or shifted to [0, pi]
            phi = dr.atan2(along, cos_phi)
            if self.fold:
                g = dr.abs(phi) * (self.n_phi / (0.5 * math.pi))
            else:
                g = (phi + 0.5 * math.pi) * (self.n_phi / math.pi)
            it, wt = self._node(f, self.n_bins, self.linear)
            ip, wp = self._node(g, self.n_phi, self.linear_phi)
            jt = dr.minimum(it + 1, self.n_bins - 1)
            jp = dr.minimum(ip + 1, self.n_phi - 1)

            def at(a: Any, b: Any) -> Any:
                return dr.gather(mi.Float, self.m_profile, a * self.n_phi + b, active)

            value = dr.lerp(
                dr.lerp(at(it, ip), at(it, jp), wp), dr.lerp(at(jt, ip), at(jt, jp), wp), wt
            )
            return value * cos_phi

        def _node(self, f: Any, n: int, linear: bool) -> tuple[Any, Any]:
            """Lower table node and the upper one's weight for bin coordinate ``f``."""
            if linear:
                x = dr.clip(f - 0.5, 0.0, n - 1.0)
                i = dr.minimum(mi.UInt32(x), n - 2)
                return i, x - mi.Float(i)
            return dr.minimum(mi.UInt32(dr.maximum(f, 0.0)), n - 1), mi.Float(0.0)

        def _point(self, u: Any) -> Any:
            return self.m_p0 + self.m_dir * u

        def sample_direction(self, it: Any, sample: Any, active: Any = True) -> Any:
            ds = dr.zeros(mi.DirectionSample3f)
            ds.p = self._point(sample.x)
            ds.n = mi.Normal3f(0.0)
            ds.uv = mi.Point2f(sample.x, 0.0)
            ds.time = it.time
            ds.pdf = mi.Float(1.0)
            ds.delta = mi.Bool(True)
            ds.emitter = mi.EmitterPtr(self)
            d = ds.p - it.p
            dist2 = dr.squared_norm(d)
            inv_dist = dr.rsqrt(dist2)
            ds.d = d * inv_dist
            ds.dist = dr.sqrt(dist2)
            spec = self.m_color * (self._profile(-ds.d, active) * self.m_scale / dist2)
            if self.clearance > 0:
                # Along the ray, the cylinder of radius `clearance` about the line starts
                # clearance / sin(angle between the ray and the line) before the point.
                sin = dr.safe_sqrt(1.0 - dr.square(dr.dot(ds.d, self.m_tangent)))
                clear = self.clearance / dr.maximum(sin, 1e-6)
                ds.p = shadow_end(it.p, ds.d, ds.dist, clear)
            return ds, dr.select(active & (dist2 > 0), mi.Spectrum(spec), 0.0)

        def pdf_direction(self, it: Any, ds: Any, active: Any = True) -> Any:
            return mi.Float(0.0)

        def eval_direction(self, it: Any, ds: Any, active: Any = True) -> Any:
            d = ds.p - it.p
            dist2 = dr.squared_norm(d)
            e = -d * dr.rsqrt(dist2)
            spec = self.m_color * (self._profile(e, active) * self.m_scale / dist2)
            return dr.select(active, mi.Spectrum(spec), 0.0)

        def eval(self, si: Any, active: Any = True) -> Any:
            return mi.Spectrum(0.0)  # a line has no area: rays never hit it

        def sample_position(self, time: Any, sample: Any, active: Any = True) -> Any:
            ps = dr.zeros(mi.PositionSample3f)
            ps.p = self._point(sample.x)
            ps.time = time
            ps.pdf = mi.Float(1.0)
            ps.delta = mi.Bool(True)
            return ps, mi.Float(1.0)

        def pdf_position(self, ps: Any, active: Any = True) -> Any:
            return mi.Float(0.0)

        def sample_ray(
            self, time: Any, sample1: Any, sample2: Any, sample3: Any, active: Any = True
        ) -> Any:
            # Uniform point on the line, uniform direction on the sphere.
            p = self._point(sample2.x)
            d = mi.warp.square_to_uniform_sphere(sample3)
            weight = self.m_color * (self._profile(d, active) * self.m_scale * (4.0 * math.pi))
            wavelengths = dr.zeros(mi.Color0f, dr.width(sample1)) if hasattr(mi, "Color0f") else 0
            return mi.Ray3f(p, d, time, wavelengths), dr.select(active, mi.Spectrum(weight), 0.0)

        def sample_wavelengths(self, si: Any, sample: Any, active: Any = True) -> Any:
            wl = dr.zeros(type(si.wavelengths), dr.width(si.p))
            e = dr.normalize(si.wi)
            spec = self.m_color * (self._profile(e, active) * self.m_scale)
            return wl, dr.select(active, mi.Spectrum(spec), 0.0)

        def bbox(self) -> Any:
            bb = mi.ScalarBoundingBox3f(mi.ScalarPoint3f(*[float(x) for x in self._p0]))
            bb.expand(mi.ScalarPoint3f(*[float(x) for x in self._p1]))
            return bb

        def traverse(self, callback: Any) -> None:
            callback.put("color", self.m_color, mi.ParamFlags.Differentiable)

        def to_string(self) -> str:
            return (
                f"LineEmitter[p0={self._p0.tolist()}, p1={self._p1.tolist()}, "
                f"bins={self.n_bins}x{self.n_phi}, linear={self.linear}]"
            )

    return LineEmitter
