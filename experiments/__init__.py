"""Benchmarks, studies and the code they share; run each script as a module, e.g.
``python -m experiments.bench.bench``."""
