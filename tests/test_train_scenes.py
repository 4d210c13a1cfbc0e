"""The training tests' tiny scenes (tests/helpers/train_scenes.py) are consistent."""

from __future__ import annotations

from a3d.runtime.sources.folder import list_frames, read_ground_truth
from tests.helpers.train_scenes import write_scenes


def test_scene_ground_truth_is_consistent(tmp_path):
    """The fixture itself: written GT reads back, visible boxes lie inside the amodal ones (up to
    the half pixel by which a pixel's extent passes its centre)."""
    folder = write_scenes(tmp_path / "scenes", 3)
    refs = list_frames(folder)
    assert [r.name for r in refs] == ["s000", "s001", "s002"]
    for ref in refs:
        gt = read_ground_truth(ref)
        assert gt is not None and len(gt.class_ids) >= 1
        inside = (gt.boxes2d_visible[:, :2] >= gt.boxes2d_amodal[:, :2] - 0.5).all() and (
            gt.boxes2d_visible[:, 2:] <= gt.boxes2d_amodal[:, 2:] + 0.5
        ).all()
        assert inside
