"""Multi-impact mechanisms (issue 7): the slider-crank with a clearance joint.

Prints a table and writes ``benchmarks/multi.png``:

1. Cost per simulated second of :func:`diffimpact.simulate_span` (one diffrax
   solve, Dopri8 and Tsit5) against scipy ``solve_ivp`` (DOP853, RK45, LSODA)
   on the *same* ODE: scipy integrates the very vector field of
   ``simulate_span`` (``diffimpact._solve._span_field._setup``, jitted, called once per
   stage), at the same tolerances on the same scaled state.  The error of every
   run is measured against a 1e-13 ``simulate_span`` reference at ``t1``: the
   eccentricity of the pin in the bearing (relative to the clearance) and the
   crank angle.  Timings are the best of ``REPEAT`` runs after compilation.
2. Steel/aluminium vs steel/cast-iron bearing: impacts, peak joint force.
3. Energy balance: ``motor work - kinetic energy - contact and friction
   losses`` relative to the motor work.
4. ``jax.grad`` of the first impact's peak force and impulse w.r.t. clearance
   and contact stiffness against central differences of a 1e-13 solve.

Run: ``PYTHONPATH=src python benchmarks/bench_multi.py`` (about 5 minutes on
one loaded core).
"""

from __future__ import annotations

import pathlib
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree
from scipy.integrate import solve_ivp

import diffimpact as di
from diffimpact._solve._span_field import _setup

jax.config.update("jax_enable_x64", True)  # diffimpact is validated in float64

HERE = pathlib.Path(__file__).parent
T_COST = 0.3  # [s] span of the cost runs
T_MAT = 1.0  # [s] span of the material comparison
REPEAT = 2
MU = 0.1


def crank(clearance=3e-5, cast_iron=False):
    sc = di.scenes.SliderCrank(clearance=clearance)
    return sc.cast_iron_bearing() if cast_iron else sc


def ours(sc, t1, settings, mu=MU):
    law = di.Hertz(stiffness=sc.hertz_stiffness)
    return di.simulate_span(
        sc, law, (0.0, t1), friction=di.Friction(mu, stick="slope"), settings=settings
    )


def best_time(fn):
    fn()  # compile / warm up
    times = []
    for _ in range(REPEAT):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def eccentricity_and_angle(q):
    q = np.asarray(q)
    return q[1:3], q[0]


def scipy_run(sc, t1, method, rtol, atol):
    """solve_ivp on the span solver's own scaled vector field (no onset
    states: scipy has no use for them)."""
    law = di.Hertz(stiffness=sc.hertz_stiffness)
    settings = di.SpanSettings(onset_step=None)
    p, y0 = _setup(sc, law, di.Friction(MU, stick="slope"), settings)
    # scipy integrates a flat vector: the state pytree raveled (the same
    # order and the same numbers)
    flat0, unravel = ravel_pytree(y0)
    field = jax.jit(lambda tau, y: ravel_pytree(p.field(tau, unravel(y)))[0])
    field(0.0, flat0).block_until_ready()
    tau1 = float(t1 / p.time)

    def fun(tau, y):
        return np.asarray(field(tau, y))

    def run():
        return solve_ivp(
            fun, (0.0, tau1), np.asarray(flat0), method=method, rtol=rtol, atol=atol
        )

    elapsed = best_time(run)
    sol = run()
    q = np.asarray(unravel(sol.y[:, -1]).q) * np.asarray(p.q_scale)
    return elapsed, q, sol.nfev, sol.status


def main():
    print("# Multi-impact mechanisms: slider-crank, 0.03 mm clearance")
    print(f"jax {jax.__version__}, devices {jax.devices()}")
    sc = crank()
    c = float(sc.clearance)

    # 1. Reference and cost.
    ref = ours(sc, T_COST, di.SpanSettings(rtol=1e-13, atol=1e-15, max_steps=65536))
    e_ref, phi_ref = eccentricity_and_angle(ref.q)
    print(
        f"reference (rtol 1e-13): {int(ref.impacts.count)} impacts in {T_COST} s, "
        f"{int(ref.num_accepted_steps)} steps"
    )
    rows = []
    tolerances = [1e-6, 1e-8, 1e-10]
    for name, solver in [
        ("ours Dopri8", di.SpanSettings().solver),
        ("ours Tsit5", None),
    ]:
        for rtol in tolerances:
            kw = dict(rtol=rtol, atol=1e-2 * rtol, max_steps=65536)
            if solver is None:
                import diffrax

                kw["solver"] = diffrax.Tsit5()
            s = di.SpanSettings(**kw)
            fn = eqx.filter_jit(lambda s=s: ours(sc, T_COST, s))
            elapsed = best_time(lambda fn=fn: jax.block_until_ready(fn()))
            r = fn()
            e, phi = eccentricity_and_angle(r.q)
            rows.append(
                dict(
                    method=name,
                    rtol=rtol,
                    cost=elapsed / T_COST,
                    err_e=np.linalg.norm(e - e_ref) / c,
                    err_phi=abs(phi - phi_ref),
                    impacts=int(r.impacts.count),
                    work=int(r.num_steps),
                )
            )
    for method in ["DOP853", "RK45", "LSODA"]:
        for rtol in tolerances:
            elapsed, q, nfev, status = scipy_run(sc, T_COST, method, rtol, 1e-2 * rtol)
            e, phi = eccentricity_and_angle(q)
            rows.append(
                dict(
                    method=f"scipy {method}",
                    rtol=rtol,
                    cost=elapsed / T_COST,
                    err_e=np.linalg.norm(e - e_ref) / c,
                    err_phi=abs(phi - phi_ref),
                    impacts=-1,
                    work=nfev,
                )
            )
    print()
    print(
        "| method | rtol | cost [s per simulated s] | eccentricity error / c "
        "| crank angle error [rad] | impacts | steps (ours) / RHS calls (scipy) |"
    )
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        imp = "" if r["impacts"] < 0 else str(r["impacts"])
        print(
            f"| {r['method']} | {r['rtol']:.0e} | {r['cost']:.3g} | {r['err_e']:.2e} "
            f"| {r['err_phi']:.2e} | {imp} | {r['work']} |"
        )

    # 2 + 3. Materials, energy balance.
    print()
    print(
        f"Steel/aluminium vs steel/cast iron, {T_MAT} s from rest, mu = {MU}, "
        "default SpanSettings (rtol 1e-11):"
    )
    print(
        "| pair | K [N/mm^1.5] | impacts | peak joint force [N] | first-impact "
        "peak [N] | mean impact peak [N] | energy residual / motor work |"
    )
    print("|---|---|---|---|---|---|---|")
    mats = {}
    for label, ci in [("steel/aluminium", False), ("steel/cast iron", True)]:
        s = crank(cast_iron=ci)
        r = ours(s, T_MAT, di.SpanSettings(max_steps=65536, max_impacts=512))
        im = r.impacts
        n = min(int(im.count), 512)
        peaks = np.asarray(im.peak_force[:n])
        balance = (
            r.applied_work
            - r.kinetic_energy
            - r.contact_energy
            - r.dissipated_contact_work
            - r.friction_work
        )
        resid = abs(float(balance)) / float(r.applied_work)
        mats[label] = (r, peaks, np.asarray(im.start[:n]))
        print(
            f"| {label} | {float(s.hertz_stiffness) / 1e3**1.5:.2f} | "
            f"{int(im.count)} | {peaks.max():.4g} | {peaks[0]:.4g} | "
            f"{peaks.mean():.4g} | {resid:.1e} |"
        )

    # 4. Gradients.
    print()
    tight = di.SpanSettings(max_steps=4096, max_impacts=8, rtol=1e-13, atol=1e-15)
    short = di.SpanSettings(max_steps=4096, max_impacts=8)

    def first(p, settings):
        r = crank_span(p[0], p[1], MU, 0.03, settings)
        return jnp.stack([r.impacts.peak_force[0], r.impacts.impulse[0]])

    p0 = jnp.array([3e-5, float(sc.hertz_stiffness)])
    jac = np.asarray(eqx.filter_jit(jax.jacrev(lambda p: first(p, short)))(p0))
    f_tight = eqx.filter_jit(lambda p: first(p, tight))
    print(
        "| output | parameter | jax.grad (rtol 1e-11) | central diff. (rtol 1e-13) "
        "| rel. diff. |"
    )
    print("|---|---|---|---|---|")
    grad_rows = []
    for k, pname in enumerate(["clearance [m]", "stiffness [N/m^1.5]"]):
        h = 1e-3 * float(p0[k])
        e = jnp.zeros(2).at[k].set(h)
        fd = np.asarray(f_tight(p0 + e) - f_tight(p0 - e)) / (2 * h)
        for j, oname in enumerate(["first peak force", "first impulse"]):
            rel = abs(jac[j, k] - fd[j]) / abs(fd[j])
            grad_rows.append(rel)
            print(f"| {oname} | {pname} | {jac[j, k]:.6e} | {fd[j]:.6e} | {rel:.1e} |")

    # 5. Gradients over a longer horizon: 0.2 s, about 8 impacts.
    print()
    horizon_gradients(float(sc.hertz_stiffness))

    plot(rows, mats)


def crank_span(clearance, stiffness, mu, t1, settings):
    """The default slider-crank from rest over ``(0, t1)``, Hertz joint."""
    return di.simulate_span(
        di.scenes.SliderCrank(clearance=clearance),
        di.Hertz(stiffness=stiffness),
        (0.0, t1),
        friction=di.Friction(mu, stick="slope"),
        settings=settings,
    )


def horizon_gradients(k0, t1=0.2):
    """``jax.jacrev`` (default settings) of the crank angle at ``t1``, the
    total joint impulse and the third impact's peak force w.r.t. clearance,
    stiffness and mu, against central differences (step 1e-3 relative) of a
    1e-13 solve.  Before the vector field bounded wild trial states, these
    gradients were NaN from about 0.07 s on."""
    tight = di.SpanSettings(max_steps=16384, max_impacts=16, rtol=1e-13, atol=1e-15)
    default = di.SpanSettings(max_steps=8192, max_impacts=16)

    def outputs(p, settings):
        r = crank_span(p[0], p[1], p[2], t1, settings)
        im = r.impacts
        return jnp.stack([r.q[0], jnp.sum(im.impulse), im.peak_force[2]]), im.count

    p0 = jnp.array([3e-5, k0, MU])
    jac = np.asarray(eqx.filter_jit(jax.jacrev(lambda p: outputs(p, default)[0]))(p0))
    steps = jnp.diag(1e-3 * p0)
    out, counts = eqx.filter_jit(jax.vmap(lambda p: outputs(p, tight)))(
        jnp.concatenate([p0 + steps, p0 - steps])
    )
    out = np.asarray(out)
    print(f"Gradients over {t1} s ({int(counts[0])} impacts):")
    print("| output | clearance | stiffness | mu |")
    print("|---|---|---|---|")
    names = ["crank angle at t1", "total joint impulse", "third impact's peak"]
    for j, name in enumerate(names):
        cells = []
        for k in range(3):
            fd = (out[k, j] - out[k + 3, j]) / (2 * float(steps[k, k]))
            cells.append(f"{abs(jac[j, k] - fd) / abs(fd):.1e}")
        print(f"| {name} | " + " | ".join(cells) + " |")


def plot(rows, mats):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    for method in dict.fromkeys(r["method"] for r in rows):
        sel = [r for r in rows if r["method"] == method]
        a.loglog(
            [max(r["err_e"], 1e-16) for r in sel],
            [r["cost"] for r in sel],
            "o-" if method.startswith("ours") else "s--",
            label=method,
        )
    a.set_xlabel("eccentricity error at t1 / clearance")
    a.set_ylabel("wall time per simulated second [s]")
    a.set_title(f"slider-crank, 0.03 mm clearance, {T_COST} s span")
    a.legend(fontsize=8)
    for label, (_, peaks, starts) in mats.items():
        b.semilogy(starts, peaks, ".", label=f"{label} ({len(peaks)} impacts)")
    b.set_xlabel("impact start [s]")
    b.set_ylabel("impact peak force [N]")
    b.set_title("pin-bearing impacts, Hertz K from the materials")
    b.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(HERE / "multi.png", dpi=120)
    print(f"\nwrote {HERE / 'multi.png'}")


if __name__ == "__main__":
    main()
