"""Error types of a3d: what the user must fix, as one line that names the file.

``InputError`` is raised for bad input files or values (message ``"PATH: problem"``), so a
command-line tool can print it as it is and exit; ``ModelError`` for a model file that does not
fit this runtime. Both subclass ValueError, so callers that catch ValueError keep working.
"""

from __future__ import annotations


class _OneLineError(ValueError):
    """A ValueError whose message is kept on one line (newlines become "; ")."""

    def __init__(self, message: str) -> None:
        super().__init__("; ".join(part.strip() for part in str(message).splitlines() if part.strip()))


class InputError(_OneLineError):
    """A bad input file or value: ``InputError("frames/0001.depth.png: depth is 480x640 but ...")``."""


class ModelError(_OneLineError):
    """A model file that is missing, malformed, or does not match this runtime."""
