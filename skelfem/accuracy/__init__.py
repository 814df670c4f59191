"""``--tol``: ladders of meshes (uniform or adaptive) until the design's own marker error estimate is met."""
