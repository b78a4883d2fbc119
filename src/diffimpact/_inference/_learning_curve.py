"""Data efficiency: held-out error against the number of training rows, for
several models trained on the same splits (`learning_curve`), and saving
and loading trained models."""

from __future__ import annotations

import dataclasses
import json
import pathlib

import equinox as eqx
import jax
import numpy as np

from .._io._data import ExperimentData, load_experiments
from ._learned import Hybrid
from ._network import VelocityNetwork
from ._train import train


@dataclasses.dataclass(frozen=True)
class LearningCurve:
    """What `learning_curve` found.

    - `sizes`: training rows per point (validation included);
    - `errors`: model name -> median held-out relative error, shape
      ``(len(sizes), len(seeds))``;
    - `seeds`, `test_rows` (seed -> the held-out rows), `seconds`
      (model -> training time per point, compilation included).
    """

    sizes: tuple[int, ...]
    seeds: tuple[int, ...]
    errors: dict[str, np.ndarray]
    test_rows: dict[int, np.ndarray]
    seconds: dict[str, np.ndarray]

    def table(self) -> str:
        """Mean over seeds of the median held-out error, one row per model."""
        w = max(len(m) for m in self.errors)
        head = f"{'training rows':<{w}}  " + "  ".join(f"{n:>7d}" for n in self.sizes)
        rows = [head]
        for m, e in self.errors.items():
            rows.append(
                f"{m:<{w}}  " + "  ".join(f"{x:>7.4f}" for x in np.mean(e, axis=1))
            )
        return "\n".join(rows)

    def plot(self, path=None, floor: float | None = None):
        """Held-out median error against training rows (mean over seeds,
        the band their range); ``floor``: a noise floor to draw."""
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(5.5, 4))
        for m, e in self.errors.items():
            ax.plot(self.sizes, np.mean(e, axis=1), "o-", label=m)
            ax.fill_between(self.sizes, e.min(axis=1), e.max(axis=1), alpha=0.2)
        if floor is not None:
            ax.axhline(floor, color="k", ls=":", lw=1, label="noise floor")
        ax.set_xscale("log")
        ax.set_xlabel("training rows")
        ax.set_ylabel("held-out median relative error")
        ax.legend(fontsize=8)
        fig.tight_layout()
        if path is not None:
            fig.savefig(path, dpi=120)
        return fig


def learning_curve(
    data,
    models: dict,
    *,
    sizes=(50, 100, 200, 500, None),
    seeds=(0, 1, 2),
    test_fraction: float = 0.3,
    **train_options,
) -> LearningCurve:
    """Train every model of ``models`` (name -> `Hybrid` or `VelocityNetwork`)
    on growing subsets of the same rows and judge it on the same held-out
    rows.

    Per seed, a `test_fraction` of the rows is held out, the rest shuffled;
    the first ``size`` of them (None: all) are the training rows of each
    point, every model getting the same ones.  `train_options` go to
    `train` (its validation split is taken from the training rows).
    """
    data = data if isinstance(data, ExperimentData) else load_experiments(data)
    if not models:
        raise ValueError("learning_curve: give at least one model")
    if not 0.0 < test_fraction < 1.0:
        raise ValueError(f"test_fraction must lie in (0, 1), got {test_fraction}")
    n_test = int(round(test_fraction * data.n))
    pool = data.n - n_test
    sizes = tuple(pool if s is None else int(s) for s in sizes)
    bad = [s for s in sizes if not 2 <= s <= pool]
    if bad:
        raise ValueError(
            f"sizes {bad}: each must lie in [2, {pool}] (the rows left after "
            f"holding out {n_test} of {data.n})"
        )
    seeds = tuple(int(s) for s in seeds)
    errors = {m: np.zeros((len(sizes), len(seeds))) for m in models}
    seconds = {m: np.zeros((len(sizes), len(seeds))) for m in models}
    test_rows = {}
    for j, seed in enumerate(seeds):
        order = np.random.default_rng(seed).permutation(data.n)
        test, rest = np.sort(order[:n_test]), order[n_test:]
        test_rows[seed] = test
        for i, size in enumerate(sizes):
            for name, model in models.items():
                r = train(
                    model, data, rows=np.sort(rest[:size]), seed=seed, **train_options
                )
                errors[name][i, j] = r.median_error(test)
                seconds[name][i, j] = r.seconds
    return LearningCurve(sizes, seeds, errors, test_rows, seconds)


_FORMAT = "diffimpact-model-1"


def _describe(model) -> dict:
    """The structure a saved model must match to be loaded into: its type,
    per learned parameter its features, kind and domain, and the whole
    tree's structure (every static field: a restitution law, a method, the
    solver settings) with each array's shape and dtype; the numbers are the
    file's."""
    leaves, treedef = jax.tree.flatten(eqx.filter(model, eqx.is_array))
    structure = {
        "tree": str(treedef),
        "arrays": [f"{x.dtype}{list(x.shape)}" for x in leaves],
    }
    return {**_summary(model), "structure": structure}


def _summary(model) -> dict:
    if isinstance(model, VelocityNetwork):
        return {
            "type": "VelocityNetwork",
            "inputs": list(model.inputs),
            "outputs": list(model.outputs),
            "widths": [int(layer.weight.shape[0]) for layer in model.mlp.layers],
        }
    if isinstance(model, Hybrid):
        return {
            "type": "Hybrid",
            "scene": type(model.experiment.scene).__name__,
            "law": type(model.experiment.law).__name__,
            "learned": {
                p: {"features": list(f.features), "kind": f.kind, "domain": f.domain}
                for p, f in model.learned.items()
            },
            **(
                {}
                if model.residual is None
                else {
                    "residual": {
                        "features": list(model.residual.features),
                        "outputs": list(model.residual.outputs),
                        "kind": model.residual.kind,
                    }
                }
            ),
        }
    raise TypeError(
        f"expected a diffimpact.Hybrid or VelocityNetwork, got {type(model).__name__}"
    )


def save_model(path, model, *, overwrite: bool = False) -> pathlib.Path:
    """Write a trained `Hybrid` or `VelocityNetwork` to ``path``: a JSON line
    describing its structure, then its numbers
    (`equinox.tree_serialise_leaves`; its experiment's numbers, scene and
    law, with them).  An existing file is refused unless `overwrite`."""
    header = json.dumps({"format": _FORMAT, **_describe(model)})
    path = pathlib.Path(path)
    try:
        f = open(path, "wb" if overwrite else "xb")
    except FileExistsError:
        raise ValueError(
            f"{path} already exists; save_model does not replace a file unless "
            "overwrite=True"
        ) from None
    with f:
        f.write(header.encode() + b"\n")
        eqx.tree_serialise_leaves(f, model)
    return path


def load_model(path, like):
    """Read a model saved by `save_model` into the structure of ``like`` (a
    model built the same way: the same experiment type, learned
    parameters, features and kinds, or the same network); a file of another
    structure is a ValueError saying what differs."""
    path = pathlib.Path(path)
    with open(path, "rb") as f:
        line = f.readline()
        try:
            header = json.loads(line)
        except ValueError:
            header = None
        if not isinstance(header, dict) or header.get("format") != _FORMAT:
            raise ValueError(f"{path}: not a model saved by diffimpact.save_model")
        header.pop("format")
        expected = _describe(like)
        if header != expected:
            keys = set(expected) | set(header)
            diff = sorted(k for k in keys if header.get(k) != expected.get(k))
            shown = [k for k in diff if k != "structure"]
            if shown:
                saved = {k: header.get(k) for k in shown}
                want = {k: expected.get(k) for k in shown}
                detail = f": saved {saved}, like {want}"
            else:
                detail = (
                    " (a static field such as the restitution law, the method "
                    "or the solver settings, or an array's shape: build `like` "
                    "as the saved model was built)"
                )
            raise ValueError(
                f"{path}: the saved model's structure differs from `like` in "
                f"{diff}{detail}"
            )
        return eqx.tree_deserialise_leaves(f, like)
