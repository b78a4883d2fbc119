"""The result of a fit: estimates, covariance, standard errors, correlations,
identifiability and the per-row predictions at the estimates."""

from __future__ import annotations

import dataclasses
import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from .._io._data import column_of
from .._io._frames import optional
from ._experiment import Experiment
from ._fit_problem import LOOSE, check_predictions, diverged
from ._predict import row_label
from ._residuals import (
    _FAILED_RESIDUAL,
)
from ._row_blocks import RowBlocks, workers

# Singular values of the scaled Jacobian below this fraction of the largest
# mean a direction the data do not determine (well above the ~1e-10 noise of
# derivatives through solves at rtol 1e-11, well below any real sensitivity).
_RANK_TOL = 1e-6


# Where a direction is undetermined, its variance is reported from this floor
# (so the errors come out huge and the correlation +-1, not infinite or NaN).
_SV_FLOOR = 1e-9


class IdentifiabilityWarning(UserWarning):
    """The data cannot determine some combination of the free parameters."""


@dataclasses.dataclass(frozen=True)
class FitResult:
    """The outcome of `fit` (numbers in SI units, numpy arrays).

    - `names`, `values`, `std_errors`, `start`: per free parameter;
    - `covariance`, `correlation`: ``(p, p)``;
    - `quantities`: the measured outputs fitted; `measured`, `predicted`,
      `sigma`, `residuals` (weighted): ``(n_rows, n_quantities)``, NaN where a
      row did not measure a quantity; `sigma_measured`: per quantity, whether
      its sigma came from the file (else it is the RMS of the measurements);
      `lines`: the line in the data file of each row (how every message and
      output file names a row);
    - `cost`: half the weighted sum of squares; `chi2_reduced`: ``2 cost / dof``;
    - `iterations`, `converged`, `solver`, `seconds`; `subsample`: ``(rows,
      iterations)`` of the warm start on a subsample (counted in
      `iterations`), ``(0, 0)`` without one;
    - `singular_values`: of the Jacobian w.r.t. the unconstrained parameters;
    - `warnings`: identifiability and convergence messages;
    - `experiment`: the `Experiment` with the fitted values in place;
    - `columns`: the data's columns (`ExperimentData.columns`), whose units
      `per_row` and `to_dataframe` write in.
    """

    names: tuple[str, ...]
    values: np.ndarray
    std_errors: np.ndarray
    start: np.ndarray
    covariance: np.ndarray
    correlation: np.ndarray
    quantities: tuple[str, ...]
    inputs: dict
    measured: np.ndarray
    predicted: np.ndarray
    sigma: np.ndarray
    residuals: np.ndarray
    cost: float
    chi2_reduced: float
    dof: int
    absolute_sigma: bool
    iterations: int
    converged: bool
    solver: str
    seconds: float
    singular_values: np.ndarray
    warnings: tuple[str, ...]
    experiment: Experiment
    sigma_measured: tuple[bool, ...] = ()
    lines: np.ndarray | None = None
    subsample: tuple[int, int] = (0, 0)
    columns: dict | None = None

    @property
    def identifiable(self) -> bool:
        return not any("cannot determine" in w for w in self.warnings)

    def per_row(self) -> dict[str, np.ndarray]:
        """One entry per row of the data, every column's unit in its name:
        ``line`` (the line in the file; ``row``, from 1, for a DataFrame),
        the inputs, and per fitted quantity ``measured_<column>``,
        ``predicted_<column>``, ``sigma_<column>`` (the weight: the file's
        sigma, or the RMS of the measurements) and
        ``weighted_residual_<quantity>`` (predicted - measured) / sigma;
        NaN where a row did not measure a quantity.  ``<column>`` is the
        data's own column name and unit (``contact_time_us``,
        ``angle_deg``), SI (``max_force_N``) for a quantity it has none of.
        What `to_dataframe` and the command line's ``residuals.csv`` hold."""
        n = self.measured.shape[0]
        out = {}
        if self.lines is not None:
            out["line"] = np.asarray(self.lines, dtype=int)
        else:
            out["row"] = np.arange(1, n + 1)
        for q, v in self.inputs.items():
            col = column_of(q, self.columns)
            out[col.header] = np.asarray(v, dtype=float) / col.factor
        for k, q in enumerate(self.quantities):
            col = column_of(q, self.columns)
            h = col.header
            out[f"measured_{h}"] = self.measured[:, k] / col.factor
            out[f"predicted_{h}"] = self.predicted[:, k] / col.factor
            sigma = np.where(np.isnan(self.measured[:, k]), np.nan, self.sigma[:, k])
            out[f"sigma_{h}"] = sigma / col.factor
            out[f"weighted_residual_{q}"] = self.residuals[:, k]
        return out

    def to_dataframe(self):
        """`per_row` as a pandas DataFrame (one row per row of the data, in
        its order; needs pandas)."""
        pd = optional("pandas", "FitResult.to_dataframe")
        return pd.DataFrame(self.per_row())

    def parameters_dataframe(self):
        """The estimates as a pandas DataFrame: one row per free parameter
        (the index), columns ``value``, ``std_error``, ``start`` (SI)."""
        pd = optional("pandas", "FitResult.parameters_dataframe")
        frame = pd.DataFrame(
            {"value": self.values, "std_error": self.std_errors, "start": self.start},
            index=pd.Index(list(self.names), name="parameter"),
        )
        return frame

    def summary(self) -> str:
        """A table of estimates with standard errors and the correlations."""
        w = max(len(n) for n in self.names)
        lines = [f"{'parameter':<{w}}  {'estimate':>13}  {'std error':>11}  start"]
        for n, v, s, x0 in zip(
            self.names, self.values, self.std_errors, self.start, strict=True
        ):
            lines.append(f"{n:<{w}}  {v:>13.6g}  {s:>11.3g}  {x0:.6g}")
        if len(self.names) > 1:
            lines.append("correlation:")
            for n, row in zip(self.names, self.correlation, strict=True):
                lines.append(f"  {n:<{w}}  " + "  ".join(f"{c:+.3f}" for c in row))
        lines.append(
            f"{self.solver}: {self.iterations} iterations, "
            f"{'converged' if self.converged else 'NOT converged'}, cost "
            f"{self.cost:.4g}, reduced chi^2 {self.chi2_reduced:.4g} "
            f"(dof {self.dof}), {self.seconds:.1f} s"
        )
        if self.subsample[0]:
            lines[-1] += (
                f"; the first {self.subsample[1]} iterations on "
                f"{self.subsample[0]} rows"
            )
        lines += [f"warning: {m}" for m in self.warnings]
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """A JSON-ready summary (parameters, covariance, fit statistics);
        non-finite numbers (an infinite standard error) become None (JSON has
        no Infinity)."""
        return json_ready(self._dict())

    def _dict(self) -> dict:
        return {
            "parameters": {
                n: {"value": float(v), "std_error": float(s), "start": float(x0)}
                for n, v, s, x0 in zip(
                    self.names, self.values, self.std_errors, self.start, strict=True
                )
            },
            "covariance": self.covariance.tolist(),
            "correlation": self.correlation.tolist(),
            "quantities": list(self.quantities),
            "cost": self.cost,
            "chi2_reduced": self.chi2_reduced,
            "dof": self.dof,
            "absolute_sigma": self.absolute_sigma,
            "iterations": self.iterations,
            "converged": self.converged,
            "solver": self.solver,
            "seconds": self.seconds,
            "subsample": {
                "rows": self.subsample[0],
                "iterations": self.subsample[1],
            },
            "singular_values": self.singular_values.tolist(),
            "warnings": list(self.warnings),
        }


def json_ready(x):
    if isinstance(x, dict):
        return {k: json_ready(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [json_ready(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def fit_result(
    problem,
    data,
    u,
    steps,
    converged,
    solver,
    seconds,
    x0,
    absolute,
    user_settings,
    final=None,
    warm=None,
):
    """The `FitResult` at ``u``.  `final`: the residuals and their Jacobian
    at ``u`` from the last step, if known (else both are computed here);
    `warm`: ``(rows, iterations)`` of the warm start."""
    names = problem.names
    x = np.array([float(v) for v in problem.parameters(u)])
    mask = np.asarray(problem.mask)
    measured = np.where(mask, np.asarray(problem.measured), np.nan)
    sigma = np.asarray(problem.sigma)
    if final is None:  # the optax minimisers: evaluate at the optimum
        blocks = RowBlocks(problem, np.arange(data.n), workers())
        try:
            e = blocks.evaluate(jnp.asarray(u))
        finally:
            blocks.close()
        final = tuple(np.asarray(x) for x in (e.residual, e.jacobian, e.differenced))
        final += (np.zeros(0, int),)
    r = final[0].reshape(mask.shape)
    # a row that failed (its sentinel residual) or is undefined there is named
    # by the full check, which raises
    if np.any(mask & ((r == _FAILED_RESIDUAL) | ~np.isfinite(r))):
        check_predictions(problem, u, data, "at the fitted values")
    pred, jac_u = np.where(mask, measured + sigma * r, np.nan), final[1]
    resid = np.where(mask, (pred - measured) / sigma, np.nan)
    cost = 0.5 * float(np.nansum(resid**2))
    m, p = int(mask.sum()), len(x)
    dof = m - p
    notes = []
    if not np.all(np.isfinite(pred[mask])) or not np.all(np.isfinite(jac_u)):
        raise FloatingPointError(
            "the fit reached parameters where the simulation is not finite: "
            f"{dict(zip(names, x, strict=True))}; narrow the bounds"
        )
    with np.errstate(over="ignore"):
        # Finite, but past what the covariance's J^T J can hold (|J| > 1e154):
        # not a sensitivity, an overflowed integration of one (`diverged`).
        if not np.isfinite(np.sum(jac_u**2)):
            raise diverged(problem.experiment.settings)
    # dx/du of each transform, to carry the covariance from u to x.
    dx_du = np.asarray(
        [
            jax.grad(lambda v, t=t: t.forward(v))(float(u[i]))
            for i, t in enumerate(problem.transforms)
        ]
    )
    _, s, vt = np.linalg.svd(jac_u, full_matrices=False)
    s_max = s[0] if s.size and s[0] > 0 else 1.0
    weak = s < _RANK_TOL * s_max
    if weak.any():
        for k in np.nonzero(weak)[0]:
            combo = " ".join(
                f"{c:+.2f}*log({n})"
                if problem.transforms[i].kind == "log"
                else f"{c:+.2f}*{n}"
                for i, (c, n) in enumerate(zip(vt[k], names, strict=True))
                if abs(c) > 0.05
            )
            notes.append(
                "the data cannot determine the combination "
                f"[{combo}] (Jacobian singular-value ratio {s[k] / s_max:.1e}); "
                "fix one of these parameters or add measurements sensitive to it"
            )
    s_eff = np.maximum(s, _SV_FLOOR * s_max)
    cov_u = (vt.T / s_eff**2) @ vt
    if absolute:
        scale = 1.0
    elif dof > 0:
        scale = 2.0 * cost / dof
    else:
        scale = math.inf
        notes.append(
            f"{m} measurements for {p} parameters: no degrees of freedom left to "
            "estimate the noise, so the standard errors are unknown (inf); add "
            "sigma_ columns or more rows"
        )
    cov = (
        scale * cov_u * np.outer(dx_du, dx_du)
        if math.isfinite(scale)
        else (np.full((p, p), math.inf))
    )
    se = np.sqrt(np.diag(cov)) if math.isfinite(scale) else np.full(p, math.inf)
    # A parameter in an undetermined direction has no finite error, whatever
    # the noise (with exact data the residual scale alone would make it look
    # certain); its correlations still come from the floored singular values.
    involved = np.any(np.abs(vt[weak]) > 0.05, axis=0) if weak.any() else []
    for i in np.nonzero(involved)[0]:
        se[i] = math.inf
        cov[i, :] = cov[:, i] = math.inf
    # One parameter on which the predictions barely depend has a full-rank
    # Jacobian (the test above is relative to the largest singular value,
    # and with one parameter that is its own), but an error far larger than
    # itself: the data do not determine even its order of magnitude.
    for i in np.nonzero(np.isfinite(se) & (se > LOOSE * np.abs(x)))[0]:
        notes.append(
            f"the data barely determine {names[i]}: its standard error is "
            f"{se[i] / abs(x[i]):.1e} times its value; fix it or add "
            "measurements sensitive to it"
        )
    d = np.sqrt(np.diag(cov_u))
    corr = cov_u / np.outer(d, d)
    for i in range(p):
        for j in range(i + 1, p):
            if abs(corr[i, j]) > 0.99 and not weak.any():
                notes.append(
                    f"{names[i]} and {names[j]} are strongly correlated "
                    f"({corr[i, j]:+.3f}): the data barely separate them"
                )
    if final is not None and int(np.sum(final[2])):
        notes.append(
            f"the forward-mode derivatives of {int(np.sum(final[2]))} row(s) "
            "diverged at the fitted values (a solver artefact, e.g. in a stick "
            "phase); their derivatives, and so the covariance, come from "
            "central differences"
        )
    blocked = final[3] if final is not None else ()
    if len(blocked):
        where = ", ".join(str(row_label(data.lines, i)) for i in blocked[:5])
        more = f" and {len(blocked) - 5} more" if len(blocked) > 5 else ""
        notes.append(
            f"{solver} did not converge: its last trial steps were rejected "
            f"because the solves of {len(blocked)} row(s) failed there ({where}"
            f"{more}), so it stopped at the edge of the region where they fail, "
            "not at a minimum. Those rows need more solver steps: raise "
            "max_steps of the experiment's SolverSettings (the command line's "
            "--solver-steps; a stiff stick phase, e.g. a body of small "
            "inertia, needs many), or check those rows"
        )
    elif not converged:
        notes.append(
            f"{solver} did not converge in {steps} iterations; raise max_steps or "
            "start closer"
        )
    for msg in notes:
        if "cannot determine" in msg or "correlated" in msg or "barely" in msg:
            warnings.warn(msg, IdentifiabilityWarning, stacklevel=3)
    return FitResult(
        names=names,
        values=x,
        std_errors=se,
        start=x0,
        covariance=cov,
        correlation=corr,
        quantities=problem.quantities,
        inputs={k: np.asarray(v) for k, v in data.inputs.items()},
        measured=measured,
        predicted=np.where(mask, pred, np.nan),
        sigma=sigma,
        residuals=resid,
        cost=cost,
        chi2_reduced=2.0 * cost / dof if dof > 0 else math.nan,
        dof=dof,
        absolute_sigma=absolute,
        iterations=steps,
        converged=converged,
        solver=solver,
        seconds=seconds,
        singular_values=s,
        warnings=tuple(notes),
        experiment=dataclasses.replace(
            problem.with_parameters(u), settings=user_settings
        ),
        sigma_measured=tuple(q in data.sigmas for q in problem.quantities),
        lines=data.lines,
        subsample=warm or (0, 0),
        columns=dict(data.columns),
    )
