"""isp: the pipeline core.

Frames and domains, camera metadata, the Stage protocol and its registry,
pipelines, raw/DNG reading and DNG writing, and the ``isp`` command line.
This package imports nothing of ``modules``, ``calibration``, ``restoration``
or ``export``: built-in stages reach it through the ``isp.stages`` entry
points, sub-commands of the other packages are imported lazily.

>>> import isp
>>> isp.Domain.RAW.order < isp.Domain.CAMERA_RGB.order
True
"""

from isp.errors import ConfigError, InputError, IspError, PlacementError

#: the package's names, each imported from its module when first used (PEP 562):
#: a command that needs only frames (``isp calib sfr``) does not load the
#: pipeline, the stage registry and their imports
_LAZY = {"CFA": "isp.frame", "Domain": "isp.frame", "Frame": "isp.frame", "Step": "isp.frame",
         "CameraMeta": "isp.meta", "DEFAULT_STAGES": "isp.pipeline", "Pipeline": "isp.pipeline",
         "create_stage": "isp.registry", "list_stages": "isp.registry", "register_stage": "isp.registry",
         "Stage": "isp.stage", "StageBase": "isp.stage"}


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'isp' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))


__all__ = [
    "CFA", "CameraMeta", "ConfigError", "DEFAULT_STAGES", "Domain", "Frame",
    "InputError", "IspError", "Pipeline", "PlacementError", "Stage", "StageBase",
    "Step", "create_stage", "list_stages", "register_stage",
]
__version__ = "0.1.0"
