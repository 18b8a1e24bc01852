"""The integration methods by name: what a scene's ``solver.method`` may say.  The registry
itself (:data:`pcmm.ode.integrators.INTEGRATORS`) holds one integrator per name here; this list
is apart so that validating a scene loads no integrator (nor scipy.integrate)."""

#: per configuration, the cheaper method at equal accuracy (:func:`pcmm.ode.integrators.method_for`)
AUTO = "auto"
#: scipy's ``OdeSolver``s stepped by pcmm, Hairer's Fortran DOP853, fixed-step RK4
INTEGRATOR_NAMES = ("RK45", "DOP853", "Radau", "LSODA", "BDF", "RK23", "DOP853F", "RK4")
METHODS = (AUTO, *INTEGRATOR_NAMES)
