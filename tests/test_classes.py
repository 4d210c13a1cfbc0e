"""a3d.runtime.structures.classes: a mask of named classes, and an unknown name refused."""

from __future__ import annotations

import numpy as np
import pytest

from a3d.runtime.structures.classes import CLASSES, NUM_CLASSES, class_mask


def test_a_class_mask_marks_exactly_the_classes_named() -> None:
    mask = class_mask(["door", "chair", "door"])
    assert mask.shape == (NUM_CLASSES,) and mask.dtype == bool
    assert [CLASSES[i] for i in np.flatnonzero(mask)] == ["chair", "door"]
    assert not class_mask([]).any()
    with pytest.raises(ValueError, match="unknown class name 'armchair'"):
        class_mask(["chair", "armchair"])
