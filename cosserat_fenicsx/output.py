"""Results as the run goes: XDMF fields for ParaView, history.csv (summary.json: run_guard).

XDMF holds P1 and DG0 data only: the P2 displacement is interpolated to P1, stresses
(UFL expressions or Gauss-point data) become cell values (DG0; for linear stress fields
on triangles the centroid value equals the cell mean). Each step is written when it
converges and the HDF5 file is closed after it (reopened in append mode for the next), so
an interrupted or killed run keeps a readable file of what it computed (`run_guard` defers
SIGINT/SIGTERM while a step is written). Only requested fields are written. Rank 0 alone writes the CSV files and prints.
"""
import csv
import os

import dolfinx.fem
import dolfinx.io
import numpy as np
import ufl

from . import compat

FIELDS = ("displacement", "rotation", "stress", "couple_stress")


def print0(comm, *args):
    if comm.rank == 0:
        print(*args, flush=True)


class CsvLog:
    """history.csv: one row per converged step, flushed at once. resume_step (a restart):
    keep the rows of the file up to that step (first column), drop the later ones a killed
    run may have left, and append."""

    def __init__(self, comm, path, columns, resume_step=None):
        self.comm, self.columns = comm, list(columns)
        self.file = None
        if comm.rank == 0:
            kept = _rows_up_to(path, resume_step) if resume_step is not None else []
            self.file = open(path, "w", newline="")
            self.writer = csv.writer(self.file)
            self.writer.writerow(self.columns)
            self.writer.writerows(kept)
            self.file.flush()

    def write(self, row):
        if self.file is not None:
            self.writer.writerow([f"{float(row[c]):.10g}" for c in self.columns])
            self.file.flush()

    def close(self):
        if self.file is not None:
            self.file.close()
            self.file = None


def _rows_up_to(path, step):
    """Rows (without the header) of a CSV file whose first column is <= step."""
    if not os.path.isfile(path):
        return []
    with open(path, newline="") as f:
        rows = list(csv.reader(f))[1:]
    return [r for r in rows if r and float(r[0]) <= step]


def truncate_xdmf(path, t):
    """Drop the time steps after t from an XDMF file and its HDF5 data (a restart from a
    checkpoint older than the last written step). Serial: call on one rank."""
    import xml.etree.ElementTree as ET
    import h5py
    ET.register_namespace("xi", "http://www.w3.org/2001/XInclude")
    tree = ET.parse(path)
    stale = []
    for series in tree.getroot().iter("Grid"):
        if series.get("GridType") != "Collection":
            continue
        for grid in list(series):
            time = grid.find("Time")
            if time is not None and float(time.get("Value")) > t * (1 + 1e-12) + 1e-300:
                stale += [item.text.strip() for item in grid.iter("DataItem") if item.text and ":/" in item.text]
                series.remove(grid)
    tree.write(path, xml_declaration=True, encoding="utf-8")
    if stale:
        h5 = os.path.join(os.path.dirname(path), stale[0].split(":/")[0])
        with h5py.File(h5, "a") as f:
            for item in stale:
                name = item.split(":/", 1)[1]
                if name in f:
                    del f[name]


class FieldWriter:
    """XDMF time series of the requested fields of a CosseratProblem."""

    def __init__(self, problem, path, fields=FIELDS, resume_time=None):
        unknown = set(fields) - set(FIELDS)
        if unknown:
            raise ValueError(f"unknown output field(s) {sorted(unknown)}; known: {FIELDS}")
        if not problem.micropolar:
            fields = [f for f in fields if f not in ("rotation", "couple_stress")]
        self.problem, self.fields, self.path = problem, list(fields), path
        mesh = problem.mesh
        # the file is open only while a step is written (mode "a" after the mesh): an
        # interrupted or killed run leaves an HDF5 file closed after its last step
        if resume_time is not None and os.path.isfile(path):
            # a restart continues the series after its checkpoint's time
            if mesh.comm.rank == 0:
                truncate_xdmf(path, resume_time)
            mesh.comm.barrier()
        else:
            with dolfinx.io.XDMFFile(mesh.comm, path, "w") as file:
                file.write_mesh(mesh)
        gdim = mesh.geometry.dim
        self.outputs = {}
        if "displacement" in self.fields:
            V = compat.function_space(mesh, compat.lagrange_element(mesh, 1, (gdim,)))
            self.outputs["displacement"] = dolfinx.fem.Function(V, name="displacement")
        if "rotation" in self.fields:
            V = compat.function_space(mesh, compat.lagrange_element(mesh, 1))
            self.outputs["rotation"] = dolfinx.fem.Function(V, name="rotation")
        if "stress" in self.fields:
            V = compat.function_space(mesh, compat.dg_element(mesh, 0, (gdim, gdim)))
            self.outputs["stress"] = dolfinx.fem.Function(V, name="stress")
        if "couple_stress" in self.fields:
            V = compat.function_space(mesh, compat.dg_element(mesh, 0, (gdim,)))
            self.outputs["couple_stress"] = dolfinx.fem.Function(V, name="couple_stress")
        self._expressions = {}
        self.extra = {}

    def add_cell_field(self, name, shape, values):
        """An extra DG0 field; `values()` returns an array (n_owned_cells, prod(shape))."""
        mesh = self.problem.mesh
        V = compat.function_space(mesh, compat.dg_element(mesh, 0, shape))
        self.extra[name] = (dolfinx.fem.Function(V, name=name), values)

    def _set_cell_values(self, function, values):
        n = compat.num_owned_cells(self.problem.mesh)
        dofs = compat.cell_dofs(function.function_space, n).reshape(-1)
        bs = function.function_space.dofmap.index_map_bs
        function.x.array.reshape(-1, bs)[dofs] = np.asarray(values).reshape(n, bs)
        function.x.scatter_forward()

    def _interpolate_dg0(self, name, expr):
        function = self.outputs[name]
        if isinstance(expr, ufl.constantvalue.Zero):
            # e.g. the couple stress 2 mu_c l_c^2 kappa with l_c = 0: UFL folds it to a
            # zero without a mesh, which no Expression can be built from
            function.x.array[:] = 0.0
            return
        if name not in self._expressions:
            points = function.function_space.element.interpolation_points
            points = points() if callable(points) else points
            self._expressions[name] = dolfinx.fem.Expression(expr, points)
        function.interpolate(self._expressions[name])

    def write(self, t):
        problem = self.problem
        if problem.micropolar:
            u_sub, phi_sub = problem.w.sub(0), problem.w.sub(1)
        else:
            u_sub, phi_sub = problem.w, None
        if "displacement" in self.outputs:
            self.outputs["displacement"].interpolate(u_sub)
        if "rotation" in self.outputs:
            self.outputs["rotation"].interpolate(phi_sub)
        store = problem.gauss_points
        if "stress" in self.outputs:
            if store is not None:
                flux = store.cell_average(store.flux_values)
                self._set_cell_values(self.outputs["stress"], flux[:, [0, 2, 3, 1]])
            else:
                self._interpolate_dg0("stress", problem.stress())
        if "couple_stress" in self.outputs:
            if store is not None:
                flux = store.cell_average(store.flux_values)
                self._set_cell_values(self.outputs["couple_stress"], flux[:, 4:6])
            else:
                self._interpolate_dg0("couple_stress", problem.couple_stress())
        for function, values in self.extra.values():
            self._set_cell_values(function, values())
        with dolfinx.io.XDMFFile(self.problem.mesh.comm, self.path, "a") as file:
            for function in list(self.outputs.values()) + [f for f, _ in self.extra.values()]:
                file.write_function(function, t)

    def close(self):
        """Nothing left open (each write closes the file); kept for symmetry with CsvLog."""
