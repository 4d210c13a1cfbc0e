"""open_source as a Python user calls it: defaults for every option, keywords, the intrinsics in
the forms Detector.detect takes, and errors in Python terms."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from a3d.runtime.errors import InputError
from a3d.runtime.sources.arrays import ArrayError
from a3d.runtime.sources.registry import SourceOptions, open_source
from a3d.runtime.structures.geometry import Intrinsics

SAMPLES = Path(__file__).resolve().parents[1] / "samples"
K = Intrinsics(500.0, 510.0, 280.0, 213.0)


def test_a_path_alone_opens_with_every_default() -> None:
    source = open_source(SAMPLES)
    assert len(list(source)) == 6
    assert open_source(SAMPLES, SourceOptions()).__class__ is source.__class__  # the old form still works


@pytest.mark.parametrize("form", [K, (500.0, 510.0, 280.0, 213.0), K.matrix(), K.matrix().tolist()])
def test_intrinsics_in_every_form_replace_the_sources(form: object) -> None:
    assert SourceOptions(intrinsics=form).intrinsics == K
    frame = next(iter(open_source(SAMPLES, intrinsics=form))).load()
    assert frame.intrinsics == K


def test_bad_options_are_one_line_in_python_terms() -> None:
    with pytest.raises(ArrayError, match=r"^intrinsics: expected \(fx, fy, cx, cy\) or a 3x3 matrix"):
        open_source(SAMPLES, intrinsics=(500.0, 510.0))
    with pytest.raises(ArrayError, match=r"^depth_scale: must be a positive number of metres per unit"):
        SourceOptions(depth_scale=-1)
    with pytest.raises(InputError, match=r"^depth_topic: not an option of a3d sources \(theirs: none\)$"):
        open_source(SAMPLES, depth_topic="/camera/depth")
    with pytest.raises(InputError, match=r"^kind: unknown format 'zip' \(one of: 7scenes, a3d, tum, "):
        open_source(SAMPLES, kind="zip")
    with pytest.raises(TypeError, match="not both"):
        open_source(SAMPLES, SourceOptions(), depth_scale=0.001)
    doubled = next(iter(open_source(SAMPLES, depth_scale=0.002))).load()  # PNG units read as 2 mm each
    plain = next(iter(open_source(SAMPLES))).load()
    np.testing.assert_allclose(doubled.depth, 2 * plain.depth, rtol=1e-6)
