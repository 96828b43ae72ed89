"""Studying estimators: error statistics (:mod:`.stats`), chi-square goodness of fit
(:mod:`.chi2`), gradient fitting (:mod:`.fitting`) and photon-density fitting
(:mod:`.density_fit`)."""
