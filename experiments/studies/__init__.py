"""Studies: one question each, answered with measurements
(``python -m experiments.studies.<name>``)."""
