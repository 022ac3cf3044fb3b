"""The configuration of ``isp train``: sections of typed keys, read from TOML
or JSON, every key checked (an unknown key names the valid ones).

Every key, its default and meaning are documented in :mod:`restoration.train.trainer`
(a test keeps that table and :data:`SECTIONS` in step). Numpy only: the
command line reads and checks a config without importing torch.

Paths: relative to the current folder; a path starting with ``data:`` is
under the shared data folder (``../shared/data`` beside the repository, or
``$ISP_DATA``), e.g. ``"data:lenses/phone/US-12210142-B2-e9.zmx"``.
"""

from __future__ import annotations

import dataclasses
import json
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path

from isp.errors import ConfigError, InputError

from restoration.synth.optics import PSF_DEFAULTS

__all__ = ["SECTIONS", "TrainConfig", "for_one_device", "load_config", "resolve_path"]

LOSSES = ("l2", "l1")
SCHEDULES = ("step", "cosine", "constant")
DEVICES = ("auto", "cpu", "cuda")


@dataclass(frozen=True)
class DataConfig:
    dirs: list = field(default_factory=list)
    crop: int = 128
    batch: int = 8
    val_latents: int = 4
    val_pairs: int = 32
    #: seed of the held-out draw; -1: ``run.seed`` (so a second run seed can keep the test set)
    split_seed: int = -1
    #: σ of the noise added to each pair's device descriptor (units of its spread over the tolerances):
    #: a fitted descriptor's own error, so a conditioned network trusts it as far as a fit deserves
    descriptor_noise: float = 0.0
    #: share of pairs whose descriptor is another pair's (a random one of the bank): a module given a
    #: wrong calibration, so a conditioned network learns to check the descriptor against the image
    descriptor_swap: float = 0.0


@dataclass(frozen=True)
class SynthConfig:
    out: str = ""
    lens: str = ""
    samples: int = 1
    pairs: int = 1000
    size: int = 256
    seed: int = 0
    workers: int = 2
    tolerance_scale: float = 1.0
    pixel_um: float = 0.0           # the pairs' pixel pitch; 0: the lens file's
    latent: str = "data:latent"
    cameras: list = field(default_factory=lambda: ["data:raw/SYNTHETIC_phone_S6meta_512x384.dng",
                                                   "data:raw/skia_sample_1mp.dng"])
    exposure_ev: list = field(default_factory=lambda: [0.0, 2.0])
    cct_k: list = field(default_factory=lambda: [2850.0, 7500.0])
    noise_scale: list = field(default_factory=lambda: [0.5, 2.0])
    noise: bool = True
    blend: str = "bilinear"
    demosaic: str = "malvar2004"
    tone: str = "none"
    positions: str = "frame"        # where crops lie: "frame" (uniform) or "radius" (uniform in the field radius)
    psf_n: int = 0                  # PSF window, half-pixel samples; 0: 32 µm (64 on 1 µm pixels)
    psf_grid: list = field(default_factory=lambda: list(PSF_DEFAULTS["grid"]))
    shard_size: int = 100
    basis: str = ""                 # the design's descriptor basis: each lens's descriptor in the manifest
    device_components: int = 16


#: ``model.placement``: (domain, placement text) of where the model runs, and
#: what its loss compares (the paper's placement ablation, section 5.4):
#: "pipeline" (ours): after demosaic, loss on Process(Model(J)) against the
#: sRGB target; "raw": same position, trained without the stages that
#: follow, loss on Model(J) against the target taken back to camera RGB
#: (:func:`restoration.synth.colour.unprocess_after_slot`); "srgb": at the
#: end of the pipeline, Model(Process(J)) against the sRGB target; "linear":
#: between the colour matrix and the gamma (linear sRGB at display
#: exposure), gamma(Model(Lum+CCM(J))) against the sRGB target.
PLACEMENTS = {"pipeline": ("camera_rgb", "camera_rgb after demosaic"),
              "raw": ("camera_rgb", "camera_rgb after demosaic (trained raw to raw, without the following stages)"),
              "srgb": ("display_rgb", "display_rgb after gamma"),
              "linear": ("linear_rgb", "linear_rgb after ccm")}


@dataclass(frozen=True)
class ModelConfig:
    variant: str = "doconv"
    kwargs: dict = field(default_factory=dict)
    #: where the model stands and what its loss sees (PLACEMENTS)
    placement: str = "pipeline"


@dataclass(frozen=True)
class OptimConfig:
    loss: str = "l2"
    lr: float = 1e-4
    betas: list = field(default_factory=lambda: [0.9, 0.999])
    eps: float = 1e-8
    weight_decay: float = 0.0
    schedule: str = "step"
    step_epochs: float = 10.0
    gamma: float = 0.5
    warmup_steps: int = 0
    grad_clip: float = 0.0
    highpass_penalty: float = 0.0


@dataclass(frozen=True)
class TemperatureConfig:
    start: float = 30.0
    end: float = 1.0
    epochs: float = 10.0


@dataclass(frozen=True)
class RunConfig:
    steps: int = 1000
    seed: int = 0
    device: str = "auto"
    threads: int = 2
    checkpoint_every: int = 250
    out: str = "out/train"
    seconds: float = 0.0


#: section name → its dataclass (``synth`` is optional: absent = use existing data)
SECTIONS = {"data": DataConfig, "synth": SynthConfig, "model": ModelConfig, "optim": OptimConfig,
            "temperature": TemperatureConfig, "run": RunConfig}


@dataclass(frozen=True)
class TrainConfig:
    """A checked training configuration (see :mod:`restoration.train.trainer`)."""

    data: DataConfig = field(default_factory=DataConfig)
    synth: SynthConfig | None = None
    model: ModelConfig = field(default_factory=ModelConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    temperature: TemperatureConfig = field(default_factory=TemperatureConfig)
    run: RunConfig = field(default_factory=RunConfig)

    def to_dict(self) -> dict:
        """JSON-ready nested dict (``synth`` left out when absent)."""
        d = {name: dataclasses.asdict(getattr(self, name)) for name in SECTIONS if getattr(self, name) is not None}
        return json.loads(json.dumps(d))

    @classmethod
    def from_dict(cls, d: dict, where: str = "config") -> TrainConfig:
        """Check and build; :class:`ConfigError` names the key and the valid ones."""
        if not isinstance(d, dict):
            raise ConfigError(f"{where}: expected a table of sections, got {type(d).__name__}")
        bad = sorted(set(d) - set(SECTIONS))
        if bad:
            raise ConfigError(f"{where}: unknown section(s) {', '.join(map(repr, bad))}; "
                              f"valid: {', '.join(SECTIONS)}")
        parts = {name: _section(SECTIONS[name], d[name], f"{where}: [{name}]") for name in SECTIONS if name in d}
        cfg = cls(**parts)
        cfg.check()
        return cfg

    def replace(self, section: str, **changes) -> TrainConfig:
        """A copy with keys of one section changed (checked)."""
        cur = getattr(self, section) or SECTIONS[section]()
        new = dataclasses.replace(self, **{section: dataclasses.replace(cur, **changes)})
        new.check()
        return new

    def data_dirs(self) -> list[str]:
        """``data.dirs``, or ``[synth.out]`` when only a synth spec is given."""
        if self.data.dirs:
            return [str(v) for v in self.data.dirs]
        return [self.synth.out] if self.synth is not None else []

    def check(self) -> None:
        """Ranges and choices (ConfigError with the key and the value)."""
        d, o, t, r = self.data, self.optim, self.temperature, self.run
        _positive(d.crop, "data.crop")
        _positive(d.batch, "data.batch")
        if d.crop % 4:
            raise ConfigError(f"data.crop must be a multiple of 4 (the network's input multiple); got {d.crop}")
        for k in ("val_latents", "val_pairs", "descriptor_noise"):
            if getattr(d, k) < 0:
                raise ConfigError(f"data.{k} must be ≥ 0; got {getattr(d, k)}")
        if not 0 <= d.descriptor_swap < 1:
            raise ConfigError(f"data.descriptor_swap must be in [0, 1); got {d.descriptor_swap}")
        if not self.data_dirs():
            raise ConfigError("no training data: give data.dirs (isp synth output folders) or a [synth] section")
        if self.synth is not None:
            s = self.synth
            if not s.lens:
                raise ConfigError("synth.lens is required in a [synth] section (a lens or proxy file)")
            if not s.out:
                raise ConfigError("synth.out is required in a [synth] section (where the pairs go)")
            for k in ("samples", "pairs", "size", "workers", "shard_size"):
                _positive(getattr(s, k), f"synth.{k}")
            if s.psf_n < 0:
                raise ConfigError(f"synth.psf_n must be ≥ 0 (0: a 32 µm window); got {s.psf_n}")
            if s.pixel_um and not 0.2 <= s.pixel_um <= 20.0:
                raise ConfigError(f"synth.pixel_um must be 0 (the lens file's) or 0.2–20 µm; got {s.pixel_um}")
            if s.size < d.crop:
                raise ConfigError(f"data.crop ({d.crop}) is larger than synth.size ({s.size})")
            for k in ("exposure_ev", "cct_k", "noise_scale", "psf_grid"):
                if len(getattr(s, k)) != 2:
                    raise ConfigError(f"synth.{k} must be two numbers; got {getattr(s, k)!r}")
            from restoration.synth.pairs import POSITIONS

            _choice(s.positions, POSITIONS, "synth.positions")
        _choice(self.model.placement, tuple(PLACEMENTS), "model.placement")
        _choice(o.loss, LOSSES, "optim.loss")
        _choice(o.schedule, SCHEDULES, "optim.schedule")
        if not o.lr > 0:
            raise ConfigError(f"optim.lr must be > 0; got {o.lr}")
        if len(o.betas) != 2 or not all(0 <= float(b) < 1 for b in o.betas):
            raise ConfigError(f"optim.betas must be two numbers in [0, 1); got {o.betas!r}")
        if not o.eps > 0 or min(o.weight_decay, o.grad_clip, o.warmup_steps, o.highpass_penalty) < 0:
            raise ConfigError("optim.eps must be > 0 and optim.weight_decay, grad_clip, warmup_steps, "
                              "highpass_penalty ≥ 0")
        if not o.step_epochs > 0 or not 0 < o.gamma <= 1:
            raise ConfigError(f"optim.step_epochs must be > 0 and optim.gamma in (0, 1]; "
                              f"got {o.step_epochs}, {o.gamma}")
        if not (t.start > 0 and t.end > 0 and t.epochs >= 0):
            raise ConfigError(f"temperature.start and .end must be > 0 and .epochs ≥ 0; got {t}")
        _positive(r.steps, "run.steps")
        _positive(r.threads, "run.threads")
        _positive(r.checkpoint_every, "run.checkpoint_every")
        if not r.seconds >= 0:
            raise ConfigError(f"run.seconds must be ≥ 0 (0: no time budget); got {r.seconds}")
        _choice(r.device, DEVICES, "run.device")
        if not r.out:
            raise ConfigError("run.out must name an output folder")


def _positive(v, name: str) -> None:
    if v < 1:
        raise ConfigError(f"{name} must be ≥ 1; got {v}")


def _choice(v, valid, name: str) -> None:
    if v not in valid:
        raise ConfigError(f"{name} must be one of {', '.join(map(repr, valid))}; got {v!r}")


def _coerce(value, default, key: str):
    """``value`` as the type of ``default`` (int → float allowed, bool kept apart)."""
    want = type(default)
    if want is bool:
        if isinstance(value, bool):
            return value
    elif want is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
    elif want is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif want is list:
        if isinstance(value, (list, tuple)):
            return list(value)
    elif want is dict:
        if isinstance(value, dict):
            return dict(value)
    elif isinstance(value, want):
        return value
    raise ConfigError(f"{key} must be {want.__name__}; got {value!r}")


def _section(cls, d, where: str):
    if not isinstance(d, dict):
        raise ConfigError(f"{where} must be a table; got {d!r}")
    names = [f.name for f in fields(cls)]
    bad = sorted(set(d) - set(names))
    if bad:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(map(repr, bad))}; valid: {', '.join(names)}")
    defaults = cls()
    section = where.rsplit("[", 1)[-1].rstrip("]")
    return cls(**{k: _coerce(v, getattr(defaults, k), f"{section}.{k}") for k, v in d.items()})


def load_config(path) -> TrainConfig:
    """Read and check a TOML (``.toml``) or JSON (``.json``) training config.

    Raises
    ------
    InputError
        No such file, or not valid TOML/JSON.
    ConfigError
        Unknown section or key, wrong type or range (the message names it).
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(p, "no such config file")
    text = p.read_text()
    try:
        d = json.loads(text) if p.suffix.lower() == ".json" else tomllib.loads(text)
    except (ValueError, tomllib.TOMLDecodeError) as e:
        raise InputError(p, f"not valid {'JSON' if p.suffix.lower() == '.json' else 'TOML'}: {e}") from None
    return TrainConfig.from_dict(d, where=str(p))


def resolve_path(value: str) -> Path:
    """A config path: ``data:REST`` → the shared data folder / REST; others as given."""
    if str(value).startswith("data:"):
        from restoration.synth.defaults import DATA

        return DATA / str(value)[5:]
    return Path(value)


def for_one_device(config: TrainConfig, lens) -> TrainConfig:
    """``config`` trained for one device (``isp train --lens``): pairs from
    ``lens`` alone (a fitted proxy camera; ``synth.samples = 1``),
    synthesised into ``<run.out>/pairs``.

    Raises
    ------
    InputError
        ``lens`` is not a file.
    ConfigError
        The config's pairs do not come from its ``[synth]`` section.
    """
    if not Path(lens).is_file():
        raise InputError(lens, "no such lens file (a fitted proxy.json, lens/v1 or .zmx)")
    if config.synth is None or config.data.dirs:
        raise ConfigError("--lens needs a config whose pairs come from its [synth] section (no data.dirs)")
    return config.replace("synth", lens=str(Path(lens).resolve()), samples=1,
                          out=str(Path(config.run.out) / "pairs"))
