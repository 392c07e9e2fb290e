"""Measured (or virtual) test data for an identification: reading and checking.

One CSV file per test, in the material-point driver's format (demos/material_point.py
history.csv): SI units, tension positive, strains counted from the start of the
deviatoric phase.

* triaxial / biaxial: columns ``axial_strain``, ``axial_stress``, ``volumetric_strain``
  (one of the two measured columns may be missing: that quantity is then not fitted);
* hydrostatic / isotropic_plane_strain: ``pressure`` [Pa, > 0] (or ``mean_stress``, whose
  negative is the pressure) and ``volumetric_strain``.

Optional columns ``<quantity>_std`` give the scatter sigma_n of each point over repeated
tests (thesis eq. 4.26), used by the error analysis; a test can instead be given one
scatter per quantity (Table 6.3 lists mean scatters per test).  An optional ``time``
column [s, from the start of the measured phase] gives the loading rate the model follows.

The model runs each test along the data: a load step ends at every data abscissa, and
longer intervals are split (VirtualTest.following), so that data made by the model with
its own steps are met exactly and measured data see a discretisation error that the
identification estimates and reports.  Every check here runs
before any model evaluation (bad input gets a one-line error naming file and column).
"""

from __future__ import annotations

import csv
import dataclasses
import math
import os

import numpy as np

from ..validation import InputError
from .virtual_tests import KINDS, MIN_STEPS, UNLOADING, VirtualTest

#: Table 6.2 of the thesis: normalisation factors of (6.3) for the Hostun tests [Pa, -]
TABLE_6_2 = {("triaxial", 100e3): dict(axial_stress=500e3, volumetric_strain=0.1),
             ("triaxial", 300e3): dict(axial_stress=1500e3, volumetric_strain=0.07),
             ("triaxial", 600e3): dict(axial_stress=2500e3, volumetric_strain=0.03),
             ("hydrostatic", None): dict(volumetric_strain=0.017),
             ("biaxial", 100e3): dict(axial_stress=650e3)}


@dataclasses.dataclass
class TestData:
    """The data of one test: abscissa x (axial strain or pressure), measured quantities y[q],
    optional scatter std[q] (per point) and the normalisation phi_0 of each quantity
    (eq. 4.17: weight 1 / (phi_0^2 N))."""

    test: VirtualTest
    x: np.ndarray
    y: dict
    std: dict
    normalisation: dict
    source: str = ""

    @property
    def label(self):
        return self.test.label

    @property
    def n_points(self):
        return sum(len(v) for v in self.y.values())


def default_normalisation(kind, confining, quantity, values, thesis=False):
    """phi_0 of (4.17): the largest magnitude of the data (what the Table 6.2 values are for
    the measured Hostun curves); with `thesis`, Table 6.2 itself for the thesis' five tests
    (virtual Hostun data)."""
    key = (kind, None if kind == "hydrostatic" else confining)
    for (k, p), table in TABLE_6_2.items() if thesis else ():
        if k == kind and (p is None or (key[1] is not None and math.isclose(p, key[1], rel_tol=1e-6))):
            if quantity in table:
                return table[quantity]
    # an unloading branch: its range (the stress level itself is not what it measures)
    m = float(np.ptp(values) if kind in UNLOADING else np.max(np.abs(values)))
    if not m > 0:
        raise InputError(f"{kind} test: all {quantity} data are zero; give its normalisation explicitly")
    return m


def _read_columns(path):
    if not os.path.isfile(path):
        raise InputError(f"data file {path!r} does not exist")
    try:
        with open(path, newline="", encoding="utf-8") as f:
            text = f.read()
    except OSError as error:
        raise InputError(f"data file {path!r}: {error.strerror or error}") from None
    except UnicodeDecodeError:
        raise InputError(f"data file {path!r}: not a text (UTF-8 CSV) file") from None
    if "\0" in text:
        raise InputError(f"data file {path!r}: not a text (CSV) file: it holds NUL bytes")
    try:
        rows = [r for r in csv.reader(text.splitlines()) if r and not r[0].lstrip().startswith("#")]
    except csv.Error as error:
        raise InputError(f"data file {path!r}: not a CSV file ({error})") from None
    if len(rows) < 2:
        raise InputError(f"data file {path!r}: a header line and at least one row are needed")
    header = [h.strip() for h in rows[0]]
    repeated = sorted({h for h in header if header.count(h) > 1})
    if repeated:
        raise InputError(f"data file {path!r}: column(s) {repeated} appear more than once in the header")
    cols = {h: [] for h in header}
    for i, row in enumerate(rows[1:], start=2):
        if len(row) != len(header):
            raise InputError(f"data file {path!r} line {i}: {len(row)} values for {len(header)} columns")
        for h, v in zip(header, row):
            try:
                cols[h].append(float(v))
            except ValueError:
                raise InputError(f"data file {path!r} line {i}, column {h!r}: {v!r} is not a number") from None
    return {h: np.array(v) for h, v in cols.items()}


def read_test(path, kind, confining, quantities=None, normalisation=None, scatter=None,
              n_steps=None, n_consolidation=40, start_pressure=0.0, unload_at=None, min_steps=MIN_STEPS):
    """TestData of one CSV file.  kind, confining [Pa]: the test (confining: cell pressure, or
    the final pressure of an isotropic test -- by default the largest pressure in the file);
    quantities: the measured quantities to fit (default: all of the kind's present in the
    file); normalisation: {quantity: phi_0}; scatter: {quantity: sigma} one value per
    quantity when the file has no <quantity>_std column; n_steps: equal load steps of the
    model run (default: a step ends at every data abscissa and none is longer than
    1/min_steps of the test's range, VirtualTest.following);
    start_pressure (isotropic kinds): the pressure the test starts from, its strains counted
    from there (e.g. a DEM cell prepared at p0); unload_at (triaxial_unloading, required): the
    axial compression at which the recorded unloading branch starts."""
    if kind not in KINDS:
        raise InputError(f"data file {path!r}: test kind {kind!r} is not one of {sorted(KINDS)}")
    cols = _read_columns(path)
    abscissa, measured = KINDS[kind]
    if abscissa == "pressure" and "pressure" not in cols and "mean_stress" in cols:
        cols["pressure"] = -cols["mean_stress"]
    if kind in UNLOADING and "axial_stress_change" not in cols and "axial_stress" in cols and abscissa in cols:
        # the change from the branch's start, the first row (axial strain 0)
        if abs(cols[abscissa][0]) > 1e-12:
            raise InputError(f"data file {path!r}: an unloading branch given by axial_stress must start at "
                             "axial strain 0 (or give axial_stress_change)")
        cols["axial_stress_change"] = cols["axial_stress"] - cols["axial_stress"][0]
        if "axial_stress_std" in cols:
            cols["axial_stress_change_std"] = cols["axial_stress_std"]
    if abscissa not in cols:
        raise InputError(f"data file {path!r} ({kind}): column {abscissa!r} missing (columns: {sorted(cols)})")
    wanted = list(quantities) if quantities else [q for q in measured if q in cols]
    for q in wanted:
        if q not in measured:
            raise InputError(f"data file {path!r}: a {kind} test measures {list(measured)}, not {q!r}")
        if q not in cols:
            raise InputError(f"data file {path!r} ({kind}): column {q!r} missing (columns: {sorted(cols)})")
    if not wanted:
        raise InputError(f"data file {path!r} ({kind}): none of the columns {list(measured)} is present")
    x = cols[abscissa]
    for name in [abscissa] + wanted + [q + "_std" for q in wanted if q + "_std" in cols] + \
            (["time"] if "time" in cols else []):
        bad = ~np.isfinite(cols[name])
        if bad.any():
            raise InputError(f"data file {path!r}: column {name!r} has {int(bad.sum())} non-finite value(s) "
                             f"(first at data row {int(np.argmax(bad)) + 1})")
    if abscissa == "pressure":
        if np.any(x < 0):
            raise InputError(f"data file {path!r}: pressure must be >= 0 (compression positive in this column)")
        top = float(x.max()) if confining is None else float(confining)
        if not top > 0:
            raise InputError(f"data file {path!r}: the pressures are all zero")
        if x.max() > top * (1 + 1e-9):
            raise InputError(f"data file {path!r}: pressures up to {x.max():g} Pa exceed the test's {top:g} Pa")
        p_start = float(start_pressure or 0.0)
        if x.min() < p_start * (1 - 1e-9):
            raise InputError(f"data file {path!r}: pressures below the start pressure {p_start:g} Pa")
        fields = dict(start_pressure=p_start, n_consolidation=n_consolidation)
    else:
        if confining is None:
            raise InputError(f"data file {path!r}: a {kind} test needs its confining pressure")
        fields = dict(n_consolidation=n_consolidation)
        if kind in UNLOADING:
            if unload_at is None:
                raise InputError(f"data file {path!r}: a {kind} test needs 'unload_at' (the axial compression "
                                 "where its unloading starts)")
            if np.any(x < -1e-12):
                raise InputError(f"data file {path!r}: an unloading branch has axial strains >= 0 "
                                 "(counted from its start, tension positive)")
            reach = float(x.max())
            fields["unload_at"] = float(unload_at)
        else:
            if np.any(x > 1e-12):
                raise InputError(f"data file {path!r}: axial strains must be <= 0 (compression, tension positive)")
            reach = float(-x.min())
        if not reach > 0:
            raise InputError(f"data file {path!r}: the axial strain never leaves 0")
        fields["axial_strain"] = reach
        top = float(confining)
    try:
        if n_steps:
            test = VirtualTest(kind, top, n_steps=int(n_steps), **fields)
        else:
            test = VirtualTest.following(kind, top, x, times=cols.get("time"), min_steps=min_steps, **fields)
    except InputError as error:
        raise InputError(f"data file {path!r}: {error}") from None
    y = {q: cols[q] for q in wanted}
    std = {}
    for q in wanted:
        if q + "_std" in cols:
            std[q] = cols[q + "_std"]
        elif scatter and q in scatter:
            std[q] = np.full(len(x), float(scatter[q]))
        if q in std and not np.all(std[q] > 0):
            raise InputError(f"data file {path!r}: scatter of {q!r} must be > 0 at every point")
    norm = {}
    for q in wanted:
        v = (normalisation or {}).get(q)
        norm[q] = float(v) if v is not None else default_normalisation(kind, test.confining, q, y[q])
        if not (math.isfinite(norm[q]) and norm[q] > 0):
            raise InputError(f"data file {path!r}: normalisation of {q!r} must be finite and > 0, got {v!r}")
    return TestData(test=test, x=x, y=y, std=std, normalisation=norm, source=path)


def from_history(test, h, quantities=None, every=1, noise=None, rng=None):
    """Virtual data (re-identification, thesis 6.2.3) from a model history h of `test`:
    every `every`-th record; noise {quantity: sigma} adds Gaussian noise and records sigma as
    the scatter; normalised as Table 6.2 where the thesis tests match.  The first record of a
    deviatoric test (axial strain 0) is left out."""
    qs = list(quantities or test.quantities)
    x = np.asarray(h[test.abscissa])
    idx = np.arange(1, len(x), every) if test.abscissa == "axial_strain" else np.arange(0, len(x), every)
    rng = rng or np.random.default_rng(0)
    y, std = {}, {}
    for q in qs:
        v = np.asarray(h[q])[idx].copy()
        if noise and q in noise:
            v += rng.normal(0.0, noise[q], size=v.shape)
            std[q] = np.full(len(idx), float(noise[q]))
        y[q] = v
    norm = {q: default_normalisation(test.kind, test.confining, q, np.asarray(h[q])[idx], thesis=True) for q in qs}
    return TestData(test=test, x=x[idx].copy(), y=y, std=std, normalisation=norm, source="virtual")


def write_test(data, path):
    """CSV in the format read_test reads (with <quantity>_std columns when known)."""
    cols = [data.test.abscissa] + list(data.y) + [q + "_std" for q in data.y if q in data.std]
    arrays = [data.x] + [data.y[q] for q in data.y] + [data.std[q] for q in data.y if q in data.std]
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        for row in zip(*arrays):
            w.writerow([f"{v:.12g}" for v in row])


#: the five homogeneous tests of thesis 6.1 (Table 6.2): kind, confining (final) pressure [Pa]
THESIS_TESTS = (("hydrostatic", 1.0e6), ("triaxial", 100e3), ("triaxial", 300e3), ("triaxial", 600e3),
                ("biaxial", 100e3))


#: unloading branches for the elastic step 1(a) (4.3): the triaxial tests of 6.1 unloaded by
#: 5e-4 at 2 % axial compression (the thesis uses unloading-reloading cycles; no values given)
THESIS_UNLOADING = tuple(("triaxial_unloading", p) for k, p in THESIS_TESTS if k == "triaxial")


def thesis_virtual_data(reference, n_steps=75, every=3, noise=0.0, rng=None, unloading=False, model_min_steps=None):
    """Virtual data of the five tests of 6.1 run with the parameter set `reference`
    (re-identification, thesis 6.2.3's method); noise: Gaussian, as a fraction of each
    quantity's phi_0 of Table 6.2, recorded as the data's scatter; unloading: the three
    unloading branches of THESIS_UNLOADING (10 steps each, every point kept) come first.
    model_min_steps: the model does not run the steps that made the data but follows the
    data as it would follow measured data (VirtualTest.following with the data's times,
    1 s per data step), at least this many steps over each deviatoric/pressure range."""
    from ..materials.ehlers import EhlersMaterial
    material = EhlersMaterial(**reference.as_dict())
    rng = rng or np.random.default_rng(0)
    data = []
    for kind, p in (THESIS_UNLOADING if unloading else ()) + THESIS_TESTS:
        test = VirtualTest(kind, p, n_steps=10 if kind in UNLOADING else n_steps,
                           axial_strain=5e-4 if kind in UNLOADING else 0.15)
        h = test.run(material)
        sig = None
        if noise > 0:
            sig = {q: noise * default_normalisation(kind, p, q, np.asarray(h[q]), thesis=True)
                   for q in test.quantities}
        d = from_history(test, h, every=1 if kind in UNLOADING else every, noise=sig, rng=rng)
        if model_min_steps and kind not in UNLOADING:
            # record k ends step k of a deviatoric phase (record 0 its start), step k+1 of a pressure one
            steps = np.arange(1, len(h[test.abscissa]), every) if test.abscissa == "axial_strain" \
                else np.arange(0, len(h[test.abscissa]), every) + 1
            fields = dict(axial_strain=test.axial_strain) if test.abscissa == "axial_strain" else {}
            d = dataclasses.replace(d, test=VirtualTest.following(kind, p, d.x, times=steps * 1.0,
                                                                  min_steps=model_min_steps, **fields))
        data.append(d)
    return data
