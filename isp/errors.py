"""The project's exception hierarchy.

Every error raised at a public boundary derives from :class:`IspError`, so a
command line or a batch job can catch one type, print one line and carry on.
Messages carry the offending value (and the file, where there is one); they
are written to be printed as they are.
"""

from __future__ import annotations


class IspError(Exception):
    """Root of every error this project raises on purpose."""


class InputError(IspError):
    """An input file that cannot be processed: unreadable, truncated, not a
    Bayer raw, or with metadata that makes no sense.

    The message starts with the file name, so ``str(err)`` is a complete
    one-line report.
    """

    def __init__(self, path, reason: str):
        self.path = str(path) if path is not None else None
        self.reason = reason
        super().__init__(f"{self.path}: {reason}" if self.path else reason)

    def __reduce__(self):  # picklable, so an error in a worker process reaches the parent intact
        return (type(self), (self.path, self.reason))


class ConfigError(IspError):
    """A pipeline or stage configuration that cannot run: unknown stage,
    unknown or ill-typed parameter, a domain chain that does not fit."""


class PlacementError(ConfigError):
    """A correction model placed at a pipeline position (domain) it was not
    trained for."""
