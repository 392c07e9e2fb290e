"""FEM x DEM with the cells of a rank in one struct of arrays (demcell.batch.CellBatch), or
resident on a GPU (demcell.gpu.DeviceCellBatch, device='gpu'): `DemMaterial` with its
cells in a `stores.BatchedCells`, the same statuses, messages, history and bits as one
DemCell per point (tests/test_femdem_batched.py).
"""
from .material import DemMaterial
from .stores import BatchedCells


class BatchedDemMaterial(DemMaterial):
    """DemMaterial(..., batched=True, device=device): device 'cpu' (a CellBatch on the rank's
    Numba threads) or 'gpu' (a DeviceCellBatch on the rank's CUDA device)."""

    DEVICES = BatchedCells.DEVICES

    def __init__(self, reference_cells, mode, tangent="pstlo", max_strain_increment=0.05, device="cpu",
                 fallback_tangent="kruyt"):
        super().__init__(reference_cells, mode, tangent, max_strain_increment, batched=True, device=device,
                         fallback_tangent=fallback_tangent)
