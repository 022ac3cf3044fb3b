"""The device a simulation runs through: a lens as it was built.

:func:`device_lens` turns a lens and a perturbation spec into that device:
the nominal lens, the fitted perturbation of a proxy lens file, a random
device drawn within the default tolerances (and refocused: assembly sets
focus, so a drawn device is not left defocused), or the perturbation of a
``{name: value}`` JSON file (names as :mod:`calibration.optics.perturb`
spells them, e.g. ``{"e1.decenter_x": 0.003}``). :func:`draw_lenses` draws
many devices around a lens, as data synthesis and descriptor bases need.

Imports :mod:`calibration.optics` (perturb, spot) and ``isp`` errors.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from calibration.optics.lens import Lens
from calibration.optics.perturb import ParameterSpace, Perturbation, PerturbedLens, apply
from calibration.optics.spot import refocus
from isp.errors import InputError

__all__ = ["device_lens", "draw_lenses"]


def device_lens(lens: Lens, perturb: str | None = None, seed: int = 0) -> tuple[Lens | PerturbedLens, str]:
    """A device of ``lens``, and a few words saying which.

    Parameters
    ----------
    lens : Lens
        The prescription (a proxy lens file's lens carries its fitted
        perturbation in ``metadata["perturbation"]``).
    perturb : str, optional
        None or ``"none"``: the nominal lens (or a proxy lens file's fitted
        perturbation, when ``perturb`` is None); ``"random"``: a device
        drawn within the default tolerances
        (:meth:`calibration.optics.perturb.ParameterSpace.default`) and
        refocused (:func:`calibration.optics.spot.refocus`); else the path
        of a JSON file of ``{name: value}``.
    seed : int
        Seed of the random draw.

    Returns
    -------
    device : Lens or PerturbedLens
    description : str
        E.g. ``"nominal"``, ``"random device within tolerance, refocused (seed 3)"``.

    Raises
    ------
    InputError
        The JSON file is unreadable, not JSON, or names an unknown
        perturbation.
    """
    if not perturb and lens.metadata.get("perturbation"):  # a proxy lens file
        return apply(lens, Perturbation.from_dict(lens.metadata["perturbation"])), "proxy (fitted perturbation)"
    if not perturb or perturb == "none":
        return lens, "nominal"
    if perturb == "random":
        space = ParameterSpace.default(lens)
        rng = np.random.default_rng(seed)
        p = space.to_perturbation(space.sample(rng, 1)[0])
        return refocus(apply(lens, p)), f"random device within tolerance, refocused (seed {seed})"
    path = Path(perturb)
    try:
        values = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise InputError(perturb, f"not a perturbation JSON file ({e})") from None
    try:
        return apply(lens, Perturbation.from_dict(values)), f"perturbation from {perturb}"
    except ValueError as e:
        raise InputError(perturb, str(e)) from None


def draw_lenses(lens, samples: int, rng: np.random.Generator, *, tolerance_scale: float = 1.0,
                refocus: bool = True) -> list:
    """The proxy lens and ``samples − 1`` lenses drawn within tolerance.

    Parameters
    ----------
    lens : PerturbedLens
        The proxy camera's lens (its perturbation is kept in every draw).
    samples : int
        ≥ 1.
    rng : numpy Generator
    tolerance_scale : float
        Multiplies every tolerance (0: the proxy repeated).
    refocus : bool
        Re-set focus per draw relative to the proxy (module notes).

    Returns
    -------
    list of PerturbedLens, the proxy first.
    """
    from calibration.optics.spot import best_focus

    if int(samples) < 1:
        raise ValueError(f"samples must be ≥ 1, got {samples!r}")
    if not (math.isfinite(tolerance_scale) and tolerance_scale >= 0):
        raise ValueError(f"tolerance_scale must be ≥ 0, got {tolerance_scale!r}")
    out = [lens]
    if samples == 1:
        return out
    space = ParameterSpace.default(lens.nominal)
    deltas = space.sample(rng, int(samples) - 1) * float(tolerance_scale)
    base = lens.perturbation.as_dict()
    focus_ref = best_focus(lens) if refocus else 0.0
    last = f"s{len(lens.surfaces)}.thickness"
    for d in deltas:
        pert = dict(base)
        for name, v in zip(space.names, d):
            pert[name] = pert.get(name, 0.0) + float(v)
        drawn = apply(lens.nominal, Perturbation.from_dict(pert))
        if refocus:
            pert[last] = pert.get(last, 0.0) + (best_focus(drawn) - focus_ref)
            drawn = apply(lens.nominal, Perturbation.from_dict(pert))
        out.append(drawn)
    return out
