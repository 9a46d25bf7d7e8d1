"""Every built-in decoder, measurement model, solver and input-driven process model, as the shipped
configs wire them, uses or refuses (MalformedMessage) any message, never raises another exception, and
hands on only usable output (fusion.fuzzing.check_refusals, issue 10 item 1)."""
import copy
from pathlib import Path

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from fusion.api import Message, Observation
from fusion.config import load_system
from fusion.fuzzing import check_refusals

ROOT = Path(__file__).resolve().parents[2]
SYSTEMS = {name: load_system(ROOT / "configs" / f"{name}.yaml") for name in ("abps_ins", "uwb_pv_ukf", "example_2d")}
COMPONENTS = [(f"{cfg}.{sensor}.{part}", getattr(s, part)) for cfg, system in SYSTEMS.items()
              for sensor, s in system.sensors.items() for part in ("decoder", "preprocessor", "model")
              if getattr(s, part) is not None] + [
    (f"{cfg}.process", system.process) for cfg, system in SYSTEMS.items() if system.process.input_dim]

numbers = st.one_of(st.floats(allow_nan=False, allow_infinity=False),
                    st.sampled_from([0.0, -0.0, -1.0, 1e308, -1e308, 1e300, 1e200, 1e-300, 5e-324, 2.5, 0.25]),
                    st.sampled_from([float("nan"), float("inf"), -float("inf")]))   # as another source might send
labels = st.one_of(st.sampled_from(["B1", "B2", "B3", "B4", "B5", "B7", "B9", "b1", "", "x" * 200, "$GPGGA,1*00"]),
                   st.sampled_from([None, (1, 2), b"B1"]))   # not even a label: from a buggy source
messages = st.lists(st.builds(Message, st.one_of(st.floats(0, 200), st.sampled_from([1e300, -1.0, 0.0])),
                              st.just("s"), st.lists(st.one_of(numbers, labels), max_size=12).map(tuple),
                              st.integers(1, 10_000)),
                    min_size=1, max_size=25)


@pytest.mark.parametrize("name,component", COMPONENTS, ids=[c[0] for c in COMPONENTS])
@example(batch=[Message(1.0, "s", ("B1", (1.0, 2.0)), 1), Message(1.0, "s", (1.0, 2.0, None), 2),
                Message(1.0, "s", ((1.0, 2.0),) * 6, 3), Message(1.0, "s", ((1.0, 0.0, 1.0),) * 3, 4)])
@settings(max_examples=40, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(batch=messages)
def test_any_message_is_used_or_refused(name, component, batch):
    check_refusals(copy.deepcopy(component), batch)


def test_the_contract_catches_a_plugin_that_raises_or_passes_garbage():
    model = SYSTEMS["uwb_pv_ukf"].sensors["uwb"].model

    class Raises:
        def observe(self, message):
            return model.observe(message) if message.values[0] == "B1" else {}["no such key"]

    class Garbage:
        def observe(self, message):
            return Observation(message.t, [float("nan")], model)

    with pytest.raises(KeyError):
        check_refusals(Raises(), [Message(1.0, "uwb", ("B1", 2.0)), Message(1.0, "uwb", ("B9", 2.0))])
    with pytest.raises(AssertionError, match="unusable z"):
        check_refusals(Garbage(), [Message(1.0, "uwb", ("B1", 2.0))])
    assert check_refusals(model, [Message(1.0, "uwb", ("B1", 2.0)), Message(1.0, "uwb", ("B9", 2.0))]) == 1
