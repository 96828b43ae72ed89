"""The paper: ``python -m paper.pipeline`` writes every number, table and figure that jgi.tex
includes."""
