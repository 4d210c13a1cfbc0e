"""Live rerun view of a3d's frames and detections.

One entity tree per recording, on a ``frame`` sequence timeline:

- ``world``: the gravity-aligned tilt frame (x right, y down along gravity, z forward; RDF),
  with the annotation context that gives every class its name and colour.
- ``world/points``: the coloured point cloud, back-projected and rotated into the world frame.
- ``world/detections``: the detected amodal 3D boxes, labelled with class and score.
- ``world/ground_truth``: the ground-truth 3D boxes when the frame has them.
- ``world/camera``: the camera pose (``p_world = R_tilt p_cam``), and under it
  ``world/camera/image`` the pinhole with the colour image, the depth image, the 2D boxes,
  the 3D boxes projected into the image as line strips, and ``world/camera/image/labels``:
  one "class score" label per detection at the top of its 2D box (the only labels the 2D
  views show: rerun would write one under each 2D box and a class name on every edge).
- ``map`` (``a3d-run --map`` on a posed source): the object map's gravity-aligned frame
  (a3d.runtime.mapping.object_map), with ``map/objects`` its fused boxes, ``map/trajectory`` the
  camera's path so far and ``map/camera`` the moving camera (its pose, and a frustum under it).

The default blueprint opens on the 3D view beside the camera's 2D view. The flags that ask for
it, and the import of this module, are in a3d.runtime.viewer.options (rerun is an optional extra);
the shapes it logs (labels, projected boxes) in a3d.runtime.viewer.shapes, which needs no rerun.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from a3d.runtime.errors import InputError
from a3d.runtime.structures.boxes import CENTER, THETA, boxes_array, local_half_sizes
from a3d.runtime.structures.classes import CLASS_COLORS_RGB, CLASSES, to_softmax
from a3d.runtime.structures.geometry import BOX_EDGES, Intrinsics, backproject_depth
from a3d.runtime.viewer.shapes import ViewOptions, box_labels, label_anchors, projected_box_edges

APPLICATION_ID = "a3d"
DEFAULT_OPTIONS = ViewOptions()
BOX_LINE_RADIUS_M = 0.006  # box edges about as thick as the cloud's points (radius 8 mm)
GROUND_TRUTH_RGB = (255, 255, 255)  # ground truth in one neutral colour, apart from the class colours


def default_blueprint(with_map: bool = False) -> rrb.Blueprint:
    """3D view of the world beside the camera's view (colour + boxes) and its depth view; with
    ``with_map`` a 3D view of the object map too (under the world's).

    The depth image is kept out of the 3D view (rerun would lift it into a second, rainbow point
    cloud over ``world/points``) and out of the colour view (it would cover the photo).
    """
    no_depth = "- world/camera/image/depth"
    world: rrb.Container | rrb.View = rrb.Spatial3DView(
        name="3D",
        origin="world",
        contents=["+ world/**", no_depth],
        eye_controls=rrb.EyeControls3D(
            position=(0.0, -1.0, -1.5), look_target=(0.0, 0.5, 3.0), eye_up=(0.0, -1.0, 0.0)
        ),
    )
    if with_map:
        world = rrb.Vertical(world, rrb.Spatial3DView(name="map", origin="map", contents=["+ map/**"]))
    return rrb.Blueprint(
        rrb.Horizontal(
            world,
            rrb.Vertical(
                rrb.Spatial2DView(
                    name="camera", origin="world/camera/image", contents=["+ world/camera/image/**", no_depth]
                ),
                rrb.Spatial2DView(
                    name="depth",
                    origin="world/camera/image",
                    contents=[
                        "world/camera/image/depth",
                        "world/camera/image/detections",
                        "world/camera/image/labels",
                    ],
                ),
            ),
            column_shares=[3, 2],
        ),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed"),
    )


def open_recording(args: argparse.Namespace, grpc_url: str | None = None) -> rr.RecordingStream:
    """Start the recording on the sink the flags name, with the default blueprint; with
    ``grpc_url``, on the viewer a3d started there (a3d.runtime.viewer.launch) instead."""
    if args.save:
        Path(args.save).parent.mkdir(parents=True, exist_ok=True)
    blueprint = default_blueprint(with_map=getattr(args, "map", None) is not None)
    if grpc_url is None:
        return rr.script_setup(args, APPLICATION_ID, default_blueprint=blueprint)
    recording = rr.RecordingStream(APPLICATION_ID)
    recording.connect_grpc(grpc_url, default_blueprint=blueprint)
    return recording


def close_recording(args: argparse.Namespace, rec: rr.RecordingStream, own_viewer: bool = False) -> None:
    """With the SDK's --serve keep serving until Ctrl-C (its script teardown), then disconnect; a
    viewer a3d started (``own_viewer``, a3d.runtime.viewer.launch) keeps the data itself."""
    if not own_viewer:
        rr.script_teardown(args)
    rr.disconnect(rec)


def class_annotations() -> rr.AnnotationContext:
    """Every class's name and colour (class id = softmax index = CLASSES index + 1)."""
    return rr.AnnotationContext(
        [
            rr.AnnotationInfo(id=int(to_softmax(i)), label=name, color=CLASS_COLORS_RGB[i])
            for i, name in enumerate(CLASSES)
        ]
    )


def log_static(rec: rr.RecordingStream) -> None:
    """World (and map) axes and the class annotation context; both are gravity-aligned with y
    down, rerun's RDF."""
    for root in ("world", "map"):
        rec.log(root, rr.ViewCoordinates.RDF, static=True)
        rec.log(root, class_annotations(), static=True)


def log_detections(
    rec: rr.RecordingStream | None,
    entity_path: str,
    *,
    class_ids: np.ndarray,
    scores: np.ndarray,
    boxes3d: np.ndarray,
    R_tilt: np.ndarray,
) -> None:
    """Detected 3D boxes at ``entity_path`` as ``log_frame`` logs them (``FrameDetections.log``),
    with the class annotations on the entity itself so the colours hold wherever it is logged;
    ``rec`` None: rerun's current recording."""
    rec = rec if rec is not None else rr.get_data_recording()
    if rec is None:
        raise InputError("recording: rerun has none yet; call rr.init('a3d', spawn=True) first or pass one")
    rec.log(entity_path, class_annotations(), static=True)
    labels = box_labels(class_ids, scores)
    rec.log(entity_path, boxes3d_archetype(boxes3d, R_tilt, class_ids, labels))


def _yaw_rotations(theta: np.ndarray) -> list[rr.RotationAxisAngle]:
    # Corners are rotated about +y by theta with the right-handed R_y (docs/conventions.md "3D boxes"):
    # the same axis-angle.
    return [rr.RotationAxisAngle(axis=[0.0, 1.0, 0.0], radians=float(t)) for t in theta]


def boxes3d_archetype(
    boxes: np.ndarray, R_tilt: np.ndarray, class_ids: np.ndarray, labels: list[str]
) -> rr.Boxes3D:
    """Boxes3D in the world (tilt) frame: centre R_tilt c, half sizes (l, h, w)/2, yaw about y.

    Drawn as thin wireframes (never solid or translucent faces), so the point cloud inside and
    behind every box stays visible."""
    boxes = boxes_array(boxes)
    return rr.Boxes3D(
        fill_mode=rr.components.FillMode.MajorWireframe,
        radii=BOX_LINE_RADIUS_M,
        centers=boxes[:, CENTER] @ np.asarray(R_tilt).T,
        half_sizes=local_half_sizes(boxes),
        rotation_axis_angles=_yaw_rotations(boxes[:, THETA]),
        class_ids=to_softmax(np.asarray(class_ids, dtype=np.uint16)),
        labels=labels,
        show_labels=True,
    )


def log_frame(
    rec: rr.RecordingStream,
    index: int,
    *,
    color: np.ndarray,
    depth_m: np.ndarray,
    K: Intrinsics,
    R_tilt: np.ndarray,
    class_ids: np.ndarray,
    scores: np.ndarray,
    boxes2d: np.ndarray,
    boxes3d: np.ndarray,
    gt_class_ids: np.ndarray | None = None,
    gt_boxes3d: np.ndarray | None = None,
    proposals: np.ndarray | None = None,
    options: ViewOptions = DEFAULT_OPTIONS,
) -> None:
    """Log one processed frame at sequence ``index`` of the ``frame`` timeline.

    ``color`` is BGR uint8, ``depth_m`` raw depth in metres (0 = missing), ``class_ids`` 0-based
    indices into CLASSES, ``boxes2d`` in the README's pixel coordinates, ``boxes3d`` 7-vectors in
    the camera frame with yaw in the tilt frame of ``R_tilt``.
    """
    height, width = depth_m.shape
    R_tilt = np.asarray(R_tilt, dtype=np.float64)
    class_ids = np.asarray(class_ids, dtype=np.int64).reshape(-1)
    rec.set_time("frame", sequence=index)

    rec.log("world/camera", rr.Transform3D(mat3x3=R_tilt))
    rec.log(
        "world/camera/image",
        rr.Pinhole(
            image_from_camera=K.matrix(), resolution=[width, height], camera_xyz=rr.ViewCoordinates.RDF
        ),
    )
    rec.log("world/camera/image/color", rr.Image(color, color_model="BGR"))
    rec.log("world/camera/image/depth", rr.DepthImage(depth_m.astype(np.float32), meter=1.0))

    s = max(1, options.cloud_stride)
    points = backproject_depth(depth_m[::s, ::s], _strided_intrinsics(K, s))
    valid = depth_m[::s, ::s] > 0
    rgb = color[::s, ::s, ::-1][valid]
    rec.log("world/points", rr.Points3D(points[valid] @ R_tilt.T, colors=rgb, radii=0.008))

    shown = np.asarray(scores).reshape(-1) >= options.min_score
    class_ids, scores = class_ids[shown], np.asarray(scores).reshape(-1)[shown]
    boxes2d = np.asarray(boxes2d, dtype=np.float64).reshape(-1, 4)[shown]
    boxes3d = boxes_array(boxes3d)[shown]
    labels = box_labels(class_ids, scores)
    rec.log("world/detections", boxes3d_archetype(boxes3d, R_tilt, class_ids, labels))
    rec.log(
        "world/camera/image/detections",
        rr.Boxes2D(
            array=boxes2d,
            array_format=rr.Box2DFormat.XYXY,
            class_ids=to_softmax(class_ids),
            labels=labels,  # for hovering; written once per detection by the labels entity
            show_labels=False,
        ),
    )
    rec.log(
        "world/camera/image/labels",
        rr.Points2D(
            label_anchors(boxes2d),
            radii=0.0,
            class_ids=to_softmax(class_ids),
            labels=labels,
            show_labels=True,
        ),
    )
    segments = projected_box_edges(boxes3d, R_tilt, K, (height, width))
    keep = np.isfinite(segments).all(axis=(1, 2))
    edge_ids = np.repeat(to_softmax(class_ids), len(BOX_EDGES))[keep]  # the class colours, not names
    rec.log(
        "world/camera/image/boxes3d", rr.LineStrips2D(segments[keep], class_ids=edge_ids, show_labels=False)
    )
    if options.show_ground_truth and gt_boxes3d is not None and gt_class_ids is not None:
        gt_ids = np.asarray(gt_class_ids, dtype=np.int64).reshape(-1)
        gt = boxes3d_archetype(gt_boxes3d, R_tilt, gt_ids, [f"GT {CLASSES[c]}" for c in gt_ids])
        rec.log("world/ground_truth", gt, rr.Boxes3D.from_fields(colors=GROUND_TRUTH_RGB))
    if options.max_proposals and proposals is not None:
        rec.log(
            "world/camera/image/proposals",
            rr.Boxes2D(
                array=np.asarray(proposals)[: options.max_proposals], array_format=rr.Box2DFormat.XYXY
            ),
        )


def log_map(
    rec: rr.RecordingStream,
    index: int,
    *,
    camera_pose: np.ndarray,
    K: Intrinsics,
    image_size: tuple[int, int],
    trajectory: np.ndarray,
    class_ids: np.ndarray,
    boxes: np.ndarray,
    labels: list[str],
) -> None:
    """Log the object map at sequence ``index``: the camera at ``camera_pose`` (4 x 4, camera to the
    map's frame) with a frustum, its ``trajectory`` (N, 3) so far, and the map's ``boxes`` (N, 7,
    7-vectors in the map's frame, which is its own tilt frame)."""
    rec.set_time("frame", sequence=index)
    rec.log("map/camera", rr.Transform3D(translation=camera_pose[:3, 3], mat3x3=camera_pose[:3, :3]))
    height, width = image_size
    rec.log(
        "map/camera/frustum",
        rr.Pinhole(
            image_from_camera=K.matrix(),
            resolution=[width, height],
            camera_xyz=rr.ViewCoordinates.RDF,
            image_plane_distance=0.4,
        ),
    )
    rec.log(
        "map/trajectory", rr.LineStrips3D([np.asarray(trajectory, np.float64).reshape(-1, 3)], radii=0.01)
    )
    rec.log("map/objects", boxes3d_archetype(boxes, np.eye(3), class_ids, labels))


def _strided_intrinsics(K: Intrinsics, stride: int) -> Intrinsics:
    # Pixel (u', v') of the strided image is pixel (stride u', stride v') of the full one.
    return Intrinsics(fx=K.fx / stride, fy=K.fy / stride, cx=K.cx / stride, cy=K.cy / stride)
