"""Benchmarks: ``python -m experiments.bench.bench`` runs the suite; each ``experiments.bench.<name>``
module also runs alone."""
