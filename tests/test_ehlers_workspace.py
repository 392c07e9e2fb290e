"""The work arrays of the Ehlers kernel are views at hand-written offsets of one buffer
(local_solver.make_workspace, no reference counting for speed). Guard: every view has the
shape of WS_SHAPES, the views tile the buffer in order without gaps or overlaps, and the
batch kernel's extra views (E, S, C, params) start at WS_SIZE."""
import numpy as np

from cosserat_fenicsx.materials.ehlers import local_solver as ls


def test_workspace_views_tile_the_buffer_in_the_declared_order():
    buf = np.arange(ls.WS_SIZE + 10, dtype=np.float64)
    views = ls.make_workspace(buf)
    assert len(views) == len(ls.WS_SHAPES) == len(ls.WS_NAMES)
    offset = 0
    for name, shape, view in zip(ls.WS_NAMES, ls.WS_SHAPES, views):
        assert view.shape == shape, name
        size = int(np.prod(shape))
        assert np.array_equal(view.ravel(), np.arange(offset, offset + size)), name
        offset += size
    assert offset == ls.WS_SIZE
    view = views[0]
    view[0] = -1.0                      # the views write into the buffer itself
    assert buf[0] == -1.0
    del views, view
