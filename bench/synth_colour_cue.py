"""How much an object's colour alone says about its class, per a3d-synth appearance mode.

    .venv/bin/python -m bench.synth_colour_cue [--frames 200] [--seed 11] [--workers 2]

Renders the same frames with materials drawn independently of the class (the default) and with
class-typical materials (``--appearance typical``), and for every annotated object with at least
200 visible pixels takes colour statistics of its visible pixels only (mean and standard
deviation of L*a*b*, and a 4 x 4 histogram of a*b*): no shape, size or depth. A linear
discriminant (class means, pooled covariance) is fitted on the first half of the frames and
scored on the second half. Prints the balanced accuracy (mean recall over the classes) against
chance (1/19): near chance means colour carries no class cue; far below 1 means it does not
identify the class.
"""

from __future__ import annotations

import argparse
import multiprocessing
from dataclasses import replace

import cv2
import numpy as np

from a3d.runtime.structures.classes import CLASSES
from a3d.synth.cli import frame_seed
from a3d.synth.scene import APPEARANCES, SceneConfig, generate_frame

MIN_PX = 200


def colour_features(args: tuple[int, str]) -> tuple[np.ndarray, np.ndarray]:
    """(N, 22) colour statistics and (N,) class ids of one frame's well-visible annotated objects."""
    seed, appearance = args
    frame = generate_frame(seed, replace(SceneConfig(), appearance=appearance))
    lab = cv2.cvtColor(frame.color, cv2.COLOR_BGR2LAB).reshape(-1, 3).astype(np.float64)
    inst = frame.instances.ravel()
    feats, labels = [], []
    for k, cls in enumerate(frame.gt.classes, start=1):
        px = lab[inst == k]
        if len(px) < MIN_PX:
            continue
        hist, _, _ = np.histogram2d(px[:, 1], px[:, 2], bins=4, range=[[64, 192], [64, 192]])
        feats.append(np.concatenate([px.mean(0), px.std(0), hist.ravel() / len(px)]))
        labels.append(CLASSES.index(cls))
    return np.array(feats).reshape(-1, 22), np.array(labels, dtype=np.int64)


def lda_balanced_accuracy(
    x_train: np.ndarray, y_train: np.ndarray, x_test: np.ndarray, y_test: np.ndarray
) -> float:
    """Mean per-class recall on the test set of a shared-covariance linear discriminant."""
    mu, sd = x_train.mean(0), x_train.std(0) + 1e-9
    x_train, x_test = (x_train - mu) / sd, (x_test - mu) / sd
    classes = np.unique(y_train)
    means = np.stack([x_train[y_train == c].mean(0) for c in classes])
    centred = x_train - means[np.searchsorted(classes, y_train)]
    cov = centred.T @ centred / len(x_train) + 1e-3 * np.eye(x_train.shape[1])
    w = np.linalg.solve(cov, means.T)  # (D, C)
    prior = np.log(np.bincount(np.searchsorted(classes, y_train)) / len(y_train))
    scores = x_test @ w - 0.5 * np.sum(means.T * w, axis=0) + prior
    predicted = classes[scores.argmax(1)]
    recalls = [np.mean(predicted[y_test == c] == c) for c in np.unique(y_test)]
    return float(np.mean(recalls))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--seed", type=int, default=11)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    seeds = [frame_seed(args.seed, i) for i in range(args.frames)]
    half = args.frames // 2
    print(f"{'appearance':<12} {'objects':>8} {'balanced accuracy':>18}   chance {1 / len(CLASSES):.3f}")
    with multiprocessing.Pool(args.workers) as pool:
        for appearance in APPEARANCES:
            per_frame = pool.map(colour_features, [(s, appearance) for s in seeds])
            x_tr, y_tr = (np.concatenate(a) for a in zip(*per_frame[:half], strict=True))
            x_te, y_te = (np.concatenate(a) for a in zip(*per_frame[half:], strict=True))
            accuracy = lda_balanced_accuracy(x_tr, y_tr, x_te, y_te)
            print(f"{appearance:<12} {len(y_tr) + len(y_te):>8} {accuracy:>18.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
