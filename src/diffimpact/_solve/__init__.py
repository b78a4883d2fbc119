"""The solve family: one impact (or one span of impacts) from a scene, a
contact law and friction to an `ImpactResult`.

`simulate` dispatches once (``_dispatch``) to one solver: the normal solves
(smooth-switched ODE, event-switched ODE, the energy quadrature), the planar
ODE with its tangential closed forms and partial slip, the rigid-body
impulse laws, and `simulate_span` for mechanisms.  Law binding, step-size
settings, extremum location and the small root finder live here too.
Nothing in this family imports the inference, file or command-line families.
"""
