"""a3d synth: procedural RGB-D indoor scenes with amodal 3D ground truth (numpy + OpenCV)."""
