"""fusion.run.inputs.PendingInputs: the input samples waiting to be integrated, handed out up to a time."""
from fusion.api import Message
from fusion.run.inputs import PendingInputs


def _samples(*ts):
    return [Message(t, "imu", (t,)) for t in ts]


def test_take_until_hands_out_those_at_or_before_and_keeps_the_rest():
    p = PendingInputs()
    for m in _samples(0.0, 0.01, 0.02, 0.03):
        p.add(m)
    assert p.last_t == 0.03 and len(p) == 4
    first = p.take(0.02)
    assert [m.t for m in first] == [0.0, 0.01, 0.02]
    assert [m.t for m in p.take()] == [0.03]
    assert not p and p.last_t is None and p.take() == []


def test_take_until_later_than_every_sample_hands_out_all():
    p = PendingInputs()
    for m in _samples(0.0, 0.01):
        p.add(m)
    assert [m.t for m in p.take(5.0)] == [0.0, 0.01] and not p


def test_take_until_before_every_sample_hands_out_none():
    p = PendingInputs()
    for m in _samples(1.0, 1.01):
        p.add(m)
    assert p.take(0.5) == [] and len(p) == 2


def test_a_sample_added_after_a_take_is_not_lost():
    """The reorder loop's stale reference to a replaced list once lost every sample added after a flush."""
    p = PendingInputs()
    for m in _samples(0.0, 0.01, 0.02):
        p.add(m)
    taken = p.take(0.01)
    p.add(Message(0.03, "imu", ()))
    assert [m.t for m in taken] == [0.0, 0.01]
    assert [m.t for m in p.take()] == [0.02, 0.03]
