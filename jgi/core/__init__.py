"""Building blocks that know nothing of scenes or estimators: struct-of-arrays vectors, the
counter-based RNG, sampling warps, transforms, the triangle BVH, concurrent calls, device
sharding, functions with their settings as compile-cache keys (:mod:`.configured`), image files
and the user-input errors. Every other layer builds on these."""
