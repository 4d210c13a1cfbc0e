"""The cluttered world of a3d-synth: objects of no class, rooms without classes, camera presets
and their depth families, real light, the CLI options and their statistics."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from a3d.runtime.sources.folder import list_frames, read_folder_intrinsics, read_frame, read_ground_truth
from a3d.synth import SceneConfig, generate_frame
from a3d.synth import unlabelled as un
from a3d.synth.agreement import sensed_inside_shares
from a3d.synth.cli import frame_seed, main
from a3d.synth.depth_families import depth_edges, sense
from a3d.synth.devices import DEVICES
from a3d.synth.layout import Layout, Room
from a3d.synth.raycast import PartArrays
from a3d.synth.shading import sun_shadow
from a3d.synth.stats import read_records, summarise
from a3d.synth.world import EMPTY_ROOM, add_clutter, furnish_world

SMALL = (96, 128)


def test_clutter_builders_make_unlabelled_objects_standing_on_their_base() -> None:
    rng = np.random.default_rng(0)
    builders = [
        un.shelving,
        un.filing_cabinet,
        un.partition,
        un.radiator,
        un.wall_panel,
        un.floor_plant,
        un.bag,
        un.coat_stand,
        un.stool,
        un.bench,
        un.pouf,
        un.electronics,
        un.bottle,
    ]
    for build in builders:
        for _ in range(20):
            item = build(rng)
            assert item.cls is None
            assert abs(item.lo[1]) < 0.031 and 0.01 < item.hi[1] < 2.2  # on its base (a tray may hang 3 cm)
            assert np.all(item.size < 2.5)


def test_clutter_is_added_after_the_classes_and_keeps_the_placement_rules() -> None:
    kind0, plain = furnish_world(np.random.default_rng(21), None, 0)
    kind1, cluttered = furnish_world(np.random.default_rng(21), None, 30)
    assert kind0 == kind1
    n = len(plain.objects)
    assert [p.item.cls for p in cluttered.objects[:n]] == [p.item.cls for p in plain.objects]
    added = cluttered.objects[n:]
    assert len(added) >= 20 and all(p.item.cls is None for p in added)
    for i in range(n, len(cluttered.objects)):  # each fits (placement rules) among those before it
        before = Layout(cluttered.room, cluttered.rng)
        before.objects = cluttered.objects[:i]
        assert before.fits(cluttered.objects[i], margin=0.0)


def test_rooms_without_classes_hold_clutter_only() -> None:
    kind, L = furnish_world(np.random.default_rng(4), None, 25, labelled=False)
    assert kind == EMPTY_ROOM and all(p.item.cls is None for p in L.objects) and len(L.objects) >= 15
    frame = generate_frame(
        7,
        SceneConfig(
            clutter=25, labelled=False, image_size=SMALL, intrinsics=DEVICES["kinect-v1"].frame(0.2)[1]
        ),
    )
    assert len(frame.gt) == 0 and not frame.instances.any() and frame.unlabelled > 0


def test_clutter_outnumbers_the_annotated_objects_in_view() -> None:
    config = SceneConfig(clutter=30)
    frames = [generate_frame(frame_seed(0, i), config) for i in range(4)]
    assert sum(f.unlabelled >= len(f.gt) for f in frames) >= 3
    plain = [generate_frame(frame_seed(0, i)) for i in range(4)]
    assert sum(f.unlabelled for f in frames) > 2 * sum(f.unlabelled for f in plain)


def test_add_clutter_stops_at_n_or_when_nothing_fits() -> None:
    L = Layout(Room(3.0, 3.0, 2.6), np.random.default_rng(0))
    assert add_clutter(L, 5) == 5 == len(L.objects)
    tiny = Layout(Room(0.3, 0.3, 0.5), np.random.default_rng(0))
    assert add_clutter(tiny, 10) < 10


def test_device_intrinsics_give_the_preset_field_of_view() -> None:
    for d in DEVICES.values():
        (H, W), K = d.frame(0.5)
        assert (H, W) == (round(d.size[0] / 2), round(d.size[1] / 2))
        fov = 2 * np.degrees(np.arctan((W / 2) / K.fx))
        assert fov == pytest.approx(d.hfov_deg, abs=1e-6)


def _plane_scene(H: int = 120, W: int = 160) -> tuple[np.ndarray, np.ndarray]:
    """A wall at 3 m with a box at 1.5 m in front: exact depth and a flat albedo."""
    z = np.full((H, W), 3.0, np.float32)
    z[40:80, 60:100] = 1.5
    return z, np.full((H, W), 0.5, np.float32)


def test_depth_families_fail_each_in_their_own_way() -> None:
    z, lum = _plane_scene()
    ones = np.ones_like(z)
    fx = 120.0
    edge = depth_edges(z)
    tof = sense(np.random.default_rng(0), z, fx, lum, ones, DEVICES["kinect-v2"].depth)
    ok = (tof > 0) & edge
    between = ok & (tof > 1.6) & (tof < 2.9)
    assert between.sum() > 0.2 * ok.sum()  # flying pixels: depths between box and wall
    assert not (tof[:, :10] > 0).any()  # outside the narrower depth field
    sl = sense(np.random.default_rng(0), z, fx, lum, ones, DEVICES["kinect-v1"].depth)
    assert ((sl > 1.6) & (sl < 2.9)).sum() < 0.05 * between.sum()  # structured light: no flying pixels
    stereo = sense(np.random.default_rng(0), z, fx, lum, ones, DEVICES["realsense-d435"].depth)
    textured = lum + 0.3 * np.random.default_rng(1).random(z.shape).astype(np.float32)
    stereo_tex = sense(np.random.default_rng(0), z, fx, textured, ones, DEVICES["realsense-d435"].depth)
    wall = z == 3.0
    assert (stereo[wall] == 0).mean() > (stereo_tex[wall] == 0).mean() + 0.2  # plain walls lose depth
    far = np.full_like(z, 6.0)
    lidar = sense(np.random.default_rng(0), far, fx, lum, ones, DEVICES["iphone-lidar"].depth)
    assert not lidar.any()  # beyond the LiDAR's 5 m
    with pytest.raises(ValueError, match="family"):
        sense(np.random.default_rng(0), z, fx, lum, ones, replace(DEVICES["kinect-v2"].depth, family="sonar"))


def test_real_world_frames_keep_boxes_and_depth_in_agreement() -> None:
    """With a ToF camera, daylight and clutter, annotated objects' sensed depth still lies mostly
    in their boxes (flying pixels and multipath move some of it), and colour is a JPEG'd photo."""
    size, K = DEVICES["azure-kinect"].frame(0.5)
    config = SceneConfig(
        image_size=size,
        intrinsics=K,
        depth_sensor=DEVICES["azure-kinect"].depth,
        clutter=30,
        real_light=True,
        device="azure-kinect",
    )
    frame = generate_frame(frame_seed(2, 1), config)
    shares = [s for _, _, s in sensed_inside_shares(frame)]
    assert len(shares) >= 3 and np.median(shares) > 0.85
    plain = generate_frame(frame_seed(2, 1), replace(config, real_light=False))
    np.testing.assert_array_equal(plain.gt.boxes3d, frame.gt.boxes3d)  # light changes no geometry
    assert frame.device == "azure-kinect"


def test_cli_real_world_writes_per_frame_cameras_and_stats(tmp_path) -> None:
    args = [
        "--frames",
        "6",
        "--seed",
        "2",
        "--split",
        "test=0.5",
        "--world",
        "real",
        "--camera-scale",
        "0.2",
        "--empty-share",
        "0.34",
    ]
    assert main([str(tmp_path / "a"), *args]) == 0
    assert main([str(tmp_path / "b"), *args, "--workers", "2"]) == 0
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    for rel in files:
        assert (tmp_path / "a" / rel).read_bytes() == (tmp_path / "b" / rel).read_bytes(), rel
    records = read_records(tmp_path / "a")
    empty = 0
    for split in ("train", "test"):
        folder = tmp_path / "a" / split
        for ref in list_frames(folder):
            record = next(r for r in records if r["name"] == ref.name)
            frame = read_frame(ref, read_folder_intrinsics(folder))
            (H, W), K = DEVICES[record["camera"]].frame(0.2)
            assert frame.color.shape[:2] == (H, W) and frame.intrinsics.fx == pytest.approx(K.fx)
            empty += len(read_ground_truth(ref)) == 0
    s = summarise(records)
    assert s.frames_without_annotations == empty == 2
    assert s.unlabelled_per_frame == pytest.approx(np.mean([r["unlabelled"] for r in records]))
    assert sum(s.cameras.values()) == 6 and set(s.cameras) <= set(DEVICES)
    assert main(["--stats", str(tmp_path / "a")]) == 0


def test_cli_rejects_bad_world_options(tmp_path, capsys) -> None:
    for bad in (
        ["--camera-mix", "kinect-v9"],
        ["--clutter", "-1"],
        ["--empty-share", "2"],
        ["--world", "real", "--size", "96x128"],
        ["--camera-mix", "kinect-v2", "--sensor", "kinect-v1"],
    ):
        with pytest.raises(SystemExit):
            main([str(tmp_path / "x"), "--frames", "1", *bad])
        assert "--" in capsys.readouterr().err


def test_stats_of_old_records_have_no_unlabelled_count() -> None:
    old = [{"room": "office", "depth_missing": 0.1, "objects": []}]
    s = summarise(old)
    assert s.unlabelled_per_frame is None and s.cameras == {"nyu-crop": 1}
    new = [
        {**old[0], "unlabelled": 3, "camera": "kinect-v2", "depth_family": "tof"},
        {
            **old[0],
            "unlabelled": 0,
            "camera": "kinect-v1",
            "depth_family": "structured-light",
            "objects": [{"class": "chair", "annotated": True, "visibility": 1.0, "truncated": False}],
        },
    ]
    s = summarise(new)
    assert s.unlabelled_per_frame == 1.5 and s.more_unlabelled_share == 0.5
    assert s.at_least_as_many_unlabelled_share == 0.5 and s.frames_without_annotations == 1
    assert s.depth_families == {"tof": 1, "structured-light": 1}


def test_sun_shadow_falls_along_the_light_direction() -> None:
    """A 0.4 m cube standing on the floor (tilt y = 1.5 down to the floor), sun slanting 45 deg
    towards +x: floor points under the shifted cube (x + 0.4 .. 0.8 m) are dark, others lit."""
    parts = PartArrays(
        np.array([0]),
        np.array([[0.0, 1.3, 3.0]]),
        np.array([[0.2, 0.2, 0.2]]),
        np.zeros(1),
        np.zeros(1, np.int64),
        np.zeros(1, np.int64),
        np.ones((1, 3)),
    )
    xs = np.linspace(-1.0, 1.5, 26, dtype=np.float32)
    points = np.stack([xs, np.full_like(xs, 1.5), np.full_like(xs, 3.0)])[:, None, :]  # (3, 1, 26) floor
    lit = sun_shadow(points, np.array([1.0, 1.0, 0.0]), parts, 1, np.array([0.0, 1.0, 3.0]), 3.0)[0]
    shadowed = (xs > 0.3) & (xs < 0.5)  # under the cube's top, slid 0.2-0.6 m along x, well inside
    assert (lit[shadowed] < 0.2).all() and (lit[(xs < -0.3) | (xs > 0.8)] > 0.9).all()
