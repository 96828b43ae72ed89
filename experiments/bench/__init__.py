"""Benchmarks: ``python -m experiments.bench.bench`` runs the suite; each module
``experiments.bench.<name>`` also runs alone."""
