"""Projectile shapes on the Python side: dimensions, volume, centre of mass, principal inertia at
uniform density, bounding radius and a surface mesh (for ParaView, plots and the start position).

The compiled inside test, closest point and normal are in emfabric._kernels.shapes; both read
the same dimensions (``ShapeGeometry``). Coordinates here are the shape's own frame: e3 the nose
axis, s the height above the base face (s = 0 … L); the centre of mass sits on the axis at
s = ``base``. Mass properties integrate the cross-sections slice by slice (Gauss–Legendre on
each smooth piece), exact to round-off for these profiles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

FSP_LENGTH_PER_DIAMETER = 1.16
"""FSP overall length / diameter (MIL-DTL-46593B, .22 calibre: 0.254 in / 0.219 in)."""
FSP_BEVEL = math.radians(35.0)
"""FSP: angle between each chisel face and the axis."""
FSP_FLAT_PER_DIAMETER = 0.16
"""FSP: width of the flat between the chisel faces / diameter."""

_GL_X, _GL_W = np.polynomial.legendre.leggauss(64)


def _gauss(a: float, b: float) -> tuple[np.ndarray, np.ndarray]:
    """64-point Gauss–Legendre nodes and weights on [a, b]."""
    half = 0.5 * (b - a)
    return a + half * (_GL_X + 1.0), half * _GL_W


@dataclass(frozen=True)
class ShapeGeometry:
    """Dimensions of one projectile shape [m] and what follows from them (each quadrature is
    computed once per instance: the run's stop rule reads `bound` every step)."""

    kind: str
    radius: float
    length: float = 0.0
    nose_length: float = 0.0
    flat_half_width: float = 0.0
    bevel: float = 0.0

    @cached_property
    def arc_radius(self) -> float:
        """Ogive: radius of the tangent arc, ϱ = (R² + L_n²)/(2R)."""
        if self.kind != "ogive":
            return 0.0
        return (self.radius**2 + self.nose_length**2) / (2.0 * self.radius)

    # ---- cross-sections -------------------------------------------------------------------
    def _pieces(self) -> list[tuple[float, float]]:
        """Intervals of s on which the cross-section varies smoothly."""
        big_l, big_r = self.length, self.radius
        if self.kind == "ogive":
            cuts = [0.0, big_l - self.nose_length, big_l]
        elif self.kind == "fsp":
            start = big_l - (big_r - self.flat_half_width) / math.tan(self.bevel)
            cuts = [0.0, max(start, 0.0), big_l]
        else:
            cuts = [0.0, big_l]
        return [(a, b) for a, b in zip(cuts[:-1], cuts[1:], strict=True) if b > a]

    def profile_radius(self, s: np.ndarray) -> np.ndarray:
        """Radius of the body of revolution at height s (ogive, cylinder)."""
        s = np.asarray(s, dtype=float)
        if self.kind != "ogive":
            return np.full_like(s, self.radius)
        rho = self.arc_radius
        lb = self.length - self.nose_length
        ds = np.maximum(s - lb, 0.0)
        return np.sqrt(np.maximum(rho**2 - ds**2, 0.0)) + self.radius - rho

    def _sections(self, s: np.ndarray):
        """Area A(s) and second moments ∫x² dA, ∫y² dA of the cross-sections at heights s."""
        big_r = self.radius
        if self.kind != "fsp":
            r = self.profile_radius(s)
            area = math.pi * r**2
            return area, area * r**2 / 4.0, area * r**2 / 4.0
        # disk ∩ strip |y| ≤ h(s), integrated over y = R sin θ (smooth in θ)
        h = self.flat_half_width + (self.length - s) * math.tan(self.bevel)
        th = np.arcsin(np.minimum(h / big_r, 1.0))
        area = np.empty_like(s)
        sxx = np.empty_like(s)
        syy = np.empty_like(s)
        for i, t in enumerate(th):
            x, w = _gauss(-t, t)
            c, sn = np.cos(x), np.sin(x)
            area[i] = np.sum(w * 2.0 * big_r**2 * c**2)
            syy[i] = np.sum(w * 2.0 * big_r**4 * sn**2 * c**2)
            sxx[i] = np.sum(w * (2.0 / 3.0) * big_r**4 * c**4)
        return area, sxx, syy

    def _integrate(self, fn) -> float:
        total = 0.0
        for a, b in self._pieces():
            s, w = _gauss(a, b)
            total += float(np.sum(w * fn(s)))
        return total

    # ---- mass properties ------------------------------------------------------------------
    @cached_property
    def volume(self) -> float:
        if self.kind == "sphere":
            return 4.0 / 3.0 * math.pi * self.radius**3
        return self._integrate(lambda s: self._sections(s)[0])

    @cached_property
    def base(self) -> float:
        """Height of the centre of mass above the base face (0 for the sphere)."""
        if self.kind == "sphere":
            return 0.0
        return self._integrate(lambda s: s * self._sections(s)[0]) / self.volume

    def principal_inertia(self, mass: float) -> np.ndarray:
        """Moments of inertia about the centre of mass along e1, e2, e3 at uniform density."""
        if self.kind == "sphere":
            return np.full(3, 0.4 * mass * self.radius**2)
        rho = mass / self.volume
        sc = self.base

        def about(which):
            def fn(s):
                area, sxx, syy = self._sections(s)
                arm = (s - sc) ** 2 * area
                return (syy + arm, sxx + arm, sxx + syy)[which]
            return fn

        return np.array([rho * self._integrate(about(k)) for k in range(3)])

    @cached_property
    def bound(self) -> float:
        """Largest distance from the centre of mass to the surface."""
        if self.kind == "sphere":
            return self.radius
        sc = self.base
        s = np.linspace(0.0, self.length, 4001)
        r = self.profile_radius(s) if self.kind == "ogive" else np.full_like(s, self.radius)
        return float(np.sqrt(((s - sc) ** 2 + r**2).max()))

    def extent(self, direction) -> float:
        """Largest q·direction over the body (q relative to the centre of mass, shape frame):
        the support function, from a dense sampling of the surface (to ~1e-6 R)."""
        d = np.asarray(direction, dtype=float)
        if self.kind == "sphere":
            return self.radius * float(np.linalg.norm(d))
        s = np.union1d(np.linspace(0.0, self.length, 2001),
                       [c for piece in self._pieces() for c in piece])
        if self.kind != "fsp":
            r = self.profile_radius(s)
            return float((r * math.hypot(d[0], d[1]) + (s - self.base) * d[2]).max())
        th = np.linspace(0.0, 2.0 * math.pi, 2048, endpoint=False)
        ymax = self.flat_half_width + (self.length - s) * math.tan(self.bevel)
        x = self.radius * np.cos(th)[None, :]
        y = np.clip(self.radius * np.sin(th)[None, :], -ymax[:, None], ymax[:, None])
        best = float((x * d[0] + y * d[1] + (s - self.base)[:, None] * d[2]).max())
        # the corners where a chisel face meets the cylinder, exactly
        yc = np.minimum(ymax, self.radius)
        xc = np.sqrt(self.radius**2 - yc**2)
        for sx in (1.0, -1.0):
            for sy in (1.0, -1.0):
                best = max(best, float((sx * xc * d[0] + sy * yc * d[1]
                                        + (s - self.base) * d[2]).max()))
        return best

    # ---- surface ----------------------------------------------------------------------------
    def mesh(self, n_az: int = 48, n_axial: int = 24) -> tuple[np.ndarray, np.ndarray]:
        """Points (P, 3) relative to the centre of mass in the shape frame and triangles (T, 3):
        a closed surface whose vertices lie on the body's surface."""
        if self.kind == "sphere":
            return _sphere_mesh(self.radius, n_az // 4 + 1, n_az)
        big_l, big_r = self.length, self.radius
        lb = big_l - self.nose_length if self.kind == "ogive" else big_l
        # meridian profile from the base centre to the top centre (or the tip)
        side = np.linspace(0.0, lb, max(2, n_axial // 2 if self.kind == "ogive" else n_axial))
        prof = [(0.0, 0.0), *[(0.0, big_r * f) for f in (0.5,)]]
        prof += [(s, big_r) for s in side]
        if self.kind == "ogive":
            s = np.linspace(lb, big_l, n_axial + 1)[1:]
            prof += list(zip(s, self.profile_radius(s), strict=True))
            prof[-1] = (big_l, 0.0)
        else:
            prof += [(big_l, big_r * f) for f in (0.5, 0.0)]
        prof_arr = np.array(prof)
        phi = np.linspace(0.0, 2.0 * math.pi, n_az, endpoint=False)
        pts = []
        index = {}
        for i, (s, r) in enumerate(prof_arr):
            if r == 0.0:
                index[i] = [len(pts)] * n_az
                pts.append((0.0, 0.0, s))
            else:
                index[i] = list(range(len(pts), len(pts) + n_az))
                pts.extend((r * math.cos(p), r * math.sin(p), s) for p in phi)
        tris = []
        for i in range(len(prof_arr) - 1):
            lo, hi = index[i], index[i + 1]
            for k in range(n_az):
                k1 = (k + 1) % n_az
                for tri in ((lo[k], lo[k1], hi[k1]), (lo[k], hi[k1], hi[k])):
                    if len(set(tri)) == 3:
                        tris.append(tri)
        p = np.array(pts)
        if self.kind == "fsp":
            # the chisel faces: clamp |y| to the face at each height
            ymax = self.flat_half_width + (big_l - p[:, 2]) * math.tan(self.bevel)
            p[:, 1] = np.clip(p[:, 1], -ymax, ymax)
        p[:, 2] -= self.base
        return p, np.array(tris, dtype=np.int64)


def _sphere_mesh(radius: float, n_lat: int = 12, n_lon: int = 24):
    """A UV-sphere surface (points relative to the centre, triangles)."""
    pts = [[0.0, 0.0, radius]]
    for i in range(1, n_lat):
        th = np.pi * i / n_lat
        for j in range(n_lon):
            ph = 2 * np.pi * j / n_lon
            pts.append([radius * np.sin(th) * np.cos(ph), radius * np.sin(th) * np.sin(ph),
                        radius * np.cos(th)])
    pts.append([0.0, 0.0, -radius])
    tris = []
    for j in range(n_lon):
        tris.append([0, 1 + j, 1 + (j + 1) % n_lon])
    for i in range(n_lat - 2):
        a, b = 1 + i * n_lon, 1 + (i + 1) * n_lon
        for j in range(n_lon):
            j1 = (j + 1) % n_lon
            tris.append([a + j, b + j, b + j1])
            tris.append([a + j, b + j1, a + j1])
    last = len(pts) - 1
    base = 1 + (n_lat - 2) * n_lon
    for j in range(n_lon):
        tris.append([base + j, last, base + (j + 1) % n_lon])
    return np.array(pts), np.array(tris, dtype=np.int64)


def shape_frame(axis: np.ndarray) -> np.ndarray:
    """Rows e1, e2, e3 of the shape frame for a nose direction `axis` (unit): e3 = axis, e1 the
    world x axis made perpendicular to it (the world y axis when the nose points along ±x),
    e2 = e3 × e1. A nose along −z (the default) gives e1 = x, e2 = −y exactly."""
    e3 = np.asarray(axis, dtype=float)
    ref = np.array([1.0, 0.0, 0.0]) if abs(e3[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = ref - (ref @ e3) * e3
    e1 = e1 / np.linalg.norm(e1)
    e2 = np.cross(e3, e1)
    return np.array([e1, e2, e3])


def geometry_of(projectile) -> ShapeGeometry:
    """The ShapeGeometry of a scenario's [projectile] section (validated)."""
    pr = projectile
    if pr.shape in ("sphere", "none"):
        return ShapeGeometry("sphere", pr.radius)
    if pr.shape == "fsp":
        length = pr.length if pr.length is not None else (
            FSP_LENGTH_PER_DIAMETER * 2.0 * pr.radius)
        return ShapeGeometry("fsp", pr.radius, length, 0.0,
                             0.5 * FSP_FLAT_PER_DIAMETER * 2.0 * pr.radius, FSP_BEVEL)
    if pr.shape == "ogive":
        return ShapeGeometry("ogive", pr.radius, pr.length, pr.nose_length)
    return ShapeGeometry("cylinder", pr.radius, pr.length)


@dataclass(frozen=True)
class Pose:
    """A projectile's geometry and its state at t = 0, as a scenario describes it."""

    geometry: ShapeGeometry
    frame: np.ndarray
    """Rows e1, e2, e3 (e3 the nose axis) of the shape frame in the body frame, (3, 3); the
    body frame is the world frame at t = 0."""
    inertia: np.ndarray
    """Inertia about the centre of mass in the body frame [kg m²], (3, 3)."""
    nose: np.ndarray
    """The tilt and yaw marker relative to the centre of mass [m], (3,)."""
    flight_direction: np.ndarray
    """Unit vector of the initial velocity (−z if the body starts at rest)."""
    position: np.ndarray
    """Centre of mass [m], (3,)."""
    velocity: np.ndarray
    """[m/s], (3,)."""
    angular_velocity: np.ndarray
    """[rad/s], (3,)."""


def initial_pose(projectile) -> Pose:
    """Where a scenario's [projectile] (validated) starts and how it is oriented: the one place
    that turns position, gap, velocity and axis into a pose (the builder, the field figure and
    the studies all call it)."""
    from emfabric.config.scenario import ScenarioError

    pr = projectile
    geo = geometry_of(pr)
    velocity = np.asarray(pr.velocity, dtype=float)
    speed = np.linalg.norm(velocity)
    flight = velocity / speed if speed > 0 else np.array([0.0, 0.0, -1.0])
    # the nose: the shape's axis at t = 0 (default: the flight direction); its leading surface
    # point is the tilt and yaw marker (5.2)
    lead = flight
    if pr.axis is not None:
        axis = np.asarray(pr.axis, dtype=float)
        length = float(np.linalg.norm(axis))
        big = float(np.abs(axis).max())
        if big > 0.0 and not 1e-150 < length < 1e150:
            # a direction: a length whose square over- or underflows is scaled first (an
            # ordinary axis keeps its bits)
            axis = axis / big
            length = float(np.linalg.norm(axis))
        if not length > 0.0:
            raise ScenarioError(f"projectile.axis = {list(pr.axis)}: the nose direction must "
                                f"be a non-zero vector")
        lead = axis / length
    # the body frame is the world frame at t = 0; the shape frame has e3 along the nose
    frame = np.eye(3) if geo.kind == "sphere" else shape_frame(lead)
    moments = (geo.principal_inertia(pr.mass) if pr.principal_inertia is None
               else np.asarray(pr.principal_inertia, dtype=float))
    inertia = frame.T @ np.diag(moments) @ frame
    if geo.kind == "sphere":
        nose = geo.radius * lead
        lowest = geo.radius
    else:
        nose = (geo.length - geo.base) * lead
        lowest = geo.extent(frame @ np.array([0.0, 0.0, -1.0]))
    if pr.position is None:
        position = np.array([0.0, 0.0, lowest + pr.gap])
    else:
        position = np.asarray(pr.position, dtype=float)
    return Pose(geo, frame, inertia, nose, flight, position, velocity,
                np.asarray(pr.angular_velocity, dtype=float))
