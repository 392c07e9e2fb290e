"""Benchmarks: scripts that measure accuracy, cost and robustness, grouped by subject
(benchmarks/README.md). Run them with the repository root on PYTHONPATH, as the Makefile does
(`make benchmark-<group>`); a script starts demos and other scripts with the environment it got."""
import os

#: the repository root (the folder holding cosserat_fenicsx, demcell, demos and benchmarks)
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
