"""The numerical core: parameters, model, torques, integrators, stepper, scenes (numpy and scipy only)."""
