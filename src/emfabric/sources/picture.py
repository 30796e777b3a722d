"""The field over the sheet's plane and along the flight axis, sampled for the field figure
(``emfabric field --plot``; drawn by emfabric.viz.field_plot): B and E (the uniform E and the
induced E = −(dI/dt) A of the time-varying currents), and the outlines of the sources (the
loops' and solenoids' windings, the magnets' bodies) in 3-D."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from emfabric._kernels.records import Field
from emfabric.config.scenario import Scenario
from emfabric.sources.evaluate import fields_at


@dataclass(frozen=True)
class SourceOutline:
    """A source drawn as lines: polylines of 3-D points [m]."""

    kind: str
    """"loop", "solenoid" or "magnet"."""
    label: str
    """What the legend calls it ("loop 1 (ramp)")."""
    lines: tuple[np.ndarray, ...]
    """Polylines, each (n, 3) [m]."""
    centre: np.ndarray
    """Centre [m], (3,)."""
    axis: np.ndarray
    """Unit normal (loop), axis (solenoid) or the magnet's z axis, (3,)."""
    radius: float
    """Loop or solenoid radius (a magnet: half its largest dimension) [m]."""
    length: float = 0.0
    """Solenoid length (a loop: 0) [m]."""
    time_varying: bool = False
    """Its current changes in time (waveform other than "constant"): it induces an E."""


@dataclass(frozen=True)
class FieldPicture:
    """What the figure shows, every array already evaluated [SI]."""

    xs: np.ndarray
    """Grid over the sheet's plane z = 0 [m], (nx,)."""
    ys: np.ndarray
    b_plane: np.ndarray
    """B on that grid [T], (ny, nx, 3)."""
    sheet: tuple[float, float, float, float]
    """Sheet extent (x_min, x_max, y_min, y_max) [m]."""
    start: np.ndarray
    """Projectile centre of mass at t = 0 [m], (3,)."""
    s: np.ndarray
    """Distance along the flight axis from the start [m], (n,)."""
    b_axis: np.ndarray
    """B along the flight axis [T], (n, 3)."""
    s_sheet: float
    """Where the flight axis meets z = 0 (nan if it does not) [m]."""
    time: float
    title: str
    e_plane: np.ndarray | None = None
    """E on the plane's grid [V/m], (ny, nx, 3): the uniform E plus the induced E."""
    e_axis: np.ndarray | None = None
    """E along the flight axis [V/m], (n, 3)."""
    sources: tuple[SourceOutline, ...] = ()
    """The sources' outlines (loops, solenoids, magnets)."""
    direction: np.ndarray | None = None
    """Unit flight direction, (3,)."""

    @property
    def time_varying(self) -> bool:
        """Some current changes in time (an induced E)."""
        return any(o.time_varying for o in self.sources)

    @property
    def has_e(self) -> bool:
        """An E to show: a time-varying current, or a non-zero E anywhere sampled."""
        if self.time_varying:
            return True
        return any(e is not None and bool(np.any(e != 0.0)) for e in (self.e_plane,
                                                                      self.e_axis))


def _frame(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to the unit n and to each other."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(n, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(n, u)


def circle(centre, normal, radius: float, points: int = 97) -> np.ndarray:
    """Points of the circle of `radius` about `centre` in the plane of `normal`, (points, 3),
    closed (the last point is the first)."""
    n = np.asarray(normal, dtype=float)
    n = n / np.linalg.norm(n)
    u, v = _frame(n)
    t = np.linspace(0.0, 2.0 * np.pi, points)
    return (np.asarray(centre, dtype=float)
            + radius * (np.outer(np.cos(t), u) + np.outer(np.sin(t), v)))


def _rotation(rotvec_deg) -> np.ndarray:
    """Rotation matrix of a rotation vector [deg] (axis × angle; Rodrigues)."""
    r = np.radians(np.asarray(rotvec_deg, dtype=float))
    angle = float(np.linalg.norm(r))
    if angle == 0.0:
        return np.eye(3)
    k = r / angle
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle) * kx + (1.0 - np.cos(angle)) * kx @ kx


def source_outlines(sc: Scenario) -> tuple[SourceOutline, ...]:
    """The outlines of the scenario's loops, solenoids and magnets (uniform and map sources
    have none)."""
    out = []
    for i, src in enumerate(sc.field.sources):
        tag = f"{src.kind} {i + 1}"
        if src.kind in ("loop", "solenoid"):
            d = np.asarray(src.normal if src.kind == "loop" else src.axis, dtype=float)
            if not np.linalg.norm(d) > 0.0:
                continue
            d = d / np.linalg.norm(d)
            c = np.asarray(src.centre, dtype=float)
            varying = src.waveform != "constant"
            label = tag + (f" ({src.waveform})" if varying else "")
            if src.kind == "loop":
                out.append(SourceOutline("loop", label, (circle(c, d, src.radius),), c, d,
                                         float(src.radius), 0.0, varying))
                continue
            half = 0.5 * src.length * d
            ends = (circle(c - half, d, src.radius), circle(c + half, d, src.radius))
            u, v = _frame(d)
            sides = tuple(np.array([c - half + src.radius * w, c + half + src.radius * w])
                          for w in (u, v, -u, -v))
            out.append(SourceOutline("solenoid", label, ends + sides, c, d, float(src.radius),
                                     float(src.length), varying))
        elif src.kind == "magnet":
            rot = _rotation(src.orientation)
            c = np.asarray(src.position, dtype=float)
            if src.shape == "cuboid":
                a, b, h = (0.5 * float(x) for x in src.dimension)
                corners = np.array([[sx * a, sy * b, sz * h] for sx in (-1, 1)
                                    for sy in (-1, 1) for sz in (-1, 1)])
                edges = [(0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7),
                         (0, 4), (1, 5), (2, 6), (3, 7)]
                lines = tuple(np.array([corners[p], corners[q]]) @ rot.T + c
                              for p, q in edges)
                size = float(np.linalg.norm([a, b, h]))
            else:
                r, h = 0.5 * float(src.dimension[0]), 0.5 * float(src.dimension[1])
                z = np.array([0.0, 0.0, 1.0])
                rings = tuple(circle(s * h * z, z, r) @ rot.T + c for s in (-1, 1))
                sides = tuple(np.array([[x, y, -h], [x, y, h]]) @ rot.T + c
                              for x, y in ((r, 0), (0, r), (-r, 0), (0, -r)))
                lines = rings + sides
                size = float(np.hypot(r, h))
            out.append(SourceOutline("magnet", f"{tag} ({src.shape})", lines, c,
                                     rot @ np.array([0.0, 0.0, 1.0]), size))
    return tuple(out)


def field_picture(sc: Scenario, fld: Field, at_time: float, start: np.ndarray,
                  direction: np.ndarray) -> FieldPicture:
    """Evaluate the field (B and E) over the sheet's plane (margin 25 %) and along the flight
    axis from the projectile's start [m] in the unit `direction` to as far beyond the sheet
    (the pose of emfabric.sim.geometry.initial_pose), with the sources' outlines."""
    lx, ly = sc.fabric.size
    xs = np.linspace(-0.625 * lx, 0.625 * lx, 81)
    ys = np.linspace(-0.625 * ly, 0.625 * ly, 81)
    gx, gy = np.meshgrid(xs, ys)
    plane = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)
    e_plane, b_plane = fields_at(fld, plane, at_time)
    d = np.asarray(direction, dtype=float)
    start = np.asarray(start, dtype=float)
    s_sheet = -start[2] / d[2] if d[2] != 0 else float("nan")
    reach = 2.0 * (abs(s_sheet) if np.isfinite(s_sheet) else max(lx, ly))
    s = np.linspace(0.0, max(reach, 0.5 * max(lx, ly)), 400)
    e_axis, b_axis = fields_at(fld, start + np.outer(s, d), at_time)
    shape = (len(ys), len(xs), 3)
    return FieldPicture(xs, ys, b_plane.reshape(shape),
                        (-lx / 2, lx / 2, -ly / 2, ly / 2), start, s, b_axis,
                        s_sheet if s_sheet >= 0 else float("nan"), at_time, sc.name,
                        e_plane.reshape(shape), e_axis, source_outlines(sc), d)
