"""Image classifiers trained on real photographs (ImageNet), their classes mapped onto a3d's 19: a
second opinion on a3d's own detections (a3d.runtime.postprocess.fuse.second_opinion);
``Classifier2D.load("mobilenet-v2").classify(rgb, boxes)``."""

from a3d.runtime.classifier2d.classifier import CLASSIFIERS, Classifier2D

__all__ = ["CLASSIFIERS", "Classifier2D"]
