"""The Ehlers material: kernel throughput, the biaxial test and the softening layer
(regularisation, mesh convergence, cost of a decoupled band)."""
