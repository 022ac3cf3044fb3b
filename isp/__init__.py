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
from isp.frame import CFA, Domain, Frame, Step
from isp.meta import CameraMeta
from isp.pipeline import DEFAULT_STAGES, Pipeline
from isp.registry import create_stage, list_stages, register_stage
from isp.stage import Stage, StageBase

__all__ = [
    "CFA", "CameraMeta", "ConfigError", "DEFAULT_STAGES", "Domain", "Frame",
    "InputError", "IspError", "Pipeline", "PlacementError", "Stage", "StageBase",
    "Step", "create_stage", "list_stages", "register_stage",
]
__version__ = "0.1.0"
