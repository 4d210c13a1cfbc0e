"""a3d-run SOURCE --ray (a3d.runtime.scale): the same file as a plain run, problems, resuming, refusals.

The part files and the source check need no Ray. The rest runs on a local Ray of 2 CPUs with 2
workers of 1 thread each, on a tiny frame folder (tests/helpers/runtime_frames) with one broken
frame, and the pinned model; every line must equal plain a3d-run's on the same frames, all but
its "timing" (seconds per stage, the one field that differs between two runs of one frame).
"""

from __future__ import annotations

import json
import logging
import shutil
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from a3d.runtime.cli import run as run_cli
from a3d.runtime.errors import InputError
from a3d.runtime.extras import installed
from a3d.runtime.io.detections_io import FrameDetections, format_line
from a3d.runtime.scale.parts import Parts
from a3d.runtime.scale.plan import INDEPENDENT_KINDS, check_independent
from a3d.runtime.sources.base import FrameLoader
from a3d.runtime.sources.registry import SourceOptions, open_source
from tests.helpers.runtime_frames import write_scene_folder
from tests.real_formats import jpeg, synth_frames, write_seven_scenes, write_sun_release_frame, write_tum

MODEL = Path(__file__).parent / "data" / "pinned_model.onnx"
FRAMES = [f"f{k}" for k in range(6)]
BROKEN = "zz"  # sorts last: a colour file that is no image
needs_ray = pytest.mark.skipif(not installed("ray"), reason="ray is not installed (pip install 'a3d[ray]')")


def run(argv: list[str]) -> int:
    """main's exit status, whether it returns it or argparse raises SystemExit."""
    try:
        return run_cli.main(argv)
    except SystemExit as e:
        return int(e.code or 0)


def _line(name: str) -> str:
    """A valid detections line without detections."""
    none = np.zeros(0)
    return format_line(
        FrameDetections(name, np.eye(3), none.astype(np.int64), none, np.zeros((0, 4)), np.zeros((0, 7)))
    )


def _without_timing(path: Path) -> list[dict]:
    lines = [json.loads(line) for line in path.read_text().splitlines()]
    assert all("timing" in line for line in lines)  # what is left out below is really there
    return [{key: value for key, value in line.items() if key != "timing"} for line in lines]


# ----------------------------------------------------------------------------- no Ray needed


def test_parts_merge_into_the_resumed_output_in_source_order(tmp_path: Path) -> None:
    output = tmp_path / "out.jsonl"
    output.write_text(f"{_line('a')}\n{_line('d')}\n")  # an earlier run's lines, positions 0 and 3
    parts = Parts(output)
    assert parts.start(resume=True) == set()
    parts.write([(2, _line("c")), (1, _line("b"))])  # a block comes back in any order
    parts.write([(4, _line("e"))])
    parts.write([])  # a block whose frames all failed leaves no file
    assert [p.name for p in parts.files()] == ["000000000001.jsonl", "000000000004.jsonl"]
    assert Parts(output).start(resume=True) == {"b", "c", "e"}
    parts.merge({name: i for i, name in enumerate("abcde")})
    assert output.read_text().splitlines() == [_line(name) for name in "abcde"]
    assert not parts.folder.exists()


def test_a_frame_in_the_output_and_a_part_keeps_the_outputs_line(tmp_path: Path) -> None:
    """A plain a3d-run --resume between an interrupted --ray run and its --resume redid a part's frame."""
    output = tmp_path / "out.jsonl"
    again = _line("b").replace('"timing":{}', '"timing":{"total":1.0}')  # the same frame, another line
    assert again != _line("b")
    output.write_text(f"{_line('a')}\n{again}\n")
    Parts(output).write([(1, _line("b")), (2, _line("c"))])
    Parts(output).merge({"a": 0, "b": 1, "c": 2})
    assert output.read_text().splitlines() == [_line("a"), again, _line("c")]


def test_a_fresh_run_starts_without_the_old_output_or_parts(tmp_path: Path) -> None:
    output = tmp_path / "out.jsonl"
    output.write_text(f"{_line('a')}\n")
    Parts(output).write([(1, _line("b"))])
    parts = Parts(output)
    assert parts.start(resume=False) == set()
    assert output.read_bytes() == b"" and not parts.folder.exists()
    parts.write([(0, _line("a"))])
    parts.merge({"a": 0})
    assert output.read_text() == f"{_line('a')}\n"


def test_only_sources_every_worker_can_read_are_spread(tmp_path: Path) -> None:
    check_independent(write_scene_folder(tmp_path / "frames", ["f0"]))  # a frame folder: fine
    with pytest.raises(InputError, match=r"^realsense: ray_detect needs frames that every worker can list "
                       r"and read on its own .*a RealSense camera .* streams its frames once"):  # fmt: skip
        check_independent("realsense")
    with pytest.raises(InputError, match="a bag is read front to back through one reader"):
        check_independent(tmp_path / "run.bag", "bag")


def test_a_worker_finds_frames_by_position_and_names_a_changed_source() -> None:
    from a3d.runtime.scale.ray_run import _Cursor

    passes = []

    class Source:  # counts how often the worker lists it
        def __iter__(self) -> Iterator[FrameLoader]:
            passes.append(1)
            return (FrameLoader(name, name, lambda: None) for name in "abcd")

    cursor = _Cursor(Source())
    assert [cursor.at(p, n).name for p, n in ((1, "b"), (2, "c"), (3, "d"))] == ["b", "c", "d"]
    assert len(passes) == 1  # forward: one pass through the listing
    assert cursor.at(0, "a").name == "a" and len(passes) == 2  # a block from before: a new pass
    with pytest.raises(InputError, match=r"^x: the source changed since its frames were listed \(frame 1 "):
        cursor.at(1, "x").load()
    with pytest.raises(InputError, match=r"^e: the source changed"):
        cursor.at(4, "e").load()


def _spreadable_sources(tmp_path: Path) -> dict[str, Path]:
    """One small source of every kind plan.INDEPENDENT_KINDS names, two frames each."""
    frames = synth_frames()
    write_tum(tmp_path / "tum", frames, [1.0, 1.5])
    write_seven_scenes(tmp_path / "7scenes", frames, [np.eye(4), np.eye(4)])
    for k, frame in enumerate(frames):
        folder = tmp_path / "sun" / f"NYU{k:04d}"
        write_sun_release_frame(
            folder, jpeg(frame.color), np.rint(frame.depth * 1000.0), frame.intrinsics, None
        )
    return {"a3d": write_scene_folder(tmp_path / "a3d", ["f0", "f1"]), "tum": tmp_path / "tum",
            "7scenes": tmp_path / "7scenes", "sunrgbd": tmp_path / "sun"}  # fmt: skip


@needs_ray
def test_every_spreadable_source_reaches_a_worker_whole(tmp_path: Path) -> None:
    """A worker gets the driver's opened source through Ray's cloudpickle: the same frames, read the same."""
    from ray import cloudpickle

    sources = _spreadable_sources(tmp_path)
    assert sorted(sources) == sorted(INDEPENDENT_KINDS)
    for kind, path in sources.items():
        check_independent(path)
        source = open_source(
            path, SourceOptions(intrinsics=(70.0, 70.0, 63.5, 47.5)) if kind == "tum" else None
        )
        copy = cloudpickle.loads(cloudpickle.dumps(source))
        assert [loader.name for loader in copy] == [loader.name for loader in source], kind
        assert len([loader.name for loader in copy]) == 2, kind
        mine, theirs = list(source)[1].load(), list(copy)[1].load()
        np.testing.assert_array_equal(theirs.depth, mine.depth, err_msg=kind)
        assert theirs.intrinsics == mine.intrinsics, kind


@needs_ray
@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ([], "a3d-run: error: --ray writes the detections only, without a view: add --headless"),
        (["--headless", "--map"], "each worker doing its frames in turn: not --map"),
        (["--headless", "--ray-workers", "0"], "--ray-workers must be at least 1"),
    ],
)
def test_ray_usage_errors_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture, extra: list[str], message: str
) -> None:
    folder = write_scene_folder(tmp_path / "frames", ["f0"])
    assert run([str(folder), "--model", str(MODEL), "--ray", *extra]) == 2
    assert message in capsys.readouterr().err


@needs_ray
def test_ray_refuses_a_camera_in_one_line(capsys: pytest.CaptureFixture) -> None:
    assert run(["realsense", "--model", str(MODEL), "--headless", "--ray"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("a3d-run: error: realsense: --ray needs frames that every")


def test_ray_workers_without_ray_is_a_usage_error(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    folder = write_scene_folder(tmp_path / "frames", ["f0"])
    assert run([str(folder), "--model", str(MODEL), "--headless", "--ray-workers", "2"]) == 2
    assert "--ray-workers needs --ray" in capsys.readouterr().err


# ----------------------------------------------------------------------------- on a local Ray


@pytest.fixture(scope="module")
def local_ray() -> Iterator[None]:
    ray = pytest.importorskip("ray", reason="ray is not installed (pip install 'a3d[ray]')")
    ray.init(num_cpus=2, include_dashboard=False, logging_level=logging.ERROR)
    yield
    ray.shutdown()


@pytest.fixture(scope="module")
def frames(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = write_scene_folder(tmp_path_factory.mktemp("ray") / "frames", FRAMES)
    (folder / f"{BROKEN}.color.png").write_bytes(b"not a png")
    shutil.copy(folder / "f0.depth.png", folder / f"{BROKEN}.depth.png")
    return folder


def _run_both(frames: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> tuple[Path, Path, str, str]:
    """(plain output, --ray output, plain stderr, --ray stderr), each run exiting 1 (the broken frame)."""
    common = ["--model", str(MODEL), "--headless", "--threads", "1"]
    plain, spread = tmp_path / "plain.jsonl", tmp_path / "ray.jsonl"
    assert run([str(frames), *common, "--output", str(plain)]) == 1
    plain_err = capsys.readouterr().err
    assert run([str(frames), *common, "--output", str(spread), "--ray", "--ray-workers", "2"]) == 1
    return plain, spread, plain_err, capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.usefixtures("local_ray")
def test_ray_writes_plain_a3d_runs_lines_and_problems(
    frames: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    plain, spread, plain_err, ray_err = _run_both(frames, tmp_path, capsys)
    assert _without_timing(spread) == _without_timing(plain)
    assert [line["frame"] for line in _without_timing(spread)] == FRAMES
    broken = [line for line in plain_err.splitlines() if f"{BROKEN}.color.png" in line]
    assert len(broken) == 1 and broken[0] in ray_err.splitlines()
    assert f"a3d-run: {len(FRAMES)} frames written to {spread}, 1 failed" in ray_err.splitlines()
    assert not Parts(spread).folder.exists()


@pytest.mark.slow
@pytest.mark.usefixtures("local_ray")
def test_ray_detect_resumes_from_the_output_and_the_parts(frames: Path, tmp_path: Path) -> None:
    from a3d.runtime.scale import ray_detect

    common = ["--model", str(MODEL), "--headless", "--threads", "1"]
    plain = tmp_path / "plain.jsonl"
    assert run([str(frames), *common, "--output", str(plain)]) == 1
    done = plain.read_text().splitlines()
    output = tmp_path / "out.jsonl"
    output.write_text(f"{done[0]}\n{done[1]}\n")  # an interrupted run: f0, f1 merged before
    Parts(output).write([(4, done[4])])  # and f4's block finished
    problems: list[str] = []
    result = ray_detect(frames, MODEL, output, resume=True, workers=2, threads=1, on_problem=problems.append)
    assert (result.written, result.already, len(result.failed)) == (3, 3, 1)
    assert problems == result.failed and f"{BROKEN}.color.png" in problems[0]
    lines = output.read_text().splitlines()
    assert [lines[k] for k in (0, 1, 4)] == [done[k] for k in (0, 1, 4)]  # kept, timing and all: not redone
    assert _without_timing(output) == _without_timing(plain)


@pytest.mark.slow
@pytest.mark.usefixtures("local_ray")
def test_a_worker_that_cannot_start_stops_the_run_in_one_line(frames: Path, tmp_path: Path) -> None:
    from a3d.runtime import Detector
    from a3d.runtime.scale import RayJob, RayRunner
    from a3d.runtime.scale.ray_run import RayFailed

    source = open_source(frames)
    job = RayJob(source, MODEL, Detector.load(MODEL).config, threads=1, cwd=str(tmp_path / "elsewhere"))
    with pytest.raises(RayFailed, match=r"^Ray: .*elsewhere: the driver's folder is not on this node \("):
        RayRunner(job, tmp_path / "out.jsonl").run(workers=2)
