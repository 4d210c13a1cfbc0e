"""a3d.synth: rendering agrees with the ground truth, sensor models, placement rules, determinism."""

from __future__ import annotations

import math
from dataclasses import replace

import cv2
import numpy as np
import pytest

from a3d.runtime.sources.folder import (
    list_frames,
    read_folder_intrinsics,
    read_frame,
    read_ground_truth,
    read_instances,
)
from a3d.runtime.structures.classes import CLASSES
from a3d.runtime.structures.geometry import (
    backproject,
    box_area_2d,
    box_corners_camera,
    rtilt_from_pitch_roll,
)
from a3d.synth import SceneConfig, generate_frame
from a3d.synth import furniture as fu
from a3d.synth.agreement import (
    amodal_contains_visible,
    box_local,
    exact_depth_in_boxes,
    floor_height_spread,
    in_box,
    sensed_inside_shares,
)
from a3d.synth.appearance import CLASS_FAMILIES, FAMILIES
from a3d.synth.camera import CameraPose
from a3d.synth.cli import frame_seed, main, scaled_intrinsics
from a3d.synth.parts import CYL, N_SLOTS, Furniture, box, cyl
from a3d.synth.raycast import PartArrays, RayGrid, cast
from a3d.synth.rooms import furnish
from a3d.synth.scene import build_parts
from a3d.synth.sensor import SENSORS, depth_sigma, projector_shadow, sense_depth
from a3d.synth.shading import KINDS
from a3d.synth.stats import summarise

SEEDS = (11, 12, 13, 14, 15)


@pytest.fixture(scope="module")
def frames():
    return [generate_frame(s) for s in SEEDS]


def test_box_local_maps_a_box_corners_to_its_half_extents() -> None:
    """agreement.box_local (used by the checks below) agrees with geometry's corner convention."""
    R = rtilt_from_pitch_roll(math.radians(-20), math.radians(4))
    box = np.array([0.4, 0.3, 3.0, 1.2, 0.6, 0.8, 0.7])
    corners = box_corners_camera(box[None], R)[0]
    local = box_local(corners, box, R)
    np.testing.assert_allclose(np.abs(local), np.tile([0.6, 0.4, 0.3], (8, 1)), atol=1e-9)
    assert in_box(local, box, 1e-9).all() and not in_box(local * 1.01, box, 0.001).any()


def test_mask_pixels_back_project_into_their_3d_box(frames) -> None:
    """Sensor depth: >= 95% of every annotated object's mask pixels with valid depth lie in its box
    grown by 5 cm; exact depth: every mask pixel lies in its box (1 mm), so boxes, masks and depth
    agree exactly. (bench/synth_agreement.py checks the same on a written 1000-frame set.)"""
    rows = [r for f in frames for r in sensed_inside_shares(f)]
    assert len(rows) >= 20 and min(share for _, _, share in rows) >= 0.95
    assert all(exact_depth_in_boxes(f) for f in frames)


def test_far_objects_stay_within_5cm_with_the_a3d_sensor_not_with_kinect_v1() -> None:
    """A deep classroom (objects 5-7 m away): Kinect v1's error (4-6 cm sigma, 8-13 cm disparity
    steps there) pushes a far object's depth out of its box + 5 cm; the default a3d sensor keeps
    every object inside."""
    a3d = generate_frame(79)
    assert a3d.depth_exact[a3d.instances > 0].max() > 6.0
    assert min(share for _, _, share in sensed_inside_shares(a3d)) >= 0.95
    kinect = generate_frame(79, SceneConfig(depth_sensor=SENSORS["kinect-v1"]))
    assert min(share for _, _, share in sensed_inside_shares(kinect)) < 0.8


def test_2d_boxes_masks_and_classes_are_consistent(frames) -> None:
    for f in frames:
        gt = f.gt
        H, W = f.depth.shape
        assert set(np.unique(f.instances)) == {0, *gt.instance_ids.tolist()}
        for k in range(len(gt)):
            rows, cols = np.nonzero(f.instances == gt.instance_ids[k])
            assert len(rows) >= SceneConfig().min_visible_px
            extent = [cols.min() - 0.5, rows.min() - 0.5, cols.max() + 0.5, rows.max() + 0.5]
            np.testing.assert_array_equal(gt.boxes2d_visible[k], extent)  # README pixel-extent convention
            amo = gt.boxes2d_amodal[k]
            assert -0.5 <= amo[0] <= amo[2] <= W - 0.5 and -0.5 <= amo[1] <= amo[3] <= H - 0.5
        assert np.all(gt.boxes3d[:, 3] >= gt.boxes3d[:, 4]) and np.all(
            np.abs(gt.boxes3d[:, 6]) <= math.pi / 2
        )
        assert all(c in CLASSES for c in gt.classes)
        annotated = [r for r in f.objects if r.annotated]  # statistics come in ground-truth order
        assert [r.cls for r in annotated] == gt.classes
        assert amodal_contains_visible(f)
        for r in f.objects:
            assert 0 <= r.visible_px <= r.alone_px <= r.full_px + 1e-6
            assert r.annotated == (r.visible_px >= SceneConfig().min_visible_px)


def test_rtilt_levels_the_floor(frames) -> None:
    for f in frames:
        v, u = np.nonzero(f.floor)
        assert len(u) > 1000
        assert floor_height_spread(f) < 0.02
        y = (backproject(u, v, f.depth_exact[v, u], f.intrinsics) @ f.R_tilt.T)[:, 1]
        assert abs(np.median(y) - f.camera.height) < 0.01  # tilt y points down: the floor lies at +height
        pitch = math.degrees(f.camera.pitch)
        assert -35 <= pitch <= -5 and abs(math.degrees(f.camera.roll)) <= 5 and 1.0 <= f.camera.height <= 1.8


def test_sensor_depth_is_kinect_like(frames) -> None:
    errors, depths = [], []
    for f in frames:
        valid = f.depth > 0
        assert 0.005 < 1 - valid.mean() < 0.5  # holes, but mostly depth
        assert np.all((f.depth[valid] >= 0.4) & (f.depth[valid] <= 8.5))
        errors.append(f.depth[valid] - f.depth_exact[valid])
        depths.append(f.depth_exact[valid])
    err, z = np.abs(np.concatenate(errors)), np.concatenate(depths)
    near, far = err[z < 2.0].mean(), err[z > 3.0].mean()
    assert near < 0.01 and far > 2 * near  # noise grows with depth


@pytest.mark.parametrize("sensor", sorted(SENSORS))
def test_depth_noise_follows_sigma_and_disparity_steps(sensor: str) -> None:
    rng = np.random.default_rng(0)
    s = SENSORS[sensor]
    fx = 518.857901
    for z0 in (1.0, 3.0, 5.0):
        z = np.full((200, 200), z0, np.float32)
        d = sense_depth(rng, z, fx, np.full(z.shape, 0.5, np.float32), np.ones(z.shape, np.float32), s)
        ok = d > 0
        assert ok.mean() > 0.9
        # quantised to 1/subpixel-pixel disparity steps
        steps = fx * s.baseline / d[ok] * s.subpixel
        np.testing.assert_allclose(steps, np.round(steps), atol=1e-2)
        spread = d[ok].std()
        step = z0**2 / (fx * s.baseline * s.subpixel)
        assert 0.5 * depth_sigma(z0, s) < spread < 1.5 * math.hypot(depth_sigma(z0, s), step / math.sqrt(12))


def test_projector_shadow_lies_left_of_near_objects() -> None:
    fb = 518.857901 * 0.075
    z = np.full((50, 300), 3.0, np.float32)
    z[:, 150:200] = 1.0
    shadow = projector_shadow(z, fb)
    width = fb * (1 / 1.0 - 1 / 3.0)  # 25.9 px
    row = np.flatnonzero(shadow[10])
    assert (
        row.min() == 150 - math.floor(width) and row.max() == 149
    )  # a band ending at the object's left edge
    assert not shadow[:, 150:].any()


def test_ray_casting_is_exact_for_a_box_and_a_cylinder() -> None:
    K = scaled_intrinsics((120, 160)).matrix()
    grid = RayGrid.make(np.zeros(3), np.eye(3), K, (120, 160))
    # a cuboid on the optical axis whose front face is the plane z = 2 (no other face is seen),
    # and a vertical cylinder of radius 0.2 at z = 3 to the right
    parts = PartArrays(
        np.array([0, CYL]),
        np.array([[0.0, 0.0, 2.25], [0.6, 0.0, 3.0]]),
        np.array([[0.2, 0.3, 0.25], [0.2, 0.4, 0.2]]),
        np.array([0.0, 0.7]),
        np.array([0, 1]),
        np.zeros(2, np.int64),
        np.ones((2, 3)),
    )
    r = cast(grid, parts, 2)
    face = r.part == 0
    np.testing.assert_allclose(r.t[face], 2.0, atol=1e-5)
    rows, cols = np.nonzero(face)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    assert cols.min() == math.ceil(cx - fx * 0.2 / 2) and cols.max() == math.floor(cx + fx * 0.2 / 2)
    assert rows.min() == math.ceil(cy + fy * -0.3 / 2) and rows.max() == math.floor(cy + fy * 0.3 / 2)
    v, u = np.nonzero(r.part == 1)
    p = backproject(u, v, r.t[v, u], K)
    np.testing.assert_allclose(np.hypot(p[:, 0] - 0.6, p[:, 2] - 3.0), 0.2, atol=1e-4)  # on the cylinder wall
    assert np.all(np.abs(p[:, 1]) <= 0.4 + 1e-5)
    assert r.alone[0] == face.sum() and r.alone[1] == (r.part == 1).sum()


def test_amodal_extent_is_the_tight_box_of_all_parts() -> None:
    rng = np.random.default_rng(1)
    for cls, build in fu.BUILDERS.items():
        for _ in range(5):
            item = build(rng)
            assert item.cls == cls and np.all(item.size > 0)
            pts = []
            for p in item.parts:  # sample each part's outline in the object frame
                a = np.linspace(0, 2 * math.pi, 64, endpoint=False)
                if p.kind == CYL:
                    lx, lz = p.half[0] * np.cos(a), p.half[2] * np.sin(a)
                else:
                    sx, sz = np.meshgrid([-1.0, 1.0], [-1.0, 1.0])
                    lx, lz = sx.ravel() * p.half[0], sz.ravel() * p.half[2]
                c, s = math.cos(p.yaw), math.sin(p.yaw)
                x, z = p.centre[0] + c * lx + s * lz, p.centre[2] - s * lx + c * lz
                for h in (p.centre[1] - p.half[1], p.centre[1] + p.half[1]):
                    pts.append(np.stack([x, np.full_like(x, h), z], 1))
            pts = np.concatenate(pts)
            np.testing.assert_allclose(pts.min(0), item.lo, atol=2e-3)
            np.testing.assert_allclose(pts.max(0), item.hi, atol=2e-3)


def test_layouts_follow_the_placement_rules() -> None:
    """No two objects' boxes intersect (checked on a 1 cm raster of the footprints), except a
    child with the object it stands on; everything is inside the room and on a support."""
    for seed in range(12):
        _, L = furnish(np.random.default_rng(seed))
        room = L.room
        W, D = math.ceil(room.width * 100) + 2, math.ceil(room.depth * 100) + 2
        masks = []
        for p in L.objects:
            m = np.zeros((D, W), np.uint8)
            poly = np.array([[x * 100, z * 100] for x, z in p.footprint(-0.012)], np.float64)
            cv2.fillConvexPoly(m, np.round(poly * 16).astype(np.int32), 1, shift=4)
            masks.append(m.astype(bool))
            assert p.h0 >= -1e-6 and p.h1 <= room.height
            fp = np.array(p.footprint())
            assert (
                fp.min() >= -1e-6
                and fp[:, 0].max() <= room.width + 1e-6
                and fp[:, 1].max() <= room.depth + 1e-6
            )
            if p.parent >= 0:  # stands on its parent's top surface
                par = L.objects[p.parent]
                assert (
                    any(abs(p.base - (par.base + s.h)) < 1e-9 for s in par.item.surfaces)
                    or p.item.cls == "sink"
                )
        for i, a in enumerate(L.objects):
            for j in range(i):
                b = L.objects[j]
                if not (a.item.collides and b.item.collides) or a.parent == j or b.parent == i:
                    continue
                if min(a.h1, b.h1) - max(a.h0, b.h0) > 1e-3:
                    assert not (masks[i] & masks[j]).any(), (seed, a.item.cls, b.item.cls)


def _class_dependence_p_values(config: SceneConfig) -> np.ndarray:
    """Permutation p-values of the class-dependence of the texture kind and of the brightness of
    each object's first material slot, over 40 rooms: the share of 200 shufflings of the class
    labels within each room (which keep the rooms' shared palettes) whose chi-square of class x
    kind counts, and whose between-class variance of the luminance, reach the observed ones."""
    rooms, classes, kinds, lums = [], [], [], []
    for seed in range(40):
        rng = np.random.default_rng(seed)
        _, L = furnish(rng)
        placed = [p for p in L.objects if p.render]
        pose = CameraPose(L.room.width / 2, L.room.depth / 2, 1.5, 0.0, -0.3, 0.0)
        parts, mats, _ = build_parts(placed, pose, rng, config)
        for i, p in enumerate(placed):
            if p.item.cls is None:
                continue
            first = parts.material[np.flatnonzero(parts.obj == i)[0]]
            rooms.append(seed)
            classes.append(CLASSES.index(p.item.cls))
            kinds.append(int(mats.kind[first]))
            lums.append(float(mats.texture[first].mean()))
    rooms_a, kinds_a, lums_a = np.array(rooms), np.array(kinds), np.array(lums)
    onehot = np.eye(8)[kinds_a]

    def dependence(labels: np.ndarray) -> tuple[float, float]:
        counts = np.zeros((len(CLASSES), 8))
        np.add.at(counts, labels, onehot)
        expected = counts.sum(1, keepdims=True) * counts.sum(0, keepdims=True) / counts.sum()
        chi2 = np.sum((counts - expected) ** 2 / np.maximum(expected, 1e-9))
        n = np.bincount(labels, minlength=len(CLASSES))
        means = np.bincount(labels, lums_a, minlength=len(CLASSES)) / np.maximum(n, 1)
        return chi2, float(np.sum(n * (means - lums_a.mean()) ** 2))

    observed = dependence(np.array(classes))
    rng = np.random.default_rng(0)
    shuffled = []
    for _ in range(200):
        labels = np.array(classes)
        for r in np.unique(rooms_a):
            idx = np.flatnonzero(rooms_a == r)
            labels[idx] = labels[rng.permutation(idx)]
        shuffled.append(dependence(labels))
    assert len(classes) > 300
    return (np.array(shuffled) >= np.array(observed)).mean(axis=0)


@pytest.mark.slow  # renders many frames
def test_materials_do_not_depend_on_the_class() -> None:
    """By default texture kind and brightness are independent of the class (not extreme among
    the shufflings), and with class-typical appearance both depend on it (more than all 200)."""
    assert (_class_dependence_p_values(SceneConfig()) > 0.01).all()
    assert (_class_dependence_p_values(SceneConfig(appearance="typical")) == 0.0).all()


@pytest.mark.slow  # renders many frames
def test_typical_appearance_gives_ceramic_toilets_and_dark_screens() -> None:
    """With typical_share 1 every toilet, sink and bathtub is ceramic (bright, unsaturated,
    glossy) in its first slot and every monitor and television dark; the default never ties
    them so (some are dark, some saturated)."""
    config = SceneConfig(appearance="typical", typical_share=1.0)
    seen: dict[str, list[tuple[float, float, float]]] = {"ceramic": [], "screen": []}
    plain: list[float] = []
    for seed in range(60):
        rng = np.random.default_rng(seed)
        _, L = furnish(rng, "bathroom" if seed % 2 else "office")
        placed = [p for p in L.objects if p.render]
        pose = CameraPose(L.room.width / 2, L.room.depth / 2, 1.5, 0.0, -0.3, 0.0)
        for cfg in (config, SceneConfig()):
            parts, mats, _ = build_parts(placed, pose, np.random.default_rng(seed), cfg)
            for i, p in enumerate(placed):
                family = {"toilet": "ceramic", "sink": "ceramic", "bathtub": "ceramic",
                          "monitor": "screen", "television": "screen"}.get(p.item.cls)  # fmt: skip
                if family is None:
                    continue
                own = zip(np.flatnonzero(parts.obj == i), p.item.parts, strict=True)
                m = parts.material[next(k for k, q in own if q.slot == 0)]
                albedo = mats.texture[m, 0].reshape(-1, 3).mean(axis=0)
                if cfg is config:
                    spread = float(albedo.max() - albedo.min())
                    seen[family].append((float(albedo.mean()), spread, float(mats.gloss[m])))
                else:
                    plain.append(float(albedo.mean()))
    ceramic, screen = np.array(seen["ceramic"]), np.array(seen["screen"])
    assert len(ceramic) >= 20 and len(screen) >= 10
    assert (ceramic[:, 0] > 0.55).all() and (ceramic[:, 1] < 0.12).all() and (ceramic[:, 2] >= 0.35).all()
    assert (screen[:, 0] < 0.02).all() and (screen[:, 2] >= 0.3).all()
    assert min(plain) < 0.05 < 0.5 < max(plain)


def test_class_families_cover_every_class_with_known_families() -> None:
    assert set(CLASS_FAMILIES) == set(CLASSES)
    for slots in CLASS_FAMILIES.values():
        assert slots and all(0 <= k < N_SLOTS for k in slots)
        assert all(f in FAMILIES for families in slots.values() for f in families)
    for family in FAMILIES.values():
        assert set(family.kinds) <= set(KINDS) and abs(sum(family.weights) - 1) < 1e-9
    with pytest.raises(ValueError, match="appearance"):
        SceneConfig(appearance="class-coloured")
    with pytest.raises(ValueError, match="typical_share"):
        SceneConfig(typical_share=1.5)


def test_frames_are_deterministic_per_seed(frames) -> None:
    again = generate_frame(SEEDS[0])
    np.testing.assert_array_equal(again.color, frames[0].color)
    np.testing.assert_array_equal(again.depth, frames[0].depth)
    np.testing.assert_array_equal(again.gt.boxes3d, frames[0].gt.boxes3d)
    assert not np.array_equal(frames[1].color, frames[0].color)


@pytest.mark.slow  # worker processes
def test_cli_writes_the_same_set_with_any_worker_count(tmp_path) -> None:
    args = ["--frames", "4", "--seed", "5", "--split", "test=0.5", "--size", "96x128"]
    assert main([str(tmp_path / "a"), *args, "--workers", "1"]) == 0
    assert main([str(tmp_path / "b"), *args, "--workers", "2"]) == 0
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    assert len(files) > 10
    for rel in files:
        assert (tmp_path / "a" / rel).read_bytes() == (tmp_path / "b" / rel).read_bytes(), rel
    refs = {s: list_frames(tmp_path / "a" / s) for s in ("train", "test")}
    assert len(refs["train"]) == 2 and len(refs["test"]) == 2
    config = replace(SceneConfig(), image_size=(96, 128), intrinsics=scaled_intrinsics((96, 128)))
    ref = refs["test"][0]
    frame = read_frame(ref, read_folder_intrinsics(tmp_path / "a" / "test"))
    direct = generate_frame(frame_seed(5, int(ref.name.split("_")[1])), config)
    np.testing.assert_array_equal(frame.color, direct.color)
    np.testing.assert_allclose(frame.depth, direct.depth, atol=5e-4)  # millimetre PNG
    gt = read_ground_truth(ref)
    np.testing.assert_allclose(gt.boxes3d, direct.gt.boxes3d)
    np.testing.assert_array_equal(read_instances(ref), direct.instances)
    assert np.all(box_area_2d(gt.boxes2d_visible) > 0)
    assert main(["--stats", str(tmp_path / "a")]) == 0
    # Class-typical appearance draws other materials for the same scenes: same ground truth.
    assert main([str(tmp_path / "c"), *args, "--appearance", "typical"]) == 0
    for split in ("train", "test"):
        for a, c in zip(refs[split], list_frames(tmp_path / "c" / split), strict=True):
            assert c.gt_path.read_bytes() == a.gt_path.read_bytes()
            assert c.color_path.read_bytes() != a.color_path.read_bytes()


def test_cli_sensor_option_picks_the_depth_error_model(tmp_path) -> None:
    """--sensor kinect-v1 writes the Kinect v1 model's depth; colour and ground truth are the same."""
    args = ["--frames", "1", "--seed", "9", "--split", "test=1", "--size", "96x128"]
    assert main([str(tmp_path / "a3d"), *args]) == 0
    assert main([str(tmp_path / "kinect"), *args, "--sensor", "kinect-v1"]) == 0
    config = replace(
        SceneConfig(),
        image_size=(96, 128),
        intrinsics=scaled_intrinsics((96, 128)),
        depth_sensor=SENSORS["kinect-v1"],
    )
    direct = generate_frame(frame_seed(9, 0), config)
    folders = {name: tmp_path / name / "test" for name in ("a3d", "kinect")}
    read = {n: read_frame(list_frames(d)[0], read_folder_intrinsics(d)) for n, d in folders.items()}
    np.testing.assert_allclose(read["kinect"].depth, direct.depth, atol=5e-4)
    assert np.abs(read["a3d"].depth - direct.depth).max() > 0.01
    np.testing.assert_array_equal(read["a3d"].color, read["kinect"].color)


def test_tiny_objects_are_rendered_but_not_annotated_and_noise_can_be_off() -> None:
    config = replace(SceneConfig(), min_visible_px=10**9, noise=False)
    f = generate_frame(SEEDS[0], config)
    assert len(f.gt) == 0 and not f.instances.any() and f.objects
    np.testing.assert_array_equal(f.depth, f.depth_exact)


def test_box_and_cylinder_helpers_validate_extents() -> None:
    with pytest.raises(ValueError):
        box(0, 0, 0, 1, 0, 1)
    with pytest.raises(ValueError):
        cyl(0, 0, -0.1, 0, 1)
    with pytest.raises(ValueError):
        Furniture("chair", [])


def test_stats_summary_counts_what_it_says() -> None:
    def obj(cls: str, vis: float, cut: bool, annotated: bool = True) -> dict:
        return {"class": cls, "annotated": annotated, "visibility": vis, "truncated": cut}

    records = [
        {
            "room": "office",
            "depth_missing": 0.1,
            "objects": [obj("chair", 0.5, True), obj("chair", 0.9, False)],
        },
        {
            "room": "bedroom",
            "depth_missing": 0.3,
            "objects": [obj("bed", 1.0, True), obj("lamp", 0.0, False, False)],
        },
    ]
    s = summarise(records)
    assert s.frames == 2 and s.annotated_per_frame == 1.5
    assert s.occluded_share == pytest.approx(1 / 3) and s.truncated_share == pytest.approx(2 / 3)
    assert s.class_counts["chair"] == 2 and s.class_counts["lamp"] == 0 and s.most_frequent == "chair"
    assert "bathtub" in s.missing_classes and s.depth_missing == pytest.approx(0.2)
    assert s.unannotated_share == pytest.approx(0.25)
    checks = s.checks()
    assert not checks["annotated objects per frame >= 8"] and checks["chair most frequent"]
