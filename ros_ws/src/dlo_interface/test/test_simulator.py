"""dlo_interface.simulator: a backend is found by name among the entry points of ENTRY_POINT_GROUP (a made-up
distribution on sys.path here, so no simulator is needed), a factory passes through, an unknown name is one line
naming the registered ones."""

import sys

import pytest
from dlo_interface import simulator


@pytest.fixture
def fake_backend(tmp_path, monkeypatch):
    """A distribution 'fake_sim' registering backend 'fake' (fake_sim_backend:make) on sys.path."""
    (tmp_path / "fake_sim_backend.py").write_text(
        "CALLS = []\n\ndef make(num_envs, **options):\n    CALLS.append((num_envs, options))\n    return ('sim', num_envs)\n"
    )
    info = tmp_path / "fake_sim-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: fake_sim\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(f"[{simulator.ENTRY_POINT_GROUP}]\nfake = fake_sim_backend:make\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    simulator.registered.cache_clear()
    yield
    simulator.registered.cache_clear()
    sys.modules.pop("fake_sim_backend", None)


def test_a_registered_backend_is_found_by_name_and_built(fake_backend):
    assert "fake" in simulator.registered()
    factory = simulator.simulator_factory("fake")
    assert factory.__module__ == "fake_sim_backend" and factory.__name__ == "make"
    assert simulator.make_simulator(3, "fake", horizon=5, render=False) == ("sim", 3)
    assert sys.modules["fake_sim_backend"].CALLS == [(3, {"horizon": 5, "render": False})]


def test_no_name_is_the_default_backend(fake_backend, monkeypatch):
    monkeypatch.setattr(simulator, "DEFAULT_SIMULATOR", "fake")
    assert simulator.simulator_factory(None).__module__ == "fake_sim_backend"
    assert simulator.make_simulator(2) == ("sim", 2)


def test_a_factory_passes_through_unlooked_up(fake_backend):
    def mine(num_envs, **options):
        return "mine"

    assert simulator.simulator_factory(mine) is mine
    assert simulator.make_simulator(1, mine) == "mine"


def test_an_unknown_name_is_one_line_naming_the_registered_backends(fake_backend):
    with pytest.raises(simulator.UnknownSimulator) as error:
        simulator.simulator_factory("mujoco")
    text = str(error.value)
    assert "\n" not in text and isinstance(error.value, ValueError)
    assert text.startswith(f"simulator: no backend 'mujoco' registered in {simulator.ENTRY_POINT_GROUP}; registered: ")
    assert "fake" in text.split("registered: ")[1].split(", ")
    assert simulator.check_simulator("fake") == "fake"


def test_with_nothing_registered_the_error_says_how_to_register(monkeypatch):
    monkeypatch.setattr(simulator, "registered", lambda: {})
    with pytest.raises(simulator.UnknownSimulator, match=r"registered: none \(build the workspace: bash scripts/setup.sh\)$"):
        simulator.check_simulator("taichi")
