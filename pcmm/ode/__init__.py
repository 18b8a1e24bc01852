"""The ODE core: ``y' = f(t, y)`` stepped by a registry of integrators, with guards as witness
functions located on the dense output.  Nothing here knows Pinocchio, a scene or a mechanism."""
