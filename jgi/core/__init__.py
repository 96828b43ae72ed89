"""Building blocks that know nothing of scenes or estimators: struct-of-arrays vectors, the
counter-based RNG, sampling warps, transforms, the triangle BVH, concurrent calls, device
sharding, image files and the user-input errors. Every other layer builds on these."""
