"""Plugin registry: built-ins, a third-party package found through its entry point, errors, blocking."""
import sys
import textwrap
from pathlib import Path

import pytest

from fusion.api import ConfigError, Filter
from fusion.config import SystemSpec, wire
from fusion.registry import Registry, make_plugin_manager

def test_builtins_registered():
    _, reg = make_plugin_manager()
    assert {"pv"} <= set(reg.names("process"))
    assert {"range"} <= set(reg.names("measurement"))
    assert {"line"} <= set(reg.names("decoder"))
    assert all(e.provider.endswith("(built-in)") for e in reg.entries())


def test_third_party_plugin_from_entry_point_used_from_yaml(installed_example):
    _, reg = make_plugin_manager()
    entry = next(e for e in reg.entries("measurement") if e.name == "altimeter")
    assert entry.provider == "fusion-altimeter 0.1.0"
    spec = SystemSpec.model_validate({
        "name": "alt", "process": {"type": "pv", "dims": 3}, "filter": "kf",
        "sensors": {"baro": {"model": {"type": "altimeter", "offset": 2.0}, "noise": 0.5}}})
    system = wire(spec, registry=reg)
    model = system.sensors["baro"].model
    assert model.h(system.x0 + [0, 0, -3.0, 0, 0, 0])[0] == pytest.approx(5.0)


def test_autoload_can_be_disabled(installed_example, monkeypatch):
    monkeypatch.setenv("FUSION_DISABLE_PLUGIN_AUTOLOAD", "1")
    _, reg = make_plugin_manager()
    assert "altimeter" not in reg.names("measurement")


def test_plugin_can_be_blocked(installed_example, monkeypatch):
    monkeypatch.setenv("FUSION_BLOCK_PLUGINS", "altimeter")
    _, reg = make_plugin_manager()
    assert "altimeter" not in reg.names("measurement")


def test_misspelt_hook_fails_loudly():
    from fusion import hookimpl

    class Bad:
        @hookimpl
        def fusion_register_componets(self, registry):  # typo on purpose
            pass

    with pytest.raises(ConfigError, match=r"test_registry.py:\d+: hook 'fusion_register_componets' is not a fusion "
                                          r"hook \(did you mean 'fusion_register_components'\?\).*FUSION_BLOCK_PLUGINS="):
        make_plugin_manager(extra_plugins=[Bad()])


def test_unknown_name_lists_known_and_suggests():
    reg = Registry()

    class Ukf(Filter):
        name = "ukf"

    reg.add(Ukf)
    with pytest.raises(ConfigError, match=r"unknown filter 'ufk'; did you mean 'ukf'\? \(known filters: ukf\)"):
        reg.get("filter", "ufk")


def test_the_known_processes_are_spelt_so():
    from fusion.registry import default_registry

    with pytest.raises(ConfigError, match=r"\(known processes: .*\bins\b"):
        default_registry().get("process", "insx")


def test_double_registration_of_a_name_is_an_error():
    reg = Registry()

    class A(Filter):
        name = "same"

    class B(Filter):
        name = "same"

    reg.add(A)
    with pytest.raises(ValueError, match="registered twice"):
        reg.add(B)
