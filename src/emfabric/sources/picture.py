"""The field over the sheet's plane and along the flight axis, sampled for the field figure
(``emfabric field --plot``; drawn by emfabric.viz.field_plot)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from emfabric._kernels.records import Field
from emfabric.config.scenario import Scenario
from emfabric.sources.evaluate import fields_at


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


def field_picture(sc: Scenario, fld: Field, at_time: float, start: np.ndarray,
                  direction: np.ndarray) -> FieldPicture:
    """Evaluate the field over the sheet's plane (margin 25 %) and along the flight axis from
    the projectile's start [m] in the unit `direction` to as far beyond the sheet (the pose of
    emfabric.sim.geometry.initial_pose)."""
    lx, ly = sc.fabric.size
    xs = np.linspace(-0.625 * lx, 0.625 * lx, 81)
    ys = np.linspace(-0.625 * ly, 0.625 * ly, 81)
    gx, gy = np.meshgrid(xs, ys)
    plane = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)
    _e, b_plane = fields_at(fld, plane, at_time)
    d = direction
    s_sheet = -start[2] / d[2] if d[2] != 0 else float("nan")
    reach = 2.0 * (abs(s_sheet) if np.isfinite(s_sheet) else max(lx, ly))
    s = np.linspace(0.0, max(reach, 0.5 * max(lx, ly)), 400)
    _e, b_axis = fields_at(fld, start + np.outer(s, d), at_time)
    return FieldPicture(xs, ys, b_plane.reshape(len(ys), len(xs), 3),
                        (-lx / 2, lx / 2, -ly / 2, ly / 2), start, s, b_axis,
                        s_sheet if s_sheet >= 0 else float("nan"), at_time, sc.name)
