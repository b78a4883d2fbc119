"""The calibrated damping (COR calibration): the restitution relation against
Newton's method on smooth solves, which it replaced (2026-11-29).

    python benchmarks/bench_calibration.py

``diffimpact.damping_ratio(e)`` solves ``phi(zeta) = phi(-zeta e)``,
``phi(s) = s - ln(1 + s)`` (docs/physics/contact.md, CAL).  The earlier code
found the root of ``COR(zeta) = e`` by Newton's method, each evaluation a
smooth solve of a unit impact at rtol 1e-12; it is rebuilt here from the
package's private solver (``_solve_smooth``) for the comparison.

1. Accuracy: the root of each against a 50-digit bisection of the relation
   in Python's ``decimal`` (independent of both), e from 0.01 to 1 - 1e-9.
2. Cost: compiling and running each, jitted, for the value and for
   ``jax.grad`` (first call in this process), and one more call; and
   scipy's ``brentq`` on the same relation, one root at a time.

Prints markdown tables (paste into RESULTS.md) and writes
benchmarks/calibration.png.
"""

from __future__ import annotations

import decimal
import math
import pathlib
import sys
import time

import jax
import jax.numpy as jnp
import matplotlib
import numpy as np
import scipy.optimize

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import diffimpact as di  # noqa: E402
from diffimpact._laws._dissipative import BoundDampedHertz  # noqa: E402
from diffimpact._materials import ContactProperties  # noqa: E402
from diffimpact._solve._normal import _solve_smooth  # noqa: E402
from diffimpact._solve._root import newton_root  # noqa: E402
from diffimpact.scenes._base import NormalProblem  # noqa: E402

jax.config.update("jax_enable_x64", True)  # diffimpact is validated in float64

sys.path.insert(0, str(pathlib.Path(__file__).parent))
from _report import machine_line, markdown_table  # noqa: E402

CORS = np.concatenate(
    [[0.01, 0.05], np.linspace(0.1, 0.9, 9), 1 - np.geomspace(0.05, 1e-9, 9)]
)


def reference(e: float) -> float:
    """The nonzero root of phi(z) = phi(-z e) by bisection in 50 digits."""
    decimal.getcontext().prec = 50
    e = decimal.Decimal(e)
    one = decimal.Decimal(1)

    def phi(s):
        return s - (one + s).ln()

    lo, hi = decimal.Decimal(0), one / e
    for _ in range(200):
        mid = (lo + hi) / 2
        if mid == lo or mid == hi:
            break
        lo, hi = (mid, hi) if phi(mid) - phi(-mid * e) > 0 else (lo, mid)
    return float((lo + hi) / 2)


def by_solves(cor):
    """The earlier calibration: Newton on ``COR(zeta) - e``, each COR a smooth
    solve of a unit gravity-free impact at rtol 1e-12."""
    settings = di.SolverSettings(rtol=1e-12, atol=1e-14)

    def rebound(zeta, _):
        one = jnp.ones_like(zeta)
        problem = NormalProblem(
            mass=one,
            contact=ContactProperties(0.75 * one, one, jnp.inf * one, 0.3 * one),
            velocity=one,
            gravity=0.0 * one,
        )
        bound = BoundDampedHertz(stiffness=one, exponent=1.5 * one, damping=zeta)
        return _solve_smooth(problem, bound, settings, 0)["rebound_velocity"]

    return newton_root(
        lambda z, target: rebound(z, None) - target,
        1.5 * (1.0 - cor),
        cor,
        rtol=1e-12,
        max_iter=30,
        lower=0.0,
    )


def timed(fn, x, y):
    """Wall time of the first call (compiling) and of a call at another value."""
    t = time.perf_counter()
    jax.block_until_ready(fn(x))
    first = time.perf_counter() - t
    t = time.perf_counter()
    jax.block_until_ready(fn(y))
    return first, time.perf_counter() - t


def main():
    print(machine_line())
    ref = np.array([reference(float(e)) for e in CORS])
    methods = {
        "relation (now)": di.damping_ratio,
        "Newton on solves (before)": by_solves,
    }
    rows, errors = [], {}
    for name, fn in methods.items():
        x, y = jax.block_until_ready((jnp.asarray(0.7), jnp.asarray(0.6)))
        value_first, value_next = timed(jax.jit(fn), x, y)
        grad_first, grad_next = timed(jax.jit(jax.grad(fn)), x, y)
        z = np.asarray(jax.jit(jax.vmap(fn))(jnp.asarray(CORS)))
        errors[name] = np.abs(z - ref) / ref
        rows.append(
            [
                name,
                f"{errors[name].max():.1e}",
                f"{errors[name][CORS <= 0.9].max():.1e}",
                f"{value_first:.2f} s / {value_next * 1e3:.2g} ms",
                f"{grad_first:.2f} s / {grad_next * 1e3:.2g} ms",
            ]
        )

    # scipy's Brent method on the same relation, in plain float64 Python
    # (log1p; no series near e = 1), one root at a time: no compilation.
    def brent(e):
        if e == 1.0:
            return 0.0

        def g(z):
            return z * (1 + e) - math.log1p(z) + math.log1p(-z * e)

        # Near e = 1 the relation is a difference of nearly equal numbers
        # (the reason for the series in the package), so g's sign is rounding
        # noise there; near e = 0 the root lies closer to 1/e than float64
        # resolves (1 - zeta e ~ exp(-1/e)).  Brent's bracket fails in both.
        try:
            return scipy.optimize.brentq(
                g, 0.75 * (1 - e), (1 - 1e-12) / e, xtol=1e-300
            )
        except ValueError:
            return math.nan

    t = time.perf_counter()
    z = np.array([brent(float(e)) for e in CORS])
    per_root = (time.perf_counter() - t) / len(CORS)
    err = np.abs(z - ref) / ref
    errors["scipy brentq on the relation"] = err
    lost = ~np.isfinite(err)
    rows.append(
        [
            "scipy brentq on the relation (float64 Python)",
            f"{np.nanmax(err):.1e}; no bracket at e = "
            + ", ".join(f"{e:.9g}" for e in CORS[lost]),
            f"{np.nanmax(err[CORS <= 0.9]):.1e}",
            f"- / {per_root * 1e3:.2g} ms",
            "-",
        ]
    )
    print(
        markdown_table(
            [
                "damping_ratio",
                "worst relative error, e 0.01 to 1 - 1e-9",
                "e up to 0.9",
                "value: first call / next",
                "gradient: first call / next",
            ],
            rows,
        )
    )
    fig, ax = plt.subplots(figsize=(6, 3.5))
    for name, err in errors.items():
        ax.loglog(1 - CORS, np.maximum(err, 1e-17), "o-", label=name)
    ax.set_xlabel("1 - e")
    ax.set_ylabel("relative error of zeta")
    ax.set_title("Calibrated damping against a 50-digit reference")
    ax.legend()
    fig.tight_layout()
    out = pathlib.Path(__file__).with_name("calibration.png")
    fig.savefig(out, dpi=120)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
