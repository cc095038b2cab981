"""Ray-scene intersection: primitives, the BVH and vector helpers."""
