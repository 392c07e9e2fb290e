"""Exceptions raised by demcell (all subclasses of ``DemCellError``)."""


class DemCellError(Exception):
    """Base class: anything demcell refuses to do, with the cause in the message."""


class InputError(DemCellError, ValueError):
    """Bad user input, raised before any computation starts."""


class SolveError(DemCellError, RuntimeError):
    """The micro solve could not produce a meaningful state (e.g. non-finite values)."""
