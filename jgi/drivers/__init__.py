"""How the paths of a render are scheduled: chunks of independent paths (:mod:`.chunked`),
per-segment wavefronts with path regeneration (:mod:`.wavefront`) and light paths splatted onto
the film (:mod:`.splat`). Drivers know nothing of any estimator: an estimator hands them a pure
path function."""
