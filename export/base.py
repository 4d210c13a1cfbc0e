"""What the export steps share and a3d-export's --help needs, without torch or onnx.

The command's name, the ONNX versions it writes and its error type: a3d-export --help and
--version then work in the base install, before the 'train' extra is checked.
"""

from __future__ import annotations

PROG = "a3d-export"
MIN_OPSET = 18  # the dynamo exporter's lowest native opset; lower ones fail its version conversion
MAX_IR_VERSION = 13  # ONNX Runtime 1.31 reads IR <= 13 (onnx 1.23 writes 14 by default)
VERIFY_FRAMES = 2  # frames of --verify-frames compared (each with all its proposals)


class ExportError(RuntimeError):
    """Export or verification failed; the message is one line for the command line."""
