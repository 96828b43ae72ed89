"""What light does at one point: ray-primitive intersection (:mod:`.geometry`), BSDFs
(:mod:`.bsdf`), light sources (:mod:`.lights`) and the pinhole camera (:mod:`.camera`)."""
