"""The inference family: experiments (a measured row mapped to a scene and
its predicted observables), least-squares fits and their covariance,
posteriors (priors, transforms, NUTS, diagnostics), cross-validation and
batch sweeps.  It builds on the solve family through its public interface
(`simulate`, `SolverSettings`, the scenes and laws) only.
"""
