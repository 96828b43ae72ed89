"""Every file the paper includes is produced by the paper's pipeline (no hand-typed numbers)."""

from __future__ import annotations

import re
from pathlib import Path

from paper import pipeline

PAPER = Path(__file__).resolve().parents[1] / "paper"


def test_every_included_file_is_declared_by_a_pipeline_step():
    tex = (PAPER / "jgi.tex").read_text()
    inputs = re.findall(r"\\input\{generated/([^}]+)\}", tex)
    graphics = re.findall(r"\\includegraphics(?:\[[^\]]*\])?\{([^}]+)\}", tex)
    assert inputs and graphics
    declared = pipeline.declared_outputs()
    missing = [f for f in inputs + graphics if f not in declared]
    assert not missing, f"included by jgi.tex but produced by no pipeline step: {missing}"
    # and no other \input or graphics path sneaks in hand-made content
    assert not re.findall(r"\\input\{(?!generated/)", tex)


def test_no_digits_typed_into_results_sentences():
    """Measured values appear only through generated macros: sentences that report a
    measurement ('slope', 'standard errors', 'million paths') contain no literal number."""
    tex = (PAPER / "jgi.tex").read_text()
    for sentence in re.split(r"(?<=[.!?])\s", tex):
        if re.search(r"fitted log-log slope is|standard errors\.|million paths|smallest \$p\$-value"
                     r"|samples each|by at most", sentence):
            body = re.sub(r"\\[a-zA-Z]+\{?|\$[^$]*\$|-1", "", sentence)
            assert not re.search(r"\d\.\d", body), sentence


def test_tables_and_macros_come_from_the_pipeline():
    """jgi.tex typesets no table body of its own (tables are generated files), and every macro
    file a step writes is read by jgi.tex (a step's numbers cannot silently go unused)."""
    tex = (PAPER / "jgi.tex").read_text()
    assert r"\begin{tabular}" not in tex
    inputs = set(re.findall(r"\\input\{generated/([^}]+)\}", tex))
    unused = sorted(f for f in pipeline.declared_outputs()
                    if f.endswith("_macros.tex") and f not in inputs)
    assert not unused, f"macro files written by the pipeline but not read by jgi.tex: {unused}"
