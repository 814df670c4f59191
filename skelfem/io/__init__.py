"""Files: strict JSON, CSV, XDMF, atomic writes, and output folders that hold one complete result or none."""
