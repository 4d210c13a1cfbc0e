"""Settings from plain JSON data (a3d.runtime.io.plain_config): known answers for every rule."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field

import pytest

from a3d.runtime.errors import ModelError
from a3d.runtime.frontend.proposals import ProposalConfig, proposal_config_from_dict
from a3d.runtime.io.plain_config import MAX_COUNT, dataclass_from_plain


@dataclass(frozen=True)
class Inner:
    fraction: float = 0.5
    count: int = 3


@dataclass(frozen=True)
class Outer:
    name: str = "x"
    enabled: bool = True
    weights: tuple[float, float] = (1.0, 2.0)
    inners: tuple[Inner, ...] = (Inner(),)
    inner: Inner = field(default_factory=Inner)


LIMITS = {"fraction": (0.0, 1.0)}


def test_values_of_every_kind_build_the_dataclass() -> None:
    plain = {"name": "y", "enabled": False, "weights": [3, 4.5], "inners": [{"count": 7}, {}],
             "inner": {"fraction": 1}}  # fmt: skip
    got = dataclass_from_plain(Outer, plain, "cfg", LIMITS)
    assert got == Outer("y", False, (3.0, 4.5), (Inner(count=7), Inner()), Inner(fraction=1.0))
    assert isinstance(got.weights[0], float) and isinstance(got.inner.fraction, float)  # ints widened
    assert dataclass_from_plain(Outer, {}, "cfg") == Outer()  # missing keys keep their defaults


@pytest.mark.parametrize(
    ("plain", "says"),
    [
        ({"enabled": 1}, "cfg.enabled must be true or false, got 1"),
        ({"name": 5}, "cfg.name must be a string"),
        ({"weights": [1.0]}, "cfg.weights must be a list of 2 values"),
        ({"weights": "ab"}, "cfg.weights must be a list of 2 values"),
        ({"inners": []}, "cfg.inners must be a non-empty list"),
        (
            {"inners": [{}, {"count": -1}]},
            f"cfg.inners[1].count must be an integer in [0, {MAX_COUNT}], got -1",
        ),
        ({"inner": {"count": 2.0}}, "cfg.inner.count must be an integer"),
        ({"inner": {"count": True}}, "cfg.inner.count must be an integer"),
        ({"inner": {"count": MAX_COUNT + 1}}, "cfg.inner.count must be an integer"),
        ({"inner": {"fraction": 1.5}}, "cfg.inner.fraction must be a finite number in [0.0, 1.0], got 1.5"),
        ({"inner": {"fraction": float("nan")}}, "cfg.inner.fraction must be a finite number"),
        ({"weights": [1.0, 10**400]}, "cfg.weights[1] must be a finite number >= 0"),
        ({"weights": [1.0, -0.5]}, "cfg.weights[1] must be a finite number >= 0, got -0.5"),
        ({"inner": [1]}, "cfg.inner must be an object, got [1]"),
        ({"inner": {"colour": 1}}, "unknown setting(s) cfg.inner.colour (known: count, fraction)"),
    ],
)
def test_each_bad_value_is_named_with_its_path(plain: dict, says: str) -> None:
    with pytest.raises(ModelError) as caught:
        dataclass_from_plain(Outer, plain, "cfg", LIMITS)
    assert str(caught.value).startswith(says), str(caught.value)
    assert "\n" not in str(caught.value)


def test_proposal_config_round_trips_and_refuses_what_would_break_the_proposal_stage() -> None:
    config = ProposalConfig(max_proposals=123, min_area=50)
    plain = json.loads(json.dumps(dataclasses.asdict(config)))  # tuples become lists, as in a file
    assert proposal_config_from_dict(plain) == config
    for path, value in (("scale", 0), ("max_proposals", 0), ("duplicate_iou", 1.5), ("color_bins", 0)):
        with pytest.raises(ModelError, match=rf"proposal_config\.{path} must be"):
            proposal_config_from_dict({**plain, path: value})
    with pytest.raises(ModelError, match=r"superpixels\.n_segments must be an integer in \[1, "):
        proposal_config_from_dict({**plain, "superpixels": {**plain["superpixels"], "n_segments": 0}})
