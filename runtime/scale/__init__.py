"""Scale-out on an existing engine: a3d-run's batch inference on Ray Data (``pip install 'a3d[ray]'``).

    from a3d.runtime.scale import ray_detect
    run = ray_detect("scans/frames", "samples/model.onnx", "out/detections.jsonl", workers=8, threads=2)
    print(run.written, run.failed)

``a3d-run SOURCE --ray [ADDRESS]`` is the same from the command line (docs/running.md "Scale-out
on Ray"): the frames are listed on the driver, read and detected on a pool of Ray actors, and
written as a3d-run's lines, in source order. ``plan`` and ``parts`` need no Ray; ``ray_run``
imports it only when a run starts.
"""

from a3d.runtime.scale.ray_run import RayJob, RayRun, RayRunner, ray_detect

__all__ = ["RayJob", "RayRun", "RayRunner", "ray_detect"]
