"""Machinery shared by the estimators: MIS heuristics (:mod:`.mis`), subpaths (:mod:`.subpath`:
random walks, vertices, next-event estimation), their connections (:mod:`.connection`: a
light vertex to a camera vertex or to the pinhole), visible points and where
photons are stored (:mod:`.visible_points`), photon tracing (:mod:`.photons`), the spatial hash
grid (:mod:`.hash_grid`), density filters and estimates (:mod:`.density`), and the Metropolis
kernel (:mod:`.mcmc`)."""
