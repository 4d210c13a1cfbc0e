"""a3d synth: procedural RGB-D indoor scenes with amodal 3D ground truth (numpy + OpenCV).

``generate_frame(seed, SceneConfig())`` renders one frame; ``a3d-synth`` writes frame folders.
"""

from a3d.synth.scene import ObjectRecord, SceneConfig, SynthFrame, generate_frame

__all__ = ["ObjectRecord", "SceneConfig", "SynthFrame", "generate_frame"]
