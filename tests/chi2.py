"""The chi-square goodness-of-fit machinery lives in :mod:`jgi.chi2` (the paper's pipeline
uses it too); the tests import it from here, as before."""

from jgi.chi2 import (SIGNIFICANCE, PlaneDomain, Result, SphereDomain, assert_chi2, bucket,  # noqa: F401
                      cell_integrals, chi2_test, histogram, pearson)
