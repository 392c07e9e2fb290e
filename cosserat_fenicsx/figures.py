"""Figures of the demos: matplotlib drawing into files only (no display, no dolfinx)."""


def pyplot():
    """matplotlib.pyplot on the Agg backend, so a run on a machine without a display (a
    batch node, a container) writes its PNG files all the same."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt
