"""How the paths of a render are scheduled: chunks of independent paths (:mod:`.chunked`),
per-segment wavefronts with path regeneration (:mod:`.wavefront`) and light paths splatted onto
the film (:mod:`.splat`). Drivers know nothing of any estimator: an estimator hands them a pure
path function ``(scene, seed, pixel, sample) -> ...``, hashable by value
(:class:`jgi.core.configured.Configured`), which is a static argument of the driver's jitted
loop, so JAX's compile cache keys on the function and settings that run."""
