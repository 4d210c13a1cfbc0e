"""The authors' NYUv2 release reader and ``a3d-nyuv2``, on tiny releases written in its layout."""

from __future__ import annotations

from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest
import scipy.io

from a3d.runtime.errors import InputError
from a3d.runtime.sources import folder as frames
from a3d.runtime.sources import proposals_file
from a3d.runtime.structures.geometry import (
    NYU_CROP_INTRINSICS,
    NYU_CROP_SIZE,
    project_boxes_to_2d,
    rtilt_from_pitch_roll,
)
from a3d.train.data import nyuv2, nyuv2_cli

H, W = NYU_CROP_SIZE
R = rtilt_from_pitch_roll(-0.25, 0.04)
# Camera-frame 7-vectors of the annotated objects. The third is given with l < w, so the reader
# must return it canonical: l and w swapped, theta turned by pi/2 and wrapped.
BOXES = np.array(
    [
        [0.4, 0.3, 2.5, 0.6, 0.5, 0.9, 0.3],
        [-0.8, 0.6, 3.0, 0.5, 0.45, 0.6, -1.2],
        [0.9, 0.2, 3.5, 0.7, 1.2, 0.5, 0.4],
    ]
)
CANONICAL_THIRD = [0.9, 0.2, 3.5, 1.2, 0.7, 0.5, 0.4 + np.pi / 2 - np.pi]
SEL = [[11.0, 21.0, 50.0, 80.0], [100.0, 150.0, 180.0, 300.0], [1.0, 1.0, 561.0, 427.0]]


def corners_tilt(box: np.ndarray) -> np.ndarray:
    """The release's 8 tilt-frame corners of a 7-vector (its ``calc_corners_tilt.m``)."""
    l, w, h = box[3] / 2, box[4] / 2, box[5] / 2
    local = np.array(
        [[l, h, w], [-l, h, w], [-l, h, -w], [l, h, -w], [l, -h, w], [-l, -h, w], [-l, -h, -w], [l, -h, -w]]
    )
    t = box[6]
    rot = np.array([[np.cos(t), 0, np.sin(t)], [0, 1, 0], [-np.sin(t), 0, np.cos(t)]])
    return local @ rot.T + R @ box[:3]


def vectorize_bboxes(corners: np.ndarray, Rtilt: np.ndarray) -> np.ndarray:
    """The release's ``VectorizeBboxes.m``, transcribed (theta returned in radians, not degrees)."""
    center = (np.linalg.pinv(Rtilt) @ corners.T).T.mean(axis=0)
    height = np.linalg.norm(corners[0] - corners[4])
    d12, d14 = np.linalg.norm(corners[0] - corners[1]), np.linalg.norm(corners[0] - corners[3])
    if d12 > d14:
        size, direction = [d12, d14, height], corners[0] - corners[3]
    else:
        size, direction = [d14, d12, height], corners[0] - corners[1]
    angle = np.degrees(np.arctan2(direction[0], direction[2]))
    angle = angle - 180 if angle > 90 else angle + 180 if angle < -90 else angle
    return np.array([*center, *size, np.radians(angle)])


def annotation() -> dict:
    """The ``data`` struct: 6 labelled objects, 4 kept (one is not a class, one has no 3D box)."""
    empty = np.zeros((0, 0))
    gt3d = [
        corners_tilt(BOXES[0]),
        corners_tilt(BOXES[1]),
        corners_tilt(BOXES[0]),
        empty,
        corners_tilt(BOXES[2]),
    ]
    return {
        "Rtilt": R,
        "gt3D": [*gt3d, corners_tilt(BOXES[1])],
        "gtLabelNames": ["chair", "night_stand", "picture", "table", "tv", "garbage_bin"],
        "gt2Dsel": [
            np.array([SEL[0]]),
            np.array([SEL[1]]),
            np.array([SEL[0]]),
            np.array([SEL[0]]),
            np.array([SEL[2]]),
            np.array([SEL[1]]),
        ],
    }


def cell(items: list) -> np.ndarray:
    """A MATLAB (1, n) cell array for scipy.io.savemat."""
    out = np.empty((1, len(items)), dtype=object)
    for i, item in enumerate(items):
        out[0, i] = item
    return out


def save_v5(path: Path, data: dict) -> None:
    struct = {key: cell(value) if isinstance(value, list) else value for key, value in data.items()}
    scipy.io.savemat(path, {"data": struct})


def save_v73(path: Path, variables: dict) -> None:
    """Write ``variables`` as MATLAB v7.3 does: HDF5 after a 512-byte header, arrays transposed,
    cells as object references into ``#refs#``, char as uint16, empty arrays flagged."""
    with h5py.File(path, "w", userblock_size=512) as f:
        refs = f.create_group("#refs#")

        def put(parent: h5py.Group, name: str, value) -> None:
            if isinstance(value, dict):
                group = parent.create_group(name)
                group.attrs["MATLAB_class"] = np.bytes_("struct")
                for key, item in value.items():
                    put(group, key, item)
                return
            if len(value) == 0 if isinstance(value, (list, str)) else np.size(value) == 0:
                kind = "cell" if isinstance(value, list) else "char" if isinstance(value, str) else "double"
                ds = parent.create_dataset(name, data=np.array([0, 0], np.uint64))
                ds.attrs["MATLAB_empty"] = np.uint8(1)
            elif isinstance(value, list):
                kind = "cell"
                targets = []
                for item in value:
                    key = f"r{len(refs)}"
                    put(refs, key, item)
                    targets.append(refs[key].ref)
                ds = parent.create_dataset(name, data=np.array(targets, dtype=h5py.ref_dtype).reshape(-1, 1))
            elif isinstance(value, str):
                kind = "char"
                ds = parent.create_dataset(
                    name, data=np.array([ord(c) for c in value], np.uint16).reshape(-1, 1)
                )
            else:
                kind = "double"
                ds = parent.create_dataset(name, data=np.asarray(value, np.float64).T)
            ds.attrs["MATLAB_class"] = np.bytes_(kind)

        for key, value in variables.items():
            put(f, key, value)
    with open(path, "r+b") as fh:
        fh.write(b"MATLAB 7.3 MAT-file, written by the a3d tests".ljust(116))


def depths(seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    filled = rng.uniform(0.8, 6.0, (H, W))
    raw = np.where(rng.random((H, W)) < 0.2, 0.0, filled)
    return raw, filled


def make_release(root: Path, train=(1, 2), test=(3,), v73=(3,)) -> Path:
    for folder in ("annotations", "color", "rawDepth", "dmap_f"):
        (root / folder).mkdir(parents=True, exist_ok=True)
    for i in (*train, *test):
        color = np.random.default_rng(i).integers(0, 256, (H, W, 3), dtype=np.uint8)
        cv2.imwrite(str(root / "color" / f"{i}.jpg"), color)
        raw, filled = depths(i)
        scipy.io.savemat(root / "rawDepth" / f"{i}.mat", {"rawDepth": raw})
        scipy.io.savemat(root / "dmap_f" / f"{i}.mat", {"dmap_f": filled})
        if i in v73:
            save_v73(root / "annotations" / f"{i}.mat", {"data": annotation()})
        else:
            save_v5(root / "annotations" / f"{i}.mat", annotation())
    (root / "trainval.txt").write_text("".join(f"{i:04d}\n" for i in train))
    (root / "test.txt").write_text("".join(f"{i}\n" for i in test))
    return root


def expected_gt_boxes() -> np.ndarray:
    return np.array([BOXES[0], BOXES[1], CANONICAL_THIRD, BOXES[1]])


# ----------------------------------------------------------------------------- reader


def test_class_names_are_normalised() -> None:
    cases = {
        "night_stand": "night stand",
        "garbage_bin": "garbage bin",
        "tv": "television",
        "TV ": "television",
        "Night Stand": "night stand",
        "nightstand": "night stand",
        "chair": "chair",
        "picture": None,
        "sofa_chair": None,
    }
    for name, expected in cases.items():
        assert nyuv2.normalize_class_name(name) == expected, name


def test_matlab_boxes_become_pixel_edges() -> None:
    # 1-based inclusive pixels 11..50 (columns) are 0-based 10..49, whose edges are 9.5 and 49.5.
    assert nyuv2.matlab_boxes_to_pixels(np.array([[11, 21, 50, 80]])).tolist() == [[9.5, 19.5, 49.5, 79.5]]
    # The whole crop, 1..561 x 1..427, is the image's extent [-0.5, W - 0.5] x [-0.5, H - 0.5].
    assert nyuv2.matlab_boxes_to_pixels(np.array(SEL[2])).tolist() == [-0.5, -0.5, W - 0.5, H - 0.5]


def test_read_image_converts_the_annotation(tmp_path: Path) -> None:
    root = make_release(tmp_path / "NYUV2", train=(1,), test=(), v73=())
    image = nyuv2.read_image(root, 1)
    gt = image.gt
    assert gt.classes == ["chair", "night stand", "television", "garbage bin"]
    assert gt.class_ids.tolist() == [4, 12, 17, 9]
    assert np.allclose(gt.boxes3d, expected_gt_boxes(), atol=1e-9)
    corners = [corners_tilt(b) for b in (BOXES[0], BOXES[1], BOXES[2], BOXES[1])]
    reference = np.array([vectorize_bboxes(c, R) for c in corners])  # the authors' own conversion
    assert np.allclose(gt.boxes3d, reference, atol=1e-9)
    assert np.allclose(
        gt.boxes2d_visible, nyuv2.matlab_boxes_to_pixels(np.array([SEL[0], SEL[1], SEL[2], SEL[1]]))
    )
    amodal = project_boxes_to_2d(gt.boxes3d, R, NYU_CROP_INTRINSICS, (H, W))
    assert np.array_equal(gt.boxes2d_amodal, amodal) and (amodal[:, 2] > amodal[:, 0]).all()
    raw, filled = depths(1)
    assert image.depth_raw.dtype == np.float32 and np.array_equal(image.depth_raw, raw.astype(np.float32))
    assert np.array_equal(image.depth_filled, filled.astype(np.float32))
    assert np.array_equal(image.R_tilt, R) and image.intrinsics == NYU_CROP_INTRINSICS
    assert image.color == (root / "color" / "1.jpg").read_bytes() and image.image_size == (H, W)


def test_matlab_v73_files_read_like_v5(tmp_path: Path) -> None:
    save_v5(tmp_path / "v5.mat", annotation())
    save_v73(tmp_path / "v73.mat", {"data": annotation()})
    a = nyuv2.load_mat(tmp_path / "v5.mat")["data"]
    b = nyuv2.load_mat(tmp_path / "v73.mat")["data"]
    assert a["gtLabelNames"] == b["gtLabelNames"] == annotation()["gtLabelNames"]
    assert np.array_equal(a["Rtilt"], b["Rtilt"])
    for x, y, want in zip(a["gt3D"], b["gt3D"], annotation()["gt3D"], strict=True):
        assert x.shape == y.shape and np.array_equal(x, want) and np.array_equal(y, want)
    for x, y in zip(a["gt2Dsel"], b["gt2Dsel"], strict=True):
        assert x.shape == y.shape == (1, 4) and np.array_equal(x, y)
    root = make_release(tmp_path / "NYUV2", train=(1,), test=(2,), v73=(2,))
    assert np.array_equal(nyuv2.read_image(root, 2).gt.boxes3d, nyuv2.read_image(root, 1).gt.boxes3d)


def test_bad_release_files(tmp_path: Path) -> None:
    root = make_release(tmp_path / "NYUV2", train=(1,), test=(), v73=())
    path = root / "annotations" / "1.mat"
    data = annotation()
    save_v5(path, {**data, "Rtilt": 2 * R})
    with pytest.raises(InputError, match=r"1\.mat: data\.Rtilt: not a proper rotation"):
        nyuv2.read_image(root, 1)
    save_v5(path, {key: value for key, value in data.items() if key != "gt2Dsel"})
    with pytest.raises(InputError, match=r"1\.mat: data has no field 'gt2Dsel'"):
        nyuv2.read_image(root, 1)
    save_v5(path, {**data, "gt3D": [np.zeros((4, 3)), *data["gt3D"][1:]]})
    with pytest.raises(InputError, match=r"gt3D\{1\} must be 8x3"):
        nyuv2.read_image(root, 1)
    save_v5(path, data)
    scipy.io.savemat(root / "rawDepth" / "1.mat", {"rawDepth": depths(1)[0] * 1000})
    with pytest.raises(InputError, match=r"rawDepth/1\.mat: rawDepth looks like millimetres"):
        nyuv2.read_image(root, 1)
    scipy.io.savemat(root / "rawDepth" / "1.mat", {"rawDepth": depths(1)[0][:-1]})
    with pytest.raises(InputError, match=f"rawDepth is {H - 1}x{W} but colour is {H}x{W}"):
        nyuv2.read_image(root, 1)
    (root / "rawDepth" / "1.mat").write_bytes(b"MATLAB 5.0 MAT-file" + bytes(200))
    with pytest.raises(InputError, match=r"rawDepth/1\.mat: cannot read the MATLAB file"):
        nyuv2.read_image(root, 1)
    (root / "test.txt").write_text("3\nfour\n")
    with pytest.raises(InputError, match=r"test\.txt: line 2: expected an image number, got 'four'"):
        nyuv2.read_split(root, "test")


# ----------------------------------------------------------------------------- a3d-nyuv2


def test_cli_converts_a_release_to_frame_folders(tmp_path: Path, capsys) -> None:
    root = make_release(tmp_path / "NYUV2")
    out = tmp_path / "frames"
    assert nyuv2_cli.main([str(root), str(out)]) == 0
    assert "frames" in capsys.readouterr().out
    for split, names in (("train", ["0001", "0002"]), ("test", ["0003"])):
        refs = frames.list_frames(out / split)
        assert [r.name for r in refs] == names
        assert frames.read_folder_intrinsics(out / split) == NYU_CROP_INTRINSICS
        for ref in refs:
            index = int(ref.name)
            image = nyuv2.read_image(root, index)
            frame = frames.read_frame(ref, frames.read_folder_intrinsics(out / split))
            assert ref.color_path.read_bytes() == (root / "color" / f"{index}.jpg").read_bytes()
            assert np.max(np.abs(frame.depth - image.depth_raw)) <= 0.0005 + 1e-6  # millimetre PNG
            assert np.array_equal(frame.depth == 0, image.depth_raw == 0)
            assert np.array_equal(frame.R_tilt, image.R_tilt)
            gt = frames.read_ground_truth(ref)
            assert gt.classes == image.gt.classes
            for field in ("boxes3d", "boxes2d_visible", "boxes2d_amodal"):
                assert np.array_equal(getattr(gt, field), getattr(image.gt, field)), field


def write_mcg(segs: Path, index: int) -> None:
    """The authors' ``Segs/NYU%04d/candidates.mat``: 20 x 20 superpixel blocks (22 x 29 of them);
    candidate 2 is the bottom-right block, 7 x 1 pixels (box area 7 < 200: dropped)."""
    sp = (np.arange(H)[:, None] // 20) * 29 + np.arange(W)[None] // 20 + 1
    members = [[1, 2, 30], [638], [5, 6, 7, 8]]
    masks = [np.isin(sp, m) for m in members]
    bboxes = []
    for m in masks:
        rows, cols = np.nonzero(m)
        bboxes.append([rows.min() + 1, cols.min() + 1, rows.max() + 1, cols.max() + 1])
    labels = np.empty((len(members), 1), dtype=object)
    for i, m in enumerate(members):
        labels[i, 0] = np.array([m], dtype=np.float64)
    (segs / f"NYU{index:04d}").mkdir(parents=True)
    fields = {"superpixels": sp.astype(np.float64), "labels": labels, "bboxes": np.array(bboxes, np.float64)}
    scipy.io.savemat(segs / f"NYU{index:04d}" / "candidates.mat", {"candidates": fields})


def test_cli_writes_mcg_proposals_filtered_as_the_authors_do(tmp_path: Path) -> None:
    root = make_release(tmp_path / "NYUV2", train=(1,), test=(2,), v73=())
    for index in (1, 2):
        write_mcg(tmp_path / "Segs", index)
    out = tmp_path / "frames"
    assert nyuv2_cli.main([str(root), str(out), "--mcg", str(tmp_path / "Segs")]) == 0
    (ref,) = frames.list_frames(out / "test")
    assert ref.proposals_path == out / "test" / "0002.proposals.npz"
    proposals = proposals_file.read_precomputed_proposals(ref.proposals_path, (H, W))
    assert proposals.boxes.tolist() == [[-0.5, -0.5, 39.5, 39.5], [79.5, -0.5, 159.5, 19.5]]
    assert proposals.mask(1).sum() == 80 * 20


def test_cli_reports_a_broken_release_in_one_line(tmp_path: Path, capsys) -> None:
    root = make_release(tmp_path / "NYUV2", train=(1,), test=(2,), v73=())
    (root / "color" / "2.jpg").write_bytes((root / "color" / "2.jpg").read_bytes()[:1000])
    assert nyuv2_cli.main([str(root), str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("a3d-nyuv2: error: ") and "2.jpg: JPEG is truncated" in err
