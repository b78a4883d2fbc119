"""``diffimpact fit``: identify parameters from an experiment CSV.

    diffimpact fit DATA.csv --free mu,yield_strength [--scene NAME] [--out DIR]

prints the estimates with standard errors and correlations (a progress bar
while it works) and writes, into DIR: ``fit.json`` (parameters, covariance,
statistics), ``residuals.csv`` (one line per row: its inputs, and measured,
predicted, sigma and weighted residual per output, every column's unit in its
name and in the file's units), ``fit.png`` (measured vs predicted, residuals)
and ``loop.png`` (normal force against interference for the median row).
Nothing in DIR is overwritten without ``--force``; the check happens before
the fit starts.
While it iterates, ``fit_progress.json`` in DIR holds the last accepted
iterate; an interrupted fit restarts from it with the same command and
``--resume``, and a finished one removes it.
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys

from .._io._data import parse_number
from ._files import integer, number, open_new, writable_folder
from ._outputs import (
    plot_fit,
    plot_loop,
    provenance,
    save_figure,
    write_residuals,
    write_table,
)

_OUTPUT_FILES = ("fit.json", "residuals.csv", "fit.png", "loop.png")
# the last accepted iterate, while the fit runs (`diffimpact.fit`'s checkpoint)
_PROGRESS = "fit_progress.json"
_HOLDOUT_FILES = ("holdout.csv", "holdout.png")
_POSTERIOR_FILES = ("posterior.csv", "posterior.json", "corner.png", "predictive.png")
_LAWS = {"jackson-green": "JacksonGreen", "hertz": "Hertz"}
_METHODS = ("auto", "smooth", "events", "quadrature", "contact_space")


# `--compliant [MODEL]`: the models (`Friction.compliant`'s, named here so
# that the parser does not import the library).
_COMPLIANCE = ("mindlin", "mindlin-deresiewicz")


def bare_compliant(argv: list[str]) -> list[str]:
    """``--compliant`` without a model, written before the data file (``fit
    --compliant data.csv``), as ``--compliant=mindlin``: argparse would take
    the file for the flag's optional value.  A word that is neither a model
    nor a file (``--compliant partial``) is left to argparse, which names the
    models."""
    out = list(argv)
    for i, token in enumerate(out[:-1]):
        nxt = out[i + 1]
        path_like = os.path.exists(nxt) or "." in nxt or os.sep in nxt
        if token == "--compliant" and nxt not in _COMPLIANCE and path_like:
            out[i] = "--compliant=mindlin"
    return out


def register(sub) -> None:
    p = sub.add_parser(
        "fit",
        help="fit parameters to an experiment CSV",
        description=__doc__.split("\n\n")[0].replace("``", ""),
    )
    p.add_argument("data", help="experiment CSV (schema: docs/data-formats.md)")
    p.add_argument(
        "--free",
        required=True,
        help="comma-separated parameters to fit, e.g. mu,yield_strength",
    )
    p.add_argument(
        "--scene", default=None, help="scene name if the file has no 'scene' column"
    )
    p.add_argument(
        "--law",
        choices=sorted(_LAWS),
        default="jackson-green",
        help="normal contact law (default jackson-green)",
    )
    p.add_argument(
        "--compliant",
        nargs="?",
        const="mindlin",
        default=None,
        choices=_COMPLIANCE,
        help="tangential compliance at the contact: 'mindlin' (the default "
        "with the bare flag; Mindlin's spring, no micro-slip) or "
        "'mindlin-deresiewicz' (partial slip); Friction(compliant=...)",
    )
    p.add_argument(
        "--method",
        choices=_METHODS,
        default="auto",
        help="simulate's method (default auto); contact_space: a rigid planar "
        "body, bar or link with Hertz or Jackson-Green contact and rigid "
        "Coulomb friction, solved without an ODE (the geometry frozen at first "
        "contact: 1e-4 to 1e-2 from the planar ODE), for files of thousands of "
        "rows",
    )
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="fix a parameter to a value (SI), e.g. youngs_modulus=210e9",
    )
    p.add_argument(
        "--start",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="start value of a free parameter (SI; default: the scene's own)",
    )
    p.add_argument(
        "--bounds",
        action="append",
        default=[],
        metavar="NAME=LO:HI",
        help="bounds of a free parameter (default 0:inf)",
    )
    p.add_argument(
        "--solver",
        choices=("levenberg-marquardt", "gauss-newton", "adam", "lbfgs"),
        default="levenberg-marquardt",
        help="optimiser (default levenberg-marquardt)",
    )
    p.add_argument(
        "--max-steps",
        type=integer,
        default=100,
        help="most optimiser steps (default 100)",
    )
    p.add_argument(
        "--solver-steps",
        type=integer,
        default=None,
        metavar="N",
        help="step budget of each impact's ODE solve (SolverSettings.max_steps; "
        "default 16384): raise it for rows whose solves run out of steps",
    )
    p.add_argument(
        "--holdout",
        type=number,
        default=None,
        metavar="FRACTION",
        help="hold out this fraction of the rows, fit on the rest, and compare "
        "the held-out errors of the model and of the rigid laws",
    )
    p.add_argument(
        "--posterior",
        action="store_true",
        help="also sample the posterior of the free parameters (NUTS)",
    )
    p.add_argument(
        "--samples",
        type=integer,
        default=None,
        help="draws per chain kept (with --posterior; default 1000)",
    )
    p.add_argument(
        "--warmup",
        type=integer,
        default=None,
        help="warm-up steps per chain (with --posterior; default 1000)",
    )
    p.add_argument(
        "--chains",
        type=integer,
        default=None,
        help="chains, run together (with --posterior; default 4)",
    )
    p.add_argument(
        "--prior",
        action="append",
        default=[],
        metavar="NAME=KIND:A:B",
        help="prior of a free parameter (with --posterior), e.g. mu=uniform:0:1, "
        "yield_strength=lognormal:4e8:0.5; kinds: normal:MEAN:SD, "
        "lognormal:MEDIAN:SIGMA, uniform:LOWER:UPPER, loguniform:LOWER:UPPER "
        "(default: lognormal about the start value, sigma 1; uniform between "
        "finite bounds)",
    )
    p.add_argument(
        "--seed",
        type=integer,
        default=None,
        help="draw of the held-out rows (--holdout) or of the chains "
        "(--posterior); default 0",
    )
    p.add_argument("--out", default=None, help="output folder (default fit-<data>)")
    p.add_argument("--force", action="store_true", help="overwrite outputs in --out")
    p.add_argument(
        "--resume",
        action="store_true",
        help=f"restart an interrupted fit from the last accepted iterate in "
        f"--out ({_PROGRESS}; the same command, with --resume)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _pairs(items, what):
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise ValueError(f"--{what} expects NAME=VALUE, got {item!r}")
        out[name.strip()] = value.strip()
    return out


# The chains' random keys take a seed of at most 32 bits.
_SEED_MAX = 2**32 - 1


def _number(text, what):
    try:
        return parse_number(text)
    except ValueError:
        raise ValueError(f"--{what}: {text!r} is not a number") from None


def run(args) -> int:
    if args.out is not None and not args.out.strip():
        raise ValueError("--out is empty: give a folder (or leave --out out)")
    out = args.out or "fit-" + os.path.splitext(os.path.basename(args.data))[0]
    if os.path.exists(out) and not os.path.isdir(out):
        raise ValueError(
            f"--out {out}: is a file, not a folder; give a folder for "
            f"{', '.join(_OUTPUT_FILES)}"
        )
    if args.max_steps < 1:
        raise ValueError(f"--max-steps must be an integer >= 1, got {args.max_steps}")
    if args.solver_steps is not None and args.solver_steps < 1:
        raise ValueError(
            f"--solver-steps must be an integer >= 1, got {args.solver_steps}"
        )
    if args.seed is not None and args.holdout is None and not args.posterior:
        raise ValueError(
            "--seed draws the held-out rows or the chains: give it with --holdout "
            "or --posterior"
        )
    if args.holdout is not None and not 0.0 < args.holdout < 1.0:
        raise ValueError(f"--holdout must be a fraction in (0, 1), got {args.holdout}")
    _check_posterior_options(args)
    if args.resume and args.force:
        raise ValueError(
            "--resume restarts the fit in --out from its progress, --force starts "
            "it again: give one"
        )
    if args.resume and args.holdout is not None:
        raise ValueError(
            "--resume restarts a fit (with or without --posterior), not the "
            "fits of --holdout"
        )
    files = _files(args)
    existing = [f for f in files if os.path.exists(os.path.join(out, f))]
    if existing and not args.force:
        raise ValueError(
            f"{out}: would overwrite {', '.join(existing)}; pass --force or choose "
            "another --out"
        )
    progress = os.path.join(out, _PROGRESS)
    if os.path.exists(progress) and not (args.resume or args.force):
        raise ValueError(
            f"{progress} holds the progress of an interrupted fit: pass --resume "
            "to restart from it, or --force to start again"
        )
    # the folder exists and can be written, before minutes of fitting
    created = writable_folder(out)
    if args.force and os.path.exists(progress):
        os.remove(progress)
    try:
        return _fit_and_write(args, out)
    except KeyboardInterrupt:
        if os.path.exists(progress):
            with open(progress) as fh:
                saved = json.load(fh)
            print(
                f"\nthe last accepted iterate (iteration {saved['iteration']}, cost "
                f"{saved['cost']:.6g}) is in {progress}: the same command with "
                "--resume restarts from it",
                file=sys.stderr,
            )
        raise
    finally:
        # a failed or interrupted fit leaves no empty folder of its own making
        if created and os.path.isdir(out) and not os.listdir(out):
            os.rmdir(out)


def _fit_and_write(args, out) -> int:
    import equinox as eqx

    import diffimpact as di
    from diffimpact._inference._experiment import set_parameters
    from diffimpact._inference._scenes import scene_spec
    from diffimpact.scenes import PlanarBody

    data = di.load_experiments(args.data)
    declared = data.declarations is not None
    scene = args.scene or data.scene or ("planar_body" if declared else None)
    if scene is None:
        raise ValueError(f"{args.data}: no 'scene' column; pass --scene")
    spec = scene_spec(scene)
    scene = spec.name  # as the registry spells it ('Planar-Body' is planar_body)
    if declared and spec.cls is not PlanarBody:
        raise ValueError(
            f"--scene {args.scene}: {data.declarations.where(args.data)} declare "
            "a planar body; leave --scene out (or give planar_body)"
        )
    if declared:  # the body the file declares
        experiment = di.Experiment.from_file(data)
    else:
        experiment = di.Experiment(**spec.default())
    if args.law != "jackson-green":
        experiment = experiment.__class__(
            experiment.scene,
            getattr(di, _LAWS[args.law])(),
            experiment.friction,
            experiment.method,
            experiment.settings,
        )
    if args.method != "auto":
        experiment = dataclasses.replace(experiment, method=args.method)
    if args.solver_steps is not None:
        experiment = dataclasses.replace(
            experiment,
            settings=dataclasses.replace(
                experiment.settings, max_steps=args.solver_steps
            ),
        )
    if args.compliant:
        friction = experiment.friction
        if friction is None:
            raise ValueError(f"--compliant: the {scene} scene has no friction")
        experiment = eqx.tree_at(
            lambda e: e.friction,
            experiment,
            di.Friction(friction.mu, friction.mu_v, compliant=args.compliant),
        )
    fixed = {k: _number(v, "set") for k, v in _pairs(args.set, "set").items()}
    free = [f.strip() for f in args.free.split(",") if f.strip()]
    both = sorted(set(free) & set(fixed))
    if both:
        raise ValueError(
            f"{', '.join(both)}: given both as --free and as --set; a parameter is "
            "either fitted (use --start for its start value) or fixed"
        )
    experiment = set_parameters(experiment, fixed)
    start = {k: _number(v, "start") for k, v in _pairs(args.start, "start").items()}
    bounds = {}
    for k, v in _pairs(args.bounds, "bounds").items():
        lo, sep, hi = v.partition(":")
        if not sep:
            raise ValueError(f"--bounds expects NAME=LO:HI, got {k}={v}")
        bounds[k] = (_number(lo, "bounds"), _number(hi, "bounds"))
    options = dict(solver=args.solver, max_steps=args.max_steps)
    if args.posterior:  # priors against bounds and starts, before any fit
        from diffimpact._inference._posterior import plan

        plan(data, experiment, free, _pairs(args.prior, "prior"), start, bounds)
    if args.holdout is not None:
        result = _cross_validate(
            args, data, experiment, free, dict(start=start, bounds=bounds), out
        )
    else:
        progress = os.path.join(out, _PROGRESS)
        if args.resume and os.path.exists(progress):
            with open(progress) as fh:
                saved = json.load(fh)
            print(
                f"restarting from {progress}: iteration {saved['iteration']}, "
                f"cost {saved['cost']:.6g}"
            )
        elif args.resume:
            print(f"(no {progress}: the fit starts from the start values)")
        print(f"fitting {args.free} to {data.n} rows of {args.data} ({scene})")
        result = di.fit(
            data,
            experiment,
            args.free,
            start=start,
            bounds=bounds,
            progress=not args.no_progress,
            checkpoint=progress,
            resume=args.resume,
            **options,
        )
    print(result.summary())
    with open_new(os.path.join(out, "fit.json"), args.force) as fh:
        json.dump(
            {
                "data": os.path.abspath(args.data),
                "scene": scene,
                **result.to_dict(),
                "provenance": provenance(args),
            },
            fh,
            indent=2,
            allow_nan=False,  # strict JSON: to_dict writes null for inf
        )
    # fit.json holds the result now: the progress is spent
    if os.path.exists(os.path.join(out, _PROGRESS)):
        os.remove(os.path.join(out, _PROGRESS))
    write_residuals(result, os.path.join(out, "residuals.csv"), args.force)
    if not args.no_progress:  # a few seconds of matplotlib and a solve
        print("writing fit.png and loop.png...", file=sys.stderr, flush=True)
    plot_fit(result, os.path.join(out, "fit.png"), args.force)
    note = plot_loop(result, os.path.join(out, "loop.png"), args.force)
    if args.posterior:
        _posterior(args, data, experiment, free, start, bounds, out, result)
    # no empty plot: a scene that keeps no force history gets no loop.png
    files = tuple(f for f in _files(args) if f != "loop.png" or not note)
    print(f"wrote {out}/: {', '.join(files)}" + (f" ({note})" if note else ""))
    # --force: an earlier run's files of another kind (holdout.csv of a run
    # with --holdout, say) would sit beside these as if they belonged to them
    every = _OUTPUT_FILES + _HOLDOUT_FILES + _POSTERIOR_FILES
    stale = [
        f for f in every if f not in files and os.path.isfile(os.path.join(out, f))
    ]
    if stale and args.force:
        for f in stale:
            os.remove(os.path.join(out, f))
        print(f"removed {', '.join(stale)}: an earlier run's, not this one's (--force)")
    elif stale:
        print(
            f"note: {', '.join(stale)} in {out}/ are an earlier run's, not this one's"
        )
    return 0


def _files(args) -> tuple[str, ...]:
    return (
        _OUTPUT_FILES
        + (_HOLDOUT_FILES if args.holdout is not None else ())
        + (_POSTERIOR_FILES if args.posterior else ())
    )


def _check_posterior_options(args) -> None:
    """Sampler options without --posterior, or out of range: named before
    anything is fitted."""
    given = [
        f"--{n}"
        for n in ("samples", "warmup", "chains")
        if getattr(args, n) is not None
    ] + (["--prior"] if args.prior else [])
    if given and not args.posterior:
        raise ValueError(f"{', '.join(given)}: give with --posterior")
    if args.posterior and args.holdout is not None:
        raise ValueError(
            "--posterior and --holdout: choose one (the posterior of a held-out "
            "fit is not what either measures)"
        )
    for name, low in (("samples", 20), ("warmup", 20), ("chains", 1)):
        v = getattr(args, name)
        if v is not None and v < low:
            raise ValueError(f"--{name} must be an integer >= {low}, got {v}")
    if args.seed is not None and not 0 <= args.seed <= _SEED_MAX:
        raise ValueError(
            f"--seed must be an integer in [0, {_SEED_MAX}], got {args.seed}"
        )
    from diffimpact._inference._priors import parse_prior

    free = {f.strip() for f in args.free.split(",") if f.strip()}
    for name, text in _pairs(args.prior, "prior").items():
        if name not in free:
            raise ValueError(
                f"--prior {name}=...: {name!r} is not free (--free {args.free})"
            )
        parse_prior(text)


def _posterior(args, data, experiment, free, start, bounds, out, fitted) -> None:
    """``--posterior``: NUTS from the least-squares fit, four more files."""
    import diffimpact as di

    options = {
        k: getattr(args, a)
        for k, a in (
            ("num_samples", "samples"),
            ("num_warmup", "warmup"),
            ("num_chains", "chains"),
            ("seed", "seed"),
        )
        if getattr(args, a) is not None
    }
    print(
        f"sampling the posterior of {args.free} ({options.get('num_chains', 4)} chains)"
    )
    post = di.posterior(
        data,
        experiment,
        free,
        priors=_pairs(args.prior, "prior"),
        start=start,
        bounds=bounds,
        progress=not args.no_progress,
        least_squares=fitted,
        **options,
    )
    print(post.summary())
    post.save(os.path.join(out, "posterior.csv"), args.force)
    with open_new(os.path.join(out, "posterior.json"), args.force) as fh:
        json.dump(
            {
                "data": os.path.abspath(args.data),
                **post.to_dict(),
                "provenance": provenance(args),
            },
            fh,
            indent=2,
            allow_nan=False,
        )
    save_figure(post.plot_corner(), os.path.join(out, "corner.png"), args.force)
    save_figure(post.plot_predictive(), os.path.join(out, "predictive.png"), args.force)


def _cross_validate(args, data, experiment, free, own_options, out):
    """``--holdout``: the model and, for a planar scene with Coulomb friction,
    the three rigid laws (`RigidContact`, fitting ``mu`` where the model
    does, and ``cor``), fitted on the same rows and judged on the rest.
    Returns the model's own fit (on the training rows)."""
    import diffimpact as di
    from diffimpact.scenes import AbstractPlanarScene

    models, free_of = {args.law: experiment}, {args.law: free}
    friction = experiment.friction
    if isinstance(experiment.scene, AbstractPlanarScene) and friction is not None:
        for law in di.RESTITUTION_LAWS:
            models[law] = di.Experiment(
                experiment.scene, di.RigidContact(0.5, law), di.Friction(friction.mu)
            )
            free_of[law] = [n for n in free if n == "mu"] + ["cor"]
    else:
        print("(no rigid baselines: they need a planar scene with friction)")
    n_test = round(args.holdout * data.n)
    print(
        f"fitting {len(models)} models to {data.n - n_test} rows of {args.data}, "
        f"holding out {n_test} (seed {args.seed or 0})"
    )
    cv = di.cross_validate(
        data,
        models,
        free_of,
        holdout=args.holdout,
        seed=args.seed or 0,
        model_options={args.law: own_options},
        solver=args.solver,
        max_steps=args.max_steps,
        progress=not args.no_progress,  # each model's fit shows its bar
    )
    print("held-out RMS error (SI units):")
    print(cv.table())
    write_table(cv.per_row(), os.path.join(out, "holdout.csv"), args.force)
    fig = cv.plot()
    save_figure(fig, os.path.join(out, "holdout.png"), args.force)
    return cv.fits[args.law]
