"""From a validated design to a tagged DOLFINx mesh; material points on it; moving a mesh with its outlines."""
