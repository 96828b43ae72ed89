"""Machinery shared by the estimators: MIS heuristics (:mod:`.mis`), subpaths (:mod:`.subpath`:
random walks, vertices, next-event estimation, camera connections, visible points), photon
tracing (:mod:`.photons`), the photon hash grid and density kernels (:mod:`.photon_map`), and
the Metropolis kernel (:mod:`.mcmc`)."""
