"""The paper: ``python -m paper.pipeline`` writes every number, table and figure jgi.tex includes."""
