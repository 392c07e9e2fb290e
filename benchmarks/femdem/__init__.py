"""FEM x DEM: the biaxial test with a DEM cell at every Gauss point (tangents, regularisation,
convergence, rotations, load balance, scaling, the cross-check against YADE's FEMxDEM)."""
