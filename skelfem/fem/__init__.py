"""The finite-element core: the model Pi = sum of the terms, its matrix, linear solves, Newton, time steps."""
