"""``diffimpact learn``: a parameter as a function of the impact's state,
learned from an experiment CSV and compared with the plain physics and a
plain network on held-out rows.

    diffimpact learn DATA.csv [--learn cor[=FEATURES]] [--no-residual]
                              [--holdout 0.3] [--out DIR]

trains, on the rows not held out, the rigid impact law (Routh's method
with Coulomb friction) with constant COR and mu, the same law with the named
parameters learned (`diffimpact.Learned`), that hybrid plus a learned
correction of its outputs (`diffimpact.Residual`; not with
``--no-residual``), and a plain MLP; prints their median held-out errors
and writes, into DIR: ``learn.json`` (the models, their held-out errors, the
rows, provenance), ``errors.csv`` (each row's error under each model),
``hybrid.eqx`` and ``residual.eqx`` (the trained hybrids,
`diffimpact.load_model`).  Nothing in DIR is overwritten without ``--force``.
"""

from __future__ import annotations

import csv
import json
import os
import time

from ._files import number, open_new, writable_folder
from ._outputs import provenance

_OUTPUT_FILES = ("learn.json", "errors.csv", "hybrid.eqx")
_RESIDUAL_FILE = "residual.eqx"
_VELOCITIES = ("velocity_x_after", "velocity_y_after", "angular_velocity")
# The rigid law's parameters (`diffimpact.RigidContact`, Coulomb's mu);
# tangential_cor switches on its tangential restitution (Walton's rule).
LEARNABLE = ("cor", "mu", "tangential_cor")
# The contact-space description of the first contact: what a compliant
# law's COR depends on besides the materials (how-to "When constant
# parameters are not enough").
DEFAULT_FEATURES = (
    "normal_speed",
    "slip_ratio",
    "normal_mobility",
    "coupling",
    "contact_radius",
)


def register(sub) -> None:
    p = sub.add_parser(
        "learn",
        help="learn a parameter as a function of the impact's state, and compare "
        "with the constant-parameter physics and a plain network on held-out rows",
    )
    p.add_argument("data", help="experiment CSV of a planar scene")
    p.add_argument(
        "--learn",
        action="append",
        default=[],
        metavar="PARAM[=FEATURES]",
        help="a parameter to learn (cor, mu or tangential_cor), with "
        "comma-separated features "
        f"(default: {', '.join(DEFAULT_FEATURES)}); repeat for several "
        "(default: cor and mu)",
    )
    p.add_argument(
        "--no-residual",
        action="store_true",
        help="skip the hybrid plus a learned correction of its outputs "
        "(residual physics: for what no parameter of the law expresses)",
    )
    p.add_argument(
        "--residual-features",
        default=None,
        metavar="FEATURES",
        help="comma-separated features of the residual (default: the file's "
        "inputs, as the network reads them)",
    )
    p.add_argument(
        "--restitution",
        choices=("newton", "poisson", "energetic"),
        default="energetic",
        help="the rigid law's restitution (default energetic: never gains energy)",
    )
    p.add_argument(
        "--kind",
        choices=("mlp", "polynomial"),
        default="mlp",
        help="the learned function: a small MLP (default) or a quadratic polynomial",
    )
    p.add_argument(
        "--holdout",
        type=number,
        default=0.3,
        help="fraction of the rows held out to compare the models (default 0.3)",
    )
    p.add_argument(
        "--no-network", action="store_true", help="skip the plain-network baseline"
    )
    p.add_argument("--seed", type=int, default=0, help="draw of the rows (default 0)")
    p.add_argument("--out", default=None, help="output folder (default learn-<data>)")
    p.add_argument("--force", action="store_true", help="overwrite outputs in --out")
    p.set_defaults(func=run)


def _parse_learn(items) -> dict:
    learned = {}
    # Both by default: measured on 2,000 synthetic impacts whose mu is
    # constant, learning mu as well cost 0.0001-0.0004 of held-out error
    # (RESULTS, "Learned parameters"), and real contacts' tangential
    # response does change with the state.
    for item in items or ["cor", "mu"]:
        name, _, feats = item.partition("=")
        name = name.strip()
        if name not in LEARNABLE:
            raise ValueError(
                f"--learn {item!r}: the parameter is 'cor', 'mu' or "
                "'tangential_cor' (the rigid law's), e.g. --learn "
                "cor=normal_speed,slip_ratio"
            )
        features = tuple(f.strip() for f in feats.split(",") if f.strip())
        if feats and not features:
            raise ValueError(f"--learn {item!r}: no feature after '='")
        if name in learned:
            raise ValueError(f"--learn: {name!r} is given twice")
        learned[name] = features or DEFAULT_FEATURES
    return learned


def _residual_features(given, data) -> tuple[str, ...]:
    if given is None:
        return tuple(data.inputs)
    features = tuple(f.strip() for f in given.split(",") if f.strip())
    if not features:
        raise ValueError(
            f"--residual-features {given!r}: give comma-separated features, e.g. "
            "orientation,velocity_x,normal_speed"
        )
    return features


def _json_number(x: float):
    """A number for strict JSON: inf (every row failed) as null."""
    return x if x == x and abs(x) != float("inf") else None


def run(args) -> int:
    if not 0.0 < args.holdout < 1.0:
        raise ValueError(f"--holdout must be a fraction in (0, 1), got {args.holdout}")
    if args.out is not None and not args.out.strip():
        raise ValueError("--out is empty: give a folder (or leave --out out)")
    out = args.out or "learn-" + os.path.splitext(os.path.basename(args.data))[0]
    if os.path.exists(out) and not os.path.isdir(out):
        raise ValueError(f"--out {out}: is a file, not a folder")
    learn = _parse_learn(args.learn)
    if args.residual_features is not None and args.no_residual:
        raise ValueError("--residual-features and --no-residual contradict each other")
    files = _OUTPUT_FILES + (() if args.no_residual else (_RESIDUAL_FILE,))
    existing = [f for f in files if os.path.exists(os.path.join(out, f))]
    if existing and not args.force:
        raise ValueError(
            f"--out {out}: {', '.join(existing)} already exist; pass --force to "
            "overwrite them, or choose another --out"
        )

    import numpy as np

    import diffimpact as di

    data = di.load_experiments(args.data)
    declared = di.Experiment.from_file(data)
    if not isinstance(declared.scene, di.scenes.AbstractPlanarScene):
        raise ValueError(
            f"{args.data}: learn needs a planar scene (a body with a contact point "
            f"and its lever); this file's is {type(declared.scene).__name__}"
        )
    # The rigid law: closed form, so training over thousands of rows takes
    # seconds.  A compliant law's parameters are learned from Python
    # (`diffimpact.Hybrid` of any Experiment).
    friction = declared.friction or di.Friction(0.2)
    experiment = di.Experiment(
        declared.scene,
        di.RigidContact(
            0.6,
            args.restitution,
            tangential_cor=0.0 if "tangential_cor" in learn else None,
        ),
        di.Friction(friction.mu),
    )
    constants = ["cor", "mu"]
    learned = {p: di.Learned(f, args.kind, seed=args.seed) for p, f in learn.items()}
    for p in constants:
        learned.setdefault(p, di.Learned())
    physics = {p: di.Learned() for p in learned}
    models = {
        "physics, constant": di.Hybrid(experiment, physics),
        "hybrid": di.Hybrid(experiment, learned),
    }
    if not args.no_residual:
        features = _residual_features(args.residual_features, data)
        outputs = residual_outputs(data.outputs)
        models["hybrid + residual"] = di.Hybrid(
            experiment,
            learned,
            residual=di.Residual(features, outputs, seed=args.seed),
        )
    if not args.no_network:
        models["network"] = di.VelocityNetwork(
            experiment, list(data.inputs), list(data.outputs), seed=args.seed
        )
    n_test = round(args.holdout * data.n)
    if n_test < 1 or data.n - n_test < 2:
        raise ValueError(
            f"--holdout {args.holdout}: leaves {n_test} of {data.n} rows held out "
            "and needs at least 1 held out and 2 to learn from"
        )
    order = np.random.default_rng(args.seed).permutation(data.n)
    test, train = np.sort(order[:n_test]), np.sort(order[n_test:])
    created = writable_folder(out)
    try:
        return _learn_and_write(args, data, experiment, models, train, test, out)
    finally:
        # an interrupted or failed run leaves no empty folder of its making
        if created and os.path.isdir(out) and not os.listdir(out):
            os.rmdir(out)


def residual_outputs(measured) -> tuple[str, ...]:
    """What the residual corrects: the body's velocities after that the
    file measures; in a file that measures none of them (a sphere's
    restitution coefficients, say), what it measures."""
    return tuple(q for q in _VELOCITIES if q in measured) or tuple(measured)


def error_names(quantities) -> tuple[str, str]:
    """``(for learn.json, for the printed table)``: what `diffimpact.train`'s
    per-row error is for these quantities.  Relative in the kinetic norm
    where they are the body's three velocities after; else the RMS of the
    residuals, each in units of its quantity's noise scale
    (`TrainResult.scale`)."""
    quantities = list(quantities)
    if set(quantities) == set(_VELOCITIES):
        kinetic = "median relative error of the velocities after, kinetic norm"
        return kinetic, "relative error"
    return (
        f"median RMS error of {quantities}, each in units of its noise scale "
        "(the file's median sigma, else its spread over the training rows)",
        f"error, RMS of {quantities} in units of their noise",
    )


def _learn_and_write(args, data, experiment, models, train, test, out) -> int:
    import numpy as np

    import diffimpact as di

    results, errors = {}, {}
    for name, model in models.items():
        if name == "hybrid + residual":
            # From the trained hybrid: `train`'s first stage (the parameters,
            # the residual at zero) then starts where that training ended.
            hybrid = results["hybrid"].model
            model = di.Hybrid(hybrid.experiment, hybrid.learned, model.residual)
        print(f"training {name} on {len(train)} rows...", flush=True)
        t0 = time.perf_counter()
        r = di.train(model, data, rows=train, seed=args.seed)
        results[name] = r
        errors[name] = r.errors
        print(
            f"  {r.steps} steps, {time.perf_counter() - t0:.1f} s; held-out median "
            f"error {r.median_error(test):.4f}",
            flush=True,
        )
    what, printed = error_names(next(iter(results.values())).quantities)
    width = max(len(m) for m in models)
    print(f"\nheld-out median {printed} ({len(test)} rows):")
    for name, r in results.items():
        print(f"  {name:<{width}}  {r.median_error(test):.4f}")
    lines = data.lines if data.lines is not None else np.arange(1, data.n + 1)
    held_out = set(test.tolist())
    with open_new(os.path.join(out, "errors.csv"), args.force) as fh:
        w = csv.writer(fh)
        w.writerow(["line", "held_out", *[f"error_{m}" for m in models]])
        for i in range(data.n):
            w.writerow(
                [int(lines[i]), int(i in held_out)]
                + [repr(float(errors[m][i])) for m in models]
            )
    hybrid = results["hybrid"]
    summary = {
        "data": args.data,
        "law": type(experiment.law).__name__,
        "restitution": args.restitution,
        "learned": {
            p: {"features": list(f.features), "kind": f.kind}
            for p, f in hybrid.model.learned.items()
        },
        "residual": None
        if "hybrid + residual" not in results
        else {
            "features": list(results["hybrid + residual"].model.residual.features),
            "outputs": list(results["hybrid + residual"].model.residual.outputs),
        },
        "error": what,
        "held_out_median_error": {
            m: _json_number(r.median_error(test)) for m, r in results.items()
        },
        "training_median_error": {
            m: _json_number(r.median_error(r.train_rows)) for m, r in results.items()
        },
        "failed_rows": {m: len(r.failed) for m, r in results.items()},
        "regularisation": {m: r.regularisation for m, r in results.items()},
        "steps": {m: r.steps for m, r in results.items()},
        "held_out_lines": [int(lines[i]) for i in test],
        "provenance": provenance(args),
    }
    with open_new(os.path.join(out, "learn.json"), args.force) as fh:
        json.dump(summary, fh, indent=2, allow_nan=False)
    path = os.path.join(out, "hybrid.eqx")
    if args.force and os.path.exists(path):
        os.remove(path)
    di.save_model(path, hybrid.model)
    written = list(_OUTPUT_FILES)
    if "hybrid + residual" in results:
        path = os.path.join(out, _RESIDUAL_FILE)
        if args.force and os.path.exists(path):
            os.remove(path)
        di.save_model(path, results["hybrid + residual"].model)
        written.append(_RESIDUAL_FILE)
    print(f"wrote {out}/: {', '.join(written)}")
    return 0
