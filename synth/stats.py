"""Statistics of a generated set, against the NYUv2-like targets the generator aims at.

``a3d-synth`` writes one JSON line per frame to ``OUT/synth_objects.jsonl`` (``frame_record``):
the frame's name, split, seed, room type, missing-depth fraction, and per rendered object of a
class its visible and unoccluded pixel counts, visibility and whether it is cut by the image
border (definitions in ``a3d.synth.scene``). ``summarise`` turns those lines into the numbers
below; ``format_summary`` prints them with the targets:

* annotated objects per frame: mean >= 8;
* share of annotated objects less than 70% visible: >= 30%;
* share of annotated objects cut by the image border: >= 15%;
* chair the most frequent class, every class present.

It also reports what the cluttered world (``--world real``) adds, without targets for the
default world: objects of no class per frame (``SynthFrame.unlabelled``) and the share of
frames with more of them than annotated objects, the frames without any annotated object, and
the mix of camera presets and depth-sensor families. Records written before these keys existed
count as default-camera, structured-light frames without an unlabelled count.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from a3d.runtime.structures.classes import CLASSES
from a3d.synth.devices import DEVICES
from a3d.synth.scene import SynthFrame

DEFAULT_CAMERA = "nyu-crop"  # frames without a camera preset: NYUv2 crop intrinsics at --size

RECORDS_FILE = "synth_objects.jsonl"


def frame_record(name: str, split: str, seed: int, frame: SynthFrame) -> dict:
    """The JSON-ready statistics line of one frame."""
    return {
        "name": name,
        "split": split,
        "seed": seed,
        "room": frame.room_type,
        "depth_missing": round(float(np.mean(frame.depth == 0)), 4),
        "unlabelled": frame.unlabelled,
        "camera": frame.device or DEFAULT_CAMERA,
        "depth_family": DEVICES[frame.device].depth.family if frame.device else "structured-light",
        "objects": [
            {
                "class": o.cls,
                "annotated": o.annotated,
                "visible_px": o.visible_px,
                "alone_px": o.alone_px,
                "full_px": round(o.full_px, 1),
                "visibility": round(o.visibility, 4),
                "truncated": o.truncated,
            }
            for o in frame.objects
        ],
    }


def read_records(folder: str | Path) -> list[dict]:
    """The records of a generated folder (``FOLDER/synth_objects.jsonl``)."""
    path = Path(folder) / RECORDS_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file (generate the set with a3d-synth first)")
    with path.open() as f:
        return [json.loads(line) for line in f if line.strip()]


@dataclass(frozen=True)
class Summary:
    """Statistics over a set of frames (see the module docstring)."""

    frames: int
    annotated_per_frame: float
    annotated_per_frame_median: float
    occluded_share: float  # annotated objects with visibility < 0.7
    truncated_share: float  # annotated objects cut by the image border
    mean_visibility: float
    class_counts: dict[str, int]  # annotated objects per class, all 19 classes
    rooms: dict[str, int]
    depth_missing: float  # mean share of pixels without depth
    unannotated_share: float  # rendered class objects below the visible-pixel threshold
    unlabelled_per_frame: float | None  # objects of no class in view (None: not recorded)
    more_unlabelled_share: float | None  # frames with more objects of no class than annotated ones
    at_least_as_many_unlabelled_share: float | None
    frames_without_annotations: int
    cameras: dict[str, int]
    depth_families: dict[str, int]

    @property
    def missing_classes(self) -> list[str]:
        return [c for c in CLASSES if self.class_counts[c] == 0]

    @property
    def most_frequent(self) -> str:
        return max(self.class_counts, key=lambda c: self.class_counts[c])

    def checks(self) -> dict[str, bool]:
        """The generator's targets, each True when met."""
        return {
            "annotated objects per frame >= 8": self.annotated_per_frame >= 8,
            "share < 70% visible >= 30%": self.occluded_share >= 0.30,
            "share cut by the border >= 15%": self.truncated_share >= 0.15,
            "chair most frequent": self.most_frequent == "chair",
            "every class present": not self.missing_classes,
        }


def summarise(records: Iterable[dict]) -> Summary:
    """Summary of frame records (``frame_record`` dicts)."""
    records = list(records)
    if not records:
        raise ValueError("summarise: no frames")
    per_frame = [sum(o["annotated"] for o in r["objects"]) for r in records]
    ann = [o for r in records for o in r["objects"] if o["annotated"]]
    everything = [o for r in records for o in r["objects"]]
    n = max(len(ann), 1)
    counts = Counter(o["class"] for o in ann)
    known = [(r["unlabelled"], k) for r, k in zip(records, per_frame, strict=True) if "unlabelled" in r]
    return Summary(
        frames=len(records),
        annotated_per_frame=float(np.mean(per_frame)),
        annotated_per_frame_median=float(np.median(per_frame)),
        occluded_share=sum(o["visibility"] < 0.7 for o in ann) / n,
        truncated_share=sum(bool(o["truncated"]) for o in ann) / n,
        mean_visibility=float(np.mean([o["visibility"] for o in ann])) if ann else 0.0,
        class_counts={c: counts.get(c, 0) for c in CLASSES},
        rooms=dict(Counter(r["room"] for r in records).most_common()),
        depth_missing=float(np.mean([r["depth_missing"] for r in records])),
        unannotated_share=1 - len(ann) / max(len(everything), 1),
        unlabelled_per_frame=float(np.mean([u for u, _ in known])) if known else None,
        more_unlabelled_share=float(np.mean([u > k for u, k in known])) if known else None,
        at_least_as_many_unlabelled_share=float(np.mean([u >= k for u, k in known])) if known else None,
        frames_without_annotations=sum(k == 0 for k in per_frame),
        cameras=dict(Counter(r.get("camera", DEFAULT_CAMERA) for r in records).most_common()),
        depth_families=dict(
            Counter(r.get("depth_family", "structured-light") for r in records).most_common()
        ),
    )


def format_summary(s: Summary) -> str:
    """A human-readable report of a Summary, with the targets marked ok / MISSED."""
    lines = [
        f"frames: {s.frames}",
        f"annotated objects per frame: mean {s.annotated_per_frame:.2f}"
        f", median {s.annotated_per_frame_median:.1f}",
        f"annotated objects < 70% visible: {100 * s.occluded_share:.1f}%"
        f" (mean visibility {s.mean_visibility:.2f})",
        f"annotated objects cut by the image border: {100 * s.truncated_share:.1f}%",
        f"rendered class objects left unannotated (too few visible pixels): {100 * s.unannotated_share:.1f}%",
        f"pixels without depth: {100 * s.depth_missing:.1f}%",
        "rooms: " + ", ".join(f"{k} {v}" for k, v in s.rooms.items()),
        f"frames without annotated objects: {s.frames_without_annotations}",
        "unlabelled objects (no class, in view) per frame: "
        + (
            "not recorded"
            if s.unlabelled_per_frame is None
            else f"mean {s.unlabelled_per_frame:.2f}; frames with more unlabelled than annotated objects "
            f"{100 * s.more_unlabelled_share:.1f}%, with at least as many "
            f"{100 * s.at_least_as_many_unlabelled_share:.1f}%"
        ),
        "cameras: " + ", ".join(f"{k} {v}" for k, v in s.cameras.items()),
        "depth sensor families: " + ", ".join(f"{k} {v}" for k, v in s.depth_families.items()),
        "annotated objects per class:",
    ]
    for c, k in sorted(s.class_counts.items(), key=lambda kv: -kv[1]):
        lines.append(f"  {c:12s} {k:6d}")
    lines.append("targets:")
    lines += [f"  {'ok    ' if ok else 'MISSED'} {name}" for name, ok in s.checks().items()]
    return "\n".join(lines)
