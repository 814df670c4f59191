"""On top of a Session: sensitivities, Soft IK and tracking, gradients through time, trajectory optimisation."""
