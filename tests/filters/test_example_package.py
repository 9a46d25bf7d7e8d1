"""The example third-party package (examples/fusion-altimeter) passes the author's kit, one component of
each kind it brings (process, measurement, simulator, source, sink), selected by its own package only."""
import numpy as np

from fusion import testing
from fusion.api import Message, StateLayout


def test_the_example_components_pass_the_kit(installed_example):
    from fusion_altimeter.hover import Hover
    from fusion_altimeter.plugin import Altimeter

    testing.check_process(Hover, {"tau": 3.0})
    report = testing.check_measurement(Altimeter, {"offset": 2.0}, StateLayout.parse("p:3 v:3"),
                                       message=Message(1.0, "baro", (4.0,)))
    assert report["jacobian"] < 1e-8
    mine = {kind: testing.registered(kind, package="fusion_altimeter")
            for kind in ("process", "measurement", "simulator", "source", "sink")}
    assert mine == {"process": ["hover"], "measurement": ["altimeter"], "simulator": ["altimeter"],
                    "source": ["udp"], "sink": ["tsv_track"]}
    for kind, names in mine.items():
        for name in names:
            testing.check_component(testing.registry_class(kind, name))
    assert "range" not in testing.registered("measurement", package="fusion_altimeter")


def test_the_example_process_and_model_run_in_a_kf(installed_example):
    from fusion.config import SystemSpec, wire
    from fusion.registry import make_plugin_manager

    _, reg = make_plugin_manager()
    spec = SystemSpec.model_validate({
        "name": "hover", "process": {"type": "hover", "tau": 4.0}, "filter": "kf",
        "initial": {"mean": {"p": [0, 0, 0], "v": [0, 0, 0]}, "sd": {"p": 5.0, "v": 1.0}},
        "sensors": {"baro": {"model": {"type": "altimeter", "offset": 2.0}, "noise": 0.3}}})
    system = wire(spec, registry=reg)
    from fusion import pipeline

    lines = ["# fields baro height\n"] + [f"{0.2 * k:.1f},baro,5.0\n" for k in range(50)]
    result = pipeline.run(system, lines)
    assert np.isclose(result.last.belief.x[2], -3.0, atol=0.1)   # height 5 = offset 2 - p_z
