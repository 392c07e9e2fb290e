"""Several materials on one specimen, each on its own Gauss points (zones).

A scene with an imperfection (scenes.platen_test: a weakened corner) gives the points of
the imperfection a weaker variant of the material; both variants share one state layout,
so the Gauss-point store holds one history for all of them.
"""
import time

import numpy as np

from ..constitutive import Constitutive


class ZonedMaterial(Constitutive):
    """Several materials with the same state layout, each on its own set of Gauss points.

    `zone` (n_points,) gives the index of the material of each point; it must be set (by
    set_zones) before the Gauss-point store allocates the history. The update of each zone is the
    update of its material on the zone's rows, so the partition of the work follows the
    mesh partition as for a single material. `kernel_time` accumulates the wall time of
    the material updates (the profile benchmark reads it)."""

    def __init__(self, materials):
        self.materials = list(materials)
        names = {tuple(m.state_names) for m in self.materials}
        if len(names) != 1:
            raise ValueError("ZonedMaterial: all materials must share one state layout")
        self.state_names = self.materials[0].state_names
        self.zone = None
        self.kernel_time = 0.0
        self.kernel_calls = 0

    def set_zones(self, zone):
        zone = np.asarray(zone, dtype=np.int64)
        if zone.size and (zone.min() < 0 or zone.max() >= len(self.materials)):
            raise ValueError("ZonedMaterial: zone index out of range")
        self.zone = zone
        self._rows = [np.flatnonzero(zone == k) for k in range(len(self.materials))]

    def initial_state(self, n_points):
        if self.zone is None or len(self.zone) != n_points:
            raise RuntimeError("ZonedMaterial: set_zones(zone) with one entry per Gauss point first")
        state = np.empty((n_points, len(self.state_names)))
        for material, rows in zip(self.materials, self._rows):
            state[rows] = material.initial_state(len(rows))
        return state

    def update(self, gradients, dt, state_old, flux_out, tangent_out, state_new, points=None):
        """Each zone's material on its rows among `points` (None: every row)."""
        start = time.perf_counter()
        if len(self.materials) == 1:
            self.materials[0].update(gradients, dt, state_old, flux_out, tangent_out, state_new, points=points)
        else:
            for material, rows in zip(self.materials, self._rows):
                if points is not None:
                    rows = np.intersect1d(rows, points)
                if len(rows) == 0:
                    continue
                f, t, s = flux_out[rows], tangent_out[rows], state_new[rows]
                material.update(gradients[rows], dt, state_old[rows], f, t, s)
                flux_out[rows], tangent_out[rows], state_new[rows] = f, t, s
        self.kernel_time += time.perf_counter() - start
        self.kernel_calls += 1
