"""Bridging-scale coupling (paper 003, Li and Wan 2010) of the Cosserat continuum with a
DEM region: the scale projection (numpy/scipy), the particle -> element map (dolfinx), the
DEM region with its virtual interface layer, and the coupled time loop.

Submodules are imported explicitly (nothing here imports dolfinx or demcell)."""
