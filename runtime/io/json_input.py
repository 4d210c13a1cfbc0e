"""JSON that a user or a file supplies, parsed with every failure as one line naming the source.

json.loads fails in four ways a CLI must report, not crash on: bad UTF-8, a syntax error, an
integer of more than 4300 digits (ValueError) and nesting deeper than the recursion limit
(RecursionError). Frames, detections files and model metadata all read JSON through here.
"""

from __future__ import annotations

import json
import sys
from typing import Any

from a3d.runtime.errors import InputError


def parse_json(text: str | bytes, where: str, subject: str = "", error: type[ValueError] = InputError) -> Any:
    """The parsed value, or ``error("WHERE: [SUBJECT ]malformed JSON at line L column C: why")`` etc."""
    prefix = f"{where}: {subject + ' ' if subject else ''}"
    try:
        return json.loads(text.decode("utf-8") if isinstance(text, bytes) else text)
    except UnicodeDecodeError as e:
        raise error(f"{prefix}not UTF-8 text (byte {e.start})") from None
    except json.JSONDecodeError as e:
        raise error(f"{prefix}malformed JSON at line {e.lineno} column {e.colno}: {e.msg}") from None
    except (ValueError, RecursionError) as e:  # an integer of > 4300 digits; nesting too deep
        raise error(f"{prefix}unreadable JSON ({e})") from None


def is_finite_number(value: Any) -> bool:
    """A JSON number (int or float, not a boolean) that is finite, also for an integer beyond
    float64's range (``math.isfinite`` and ``float()`` raise on those; ``abs(v) <= max`` does not)."""
    return isinstance(value, int | float) and not isinstance(value, bool) and abs(value) <= sys.float_info.max
