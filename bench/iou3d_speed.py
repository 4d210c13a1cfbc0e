"""iou_3d throughput: one bulk call and a3d-eval's worst-case call pattern (prints pairs/s)."""

import time

import numpy as np

from a3d.runtime.structures.boxes import BOX_DIM, CENTER, SIZE, THETA
from a3d.runtime.structures.geometry import iou_3d, rtilt_from_pitch_roll

rng = np.random.default_rng(0)


def boxes(n):
    b = np.empty((n, BOX_DIM))
    b[:, CENTER] = rng.uniform([-1.5, -0.5, 1.5], [1.5, 1.0, 5.0], (n, 3))
    b[:, SIZE] = rng.uniform(0.3, 2.0, (n, 3))
    b[:, THETA] = rng.uniform(-np.pi / 2, np.pi / 2, n)
    return b


R = rtilt_from_pitch_roll(-0.3, 0.04)
# bulk
a, g = boxes(3000), boxes(100)
t = time.perf_counter()
m = iou_3d(a, g, R)
dt = time.perf_counter() - t
pairs = a.shape[0] * g.shape[0]
print(f"bulk: {pairs} pairs ({np.count_nonzero(m)} overlapping) in {dt:.3f}s = {pairs / dt:,.0f} pairs/s")
# eval pattern: 654 images x 19 classes x (100 dets vs 3 gt)
dets, gts = [boxes(100) for _ in range(50)], [boxes(3) for _ in range(50)]
t = time.perf_counter()
n = 0
for k in range(654 * 19):
    m = iou_3d(dets[k % 50], gts[k % 50], R)
    n += m.size
dt = time.perf_counter() - t
print(
    f"eval pattern: {654 * 19} calls, {n} pairs in {dt:.2f}s = {n / dt:,.0f} pairs/s, "
    f"{dt / (654 * 19) * 1e6:.0f} us/call"
)
