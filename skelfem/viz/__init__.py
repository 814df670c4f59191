"""Pictures: the deformed design in 2D (matplotlib) and 3D (PyVista), tracks, animations."""
