"""Reading a ``.npy`` header without loading its array, so a file cannot make a reader allocate
more than the size it was checked against."""

from __future__ import annotations

import tokenize
from pathlib import Path
from typing import BinaryIO

import numpy as np

from a3d.runtime.errors import InputError


def npy_header(f: BinaryIO, path: Path) -> tuple[tuple[int, ...], np.dtype, int]:
    """(shape, dtype, data offset) of a .npy stream, read without loading the array."""
    try:
        version = np.lib.format.read_magic(f)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(f)
        else:
            shape, _, dtype = np.lib.format.read_array_header_2_0(f)
    except (ValueError, EOFError, SyntaxError, TypeError, RecursionError, tokenize.TokenError) as error:
        # numpy parses the header with ast / tokenize: a malformed one raises any of these
        raise InputError(f"{path}: not a valid .npy array ({error})") from None
    if dtype.hasobject:
        raise InputError(f"{path}: .npy holds Python objects; expected a numeric array")
    return tuple(shape), dtype, f.tell()
