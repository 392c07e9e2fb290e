"""Boundary-value problems shared by demos, tests and benchmarks (built on demand)."""
