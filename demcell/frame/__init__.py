"""A cell with paper 000's micro boundary conditions: a frame of boundary particles held by a
servo (000 section 3.2.2, eqs 33-37, Tables 2-3), beside the periodic DemCell.

* ``cut_frame``, ``Frame``        cut.py       the periodic cell cut open: corners, edge pairs
* servo kernels (reactions, residuals, gains, corrections)   servo.py
* ``FrameOptions``                options.py   relaxation, thickness, gain, residual, eps_a
* ``FrameCell``                   cell.py      the MicroCell (solve, stress eq. 14, tangents)

docs/reference/frame_cell.md says what it is for and what it costs.
"""
from .cell import FRAME_TANGENTS, FrameCell, ServoRecord  # noqa: F401
from .cut import Frame, contact_weights, cut_frame  # noqa: F401
from .options import FrameOptions  # noqa: F401
