"""Checkpoints of the restoration network: weights, how to rebuild the model,
optimiser state for resuming, and the metadata an export needs.

A checkpoint is one ``torch.save`` file holding plain data only (tensors,
numbers, strings, lists, dicts), so it loads with ``weights_only=True``:

==================  ==========================================================
key                 meaning
==================  ==========================================================
``format``          ``"isp-restoration-checkpoint/v1"``
``variant``         registered model name (:func:`restoration.nn.network.build_model`)
``model_kwargs``    its overrides; ``build_model(variant, **model_kwargs)``
                    rebuilds the architecture
``state_dict``      the weights (and buffers)
``optimizer``       optimiser state (None when not saved)
``step, epoch``     training progress (``epoch`` a float: pairs seen / pairs)
``config``          the training configuration (:mod:`restoration.train.trainer`)
``metadata``        what the model is for; the training writes ``lens``,
                    ``fov_encoding`` (``"xy"``/``"none"``), ``placement``
                    (``"camera_rgb after demosaic"``), ``domain``
                    (``"camera_rgb"``), ``training_data`` (the ``isp synth``
                    manifest's ``data_sha256``; several sets comma-joined),
                    ``input_multiple``, ``receptive_radius``, ``attention``,
                    ``process`` (the luminance stage's ``tone``, ``white``),
                    ``val_psnr_db``, ``training_sets`` (per set: data hash,
                    seed, size, the manifest's ``lens`` with each lens's
                    ``psf_map_key``, ``psf_map``, ``settings``)
``torch``           torch version that wrote it
==================  ==========================================================

Writes are atomic (a temporary file beside the target, then a rename), so
an interrupted save never leaves a truncated checkpoint.

>>> import tempfile
>>> from pathlib import Path
>>> from restoration.nn.network import build_model
>>> m = build_model("doconv", depths=(1, 1, 1))
>>> path = save_checkpoint(Path(tempfile.mkdtemp()) / "m.pt", m, variant="doconv",
...                        model_kwargs={"depths": [1, 1, 1]})
>>> model, info = load_model(path)
>>> info["variant"], model.training
('doconv', False)
"""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import torch

from isp.errors import ConfigError, InputError
from isp.io.files import atomic_path

__all__ = ["FORMAT", "load_checkpoint", "load_model", "save_checkpoint"]

FORMAT = "isp-restoration-checkpoint/v1"


def _plain(value, what: str):
    """``value`` as JSON-plain data (numpy scalars and tuples converted), so
    the checkpoint stays loadable with ``weights_only=True``."""
    def default(v):
        if hasattr(v, "tolist"):
            return v.tolist()
        if isinstance(v, Path):
            return str(v)
        raise TypeError(f"{what}: {type(v).__name__} is not plain data")

    return json.loads(json.dumps(value, default=default)) if value is not None else None


def save_checkpoint(path, model, *, variant: str, model_kwargs: dict, optimizer=None, step: int = 0,
                    epoch: float = 0, config: dict | None = None, metadata: dict | None = None) -> Path:
    """Write a checkpoint (atomically).

    Parameters
    ----------
    path : path
        Target file (parent folders are created).
    model : torch.nn.Module
        Built by ``build_model(variant, **model_kwargs)``.
    variant : str
    model_kwargs : dict
        JSON-plain overrides of the variant.
    optimizer : torch.optim.Optimizer, optional
        Its state is saved for resuming.
    step, epoch : int, float
        Training progress.
    config : dict, optional
        The training configuration.
    metadata : dict, optional
        See the module table.

    Returns
    -------
    Path of the written file.
    """
    ckpt = {
        "format": FORMAT,
        "variant": str(variant),
        "model_kwargs": _plain(dict(model_kwargs), "model_kwargs"),
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        "optimizer": None if optimizer is None else optimizer.state_dict(),
        "step": int(step),
        "epoch": float(epoch),
        "config": _plain(config, "config"),
        "metadata": _plain(metadata or {}, "metadata"),
        "torch": str(torch.__version__),
    }
    with atomic_path(path) as tmp:
        torch.save(ckpt, tmp)
    return Path(path)


def load_checkpoint(path, map_location="cpu") -> dict:
    """The raw checkpoint dict (module table), e.g. to resume training.

    Raises
    ------
    InputError
        Missing file, not a checkpoint, or another format.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(p, "no such checkpoint")
    try:
        ckpt = torch.load(p, map_location=map_location, weights_only=True)
    except (pickle.UnpicklingError, RuntimeError, EOFError, OSError, ValueError) as e:  # what a bad file raises
        why = "not a torch.save file of plain data" if isinstance(e, pickle.UnpicklingError) else str(e).splitlines()[0]
        raise InputError(p, f"not a readable checkpoint ({type(e).__name__}: {why})") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        got = ckpt.get("format") if isinstance(ckpt, dict) else type(ckpt).__name__
        raise InputError(p, f"checkpoint format {got!r}, expected {FORMAT!r}")
    return ckpt


def load_model(path, map_location="cpu"):
    """Rebuild the model of a checkpoint and load its weights.

    Returns
    -------
    model : torch.nn.Module
        In eval mode, attention temperature 1, on ``map_location``.
    info : dict
        The checkpoint without ``state_dict`` and ``optimizer``: ``variant``,
        ``model_kwargs``, ``step``, ``epoch``, ``config``, ``metadata``, ...

    Raises
    ------
    InputError
        Unreadable checkpoint, or weights that do not fit the rebuilt model.
    """
    from restoration.nn.doconv import set_temperature
    from restoration.nn.network import build_model

    ckpt = load_checkpoint(path, map_location=map_location)
    try:
        model = build_model(ckpt["variant"], **ckpt["model_kwargs"])
    except ConfigError as e:
        raise InputError(path, f"cannot rebuild the model: {e}") from None
    try:
        model.load_state_dict(ckpt["state_dict"])
    except RuntimeError as e:
        raise InputError(path, f"weights do not fit model {ckpt['variant']!r}: {str(e).splitlines()[0]}") from None
    set_temperature(model, 1.0)
    model.to(map_location if isinstance(map_location, (str, torch.device)) else "cpu").eval()
    info = {k: v for k, v in ckpt.items() if k not in ("state_dict", "optimizer")}
    return model, info
