"""Kinetic-energy loss equals the work of the contact force over the impact,
with the work computed independently of the solve."""

import numpy as np
import pytest
from conftest import sphere
from scipy.integrate import quad

import diffimpact as di


@pytest.mark.parametrize("method", ["smooth", "events", "quadrature"])
@pytest.mark.parametrize(
    "velocity, yield_strength", [(1.0, 300e6), (5.0, 1e9), (0.05, 80e6)]
)
def test_jackson_green_energy_balance(method, velocity, yield_strength):
    """Loss = int_0^{d_m} F_load dd - int_{d_r}^{d_m} F_unload dd, the integrals by
    adaptive scipy quadrature of the sharp law (a code path the solver never uses)."""
    sc = sphere(velocity, yield_strength)
    law = di.JacksonGreen()
    r = di.simulate(sc, law, method)
    b = law.bind(sc.normal_problem().contact, velocity)
    d_m, d_s = float(r.max_deflection), float(b.switch_deflection())
    d_r = float(r.permanent_deformation)
    f_m = float(b.loading_force(d_m, 0.0, 1 if d_m > d_s else 0))

    def f_load(d):
        return float(b.loading_force(d, 0.0, 0 if d <= d_s else 1))

    w_load = quad(
        f_load,
        0.0,
        d_m,
        points=[d_s] if d_s < d_m else None,
        epsabs=0,
        epsrel=1e-12,
        limit=200,
    )[0]
    w_unload = quad(
        lambda d: float(b.unloading_force(d, 0.0, d_m, f_m)),
        d_r,
        d_m,
        epsabs=0,
        epsrel=1e-12,
    )[0]
    m = float(sc.mass)
    loss = 0.5 * m * (velocity**2 - float(r.rebound_velocity) ** 2)
    assert loss == pytest.approx(w_load - w_unload, rel=1e-6)
    # The reported works are the same numbers seen from the bodies' side.
    assert float(r.work_compression) == pytest.approx(w_load, rel=1e-6)
    assert float(r.work_restitution) == pytest.approx(w_unload, rel=1e-6)


@pytest.mark.parametrize(
    "law",
    [di.HuntCrossley(0.6), di.Flores(0.8), di.AdamsImpact(2.5e8, 2.0, 10.0, 1e-6)],
    ids=lambda x: type(x).__name__,
)
def test_rate_dependent_energy_balance(law):
    """For velocity-dependent laws: the work int F d_dot dt along the saved
    history (Simpson, 4001 samples) equals the kinetic-energy loss."""
    sc = sphere(1.0, 300e6)
    r = di.simulate(sc, law, n_history=4001)
    h = r.history
    t, f, v = (np.asarray(x) for x in (h.time, h.force, h.velocity))
    from scipy.integrate import simpson

    work = simpson(f * v, x=t)  # net work done on the contact (= energy lost)
    m = float(sc.mass)
    loss = 0.5 * m * (1.0 - float(r.rebound_velocity) ** 2)
    assert loss > 0.01 * 0.5 * m
    assert work == pytest.approx(loss, rel=1e-6)
    # And the reported peak force is the history's maximum.
    assert float(r.max_force) == pytest.approx(f.max(), rel=9e-7)
