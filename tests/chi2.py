"""The chi-square goodness-of-fit machinery lives in :mod:`jgi.analysis.chi2` (the paper's pipeline
uses it too); the tests import it from here, as before."""

from jgi.analysis.chi2 import (  # noqa: F401
                               SIGNIFICANCE,
                               PlaneDomain,
                               Result,
                               SphereDomain,
                               assert_chi2,
                               bucket,
                               cell_integrals,
                               chi2_test,
                               histogram,
                               pearson,
)
