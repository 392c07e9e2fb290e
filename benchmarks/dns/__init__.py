"""The bounded DEM specimen (demcell.specimen): engine throughput, the 004 chapter 7 biaxial
test, paper 000's DNS and the comparison with LAMMPS."""
