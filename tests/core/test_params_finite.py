"""fusion.api.Params: every float must be finite, nested in untyped containers too (``dict``, ``list``, numpy
arrays); a field that opts in with ``allow_inf_nan=True`` accepts inf, never NaN."""
import math

import numpy as np
import pytest
from pydantic import Field, ValidationError

from fusion.api import Params


class P(Params):
    max_range: float = Field(math.inf, allow_inf_nan=True, description="m; inf: no limit")
    sub: dict = {}
    items: list = []
    typed: dict[str, float] = {}
    arr: np.ndarray | None = None


def test_inf_where_a_field_opts_in_and_finite_values_anywhere_are_accepted():
    p = P(max_range=math.inf, sub={"a": 1.0, "b": [2, "x", {"c": 3.5}]}, items=[1.0, (2.0, 3)], arr=np.ones(2))
    assert p.max_range == math.inf and p.sub["b"][2]["c"] == 3.5


@pytest.mark.parametrize("kwargs, message", [
    ({"max_range": math.nan}, "max_range: nan: NaN is never a parameter (this field allows inf)"),
    ({"sub": {"a": math.nan}}, "sub.a: nan: NaN and inf are not parameters"),
    ({"sub": {"a": {"b": [1.0, math.inf]}}}, "sub.a.b.1: inf: NaN and inf are not parameters"),
    ({"items": [1.0, -math.inf]}, "items.1: -inf"),
    ({"arr": np.array([[1.0, 2.0], [np.nan, 0.0]])}, "arr.1.0: nan"),
    ({"typed": {"a": math.nan}}, "finite number"),          # pydantic's own check on a typed float
])
def test_nan_anywhere_and_inf_where_not_opted_in_are_errors_naming_the_field(kwargs, message):
    with pytest.raises(ValidationError) as exc:
        P(**kwargs)
    assert message in str(exc.value)
    assert exc.value.errors()[0]["loc"][0] == next(iter(kwargs))


@pytest.mark.parametrize("old, new, where", [
    ("noise: {sd: 0.1}", "noise: {sd: true}", "sensors.uwb.noise.sd"),
    ("noise: {sd: 0.1}", "noise: {sd: [false]}", "sensors.uwb.noise.sd"),
    ("spectral_density: 0.2", "spectral_density: yes", "process.spectral_density"),
    ("alpha: 0.5", "alpha: true", "filter.alpha"),
])
def test_a_yaml_boolean_is_no_number(tmp_path, old, new, where):
    """pydantic would read true as 1.0 (a noise sd of 1 m from a typo); a number field refuses it, naming it."""
    from pathlib import Path

    from fusion.api import ConfigError
    from fusion.config import load_system

    root = Path(__file__).resolve().parents[2]
    text = (root / "configs" / "uwb_pv_ukf.yaml").read_text().replace("../recordings", str(root / "recordings"))
    assert old in text
    path = tmp_path / "c.yaml"
    path.write_text(text.replace(old, new))
    with pytest.raises(ConfigError, match=rf"c.yaml:\d+: {where}: .*a number is needed, got"):
        load_system(path)
