"""The optional extras of the a3d distribution: which modules each brings, and a one-line error
naming the extra to install when one is missing (``pip install 'a3d[train]'``).

The base install is numpy, ONNX Runtime, OpenCV and tqdm; everything else is an extra that a
command or method checks for before it starts (``Needs.check``), found without importing it.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass

from a3d.runtime.errors import InputError

EXTRAS: dict[str, tuple[str, ...]] = {
    "view": ("rerun",),
    "train": ("torch", "onnx", "onnxscript", "scipy", "h5py", "matplotlib"),
    "sunrgbd": ("scipy",),
    "bag": ("rosbags",),
    "realsense": ("pyrealsense2",),
    "ray": ("ray",),  # and ray[data]'s pyarrow, which rerun needs too: a3d.runtime.scale checks it
}
"""The modules each optional extra of pyproject.toml brings (import names, not pip names)."""


class MissingExtra(InputError):
    """A command's optional extra is not installed: one line naming it and the module missing."""

    def __init__(self, extra: str, module: str, caller: str = "") -> None:
        who = f"{caller} " if caller else ""
        super().__init__(f"{who}needs the '{extra}' extra: pip install 'a3d[{extra}]' ({module} is missing)")

    @classmethod
    def of(cls, error: ModuleNotFoundError) -> MissingExtra | None:
        """The extra that brings the module an import did not find; None for a module of no extra
        (a broken install, which keeps its traceback)."""
        module = (error.name or "").split(".")[0]
        extra = next((name for name, modules in EXTRAS.items() if module in modules), None)
        return None if extra is None else cls(extra, module)


def installed(module: str) -> bool:
    """Whether ``module`` can be imported, found without importing it (torch takes seconds)."""
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):  # a blocked or half-removed module
        return False


@dataclass(frozen=True)
class Needs:
    """The optional extra a command runs on and the modules of it the command imports."""

    extra: str
    modules: tuple[str, ...]

    def check(self, caller: str = "") -> None:
        """MissingExtra for the first module that is not installed (naming ``caller``, a method)."""
        for module in self.modules:
            if not installed(module):
                raise MissingExtra(self.extra, module, caller)
