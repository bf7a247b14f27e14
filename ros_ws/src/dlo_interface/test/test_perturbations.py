"""The perturbation registry's contract part (dlo_interface.perturbations): which node owns which family, and what
a simulator does with the physics and camera families (the gym env and the sim node both use these). No Taichi, no
ROS. What each family does in the env: dlo_policy/test/test_perturbations.py; graph == env:
tests/test_graph_perturbations.py."""

import math

import pytest
from dlo_interface import perturbations as P
from dlo_interface.camera import TopCamera
from dlo_interface.sim_config import SimConfig


def test_every_side_has_one_owner_in_the_graph():
    owned = [side for sides in P.OWNERS.values() for side in sides]
    assert sorted(owned) == sorted(P.SIDES)


def test_a_node_takes_the_families_it_owns_and_names_the_owner_of_the_others():
    assert P.owned("camera_yaw=2,friction=0.6", "simulator") == {"friction": 0.6, "camera_yaw": 2.0}
    assert P.owned("", "simulator") == {} and P.owned("velocity_gain=1", "policy node") == {}  # off is none
    assert P.owned("action_delay=1,observation_delay=2", "policy node") == {"observation_delay": 2, "action_delay": 1}
    with pytest.raises(ValueError) as error:
        P.owned("observation_delay=1,velocity_gain=0.9", "simulator")
    assert str(error.value) == (
        "observation_delay, velocity_gain: observation and action perturbations belong to the policy node, not the "
        f"simulator (here: {', '.join(P.names(P.PHYSICS) + P.names(P.CAMERA))})"
    )
    with pytest.raises(ValueError, match="^friction: physics and camera perturbations belong to the simulator, not the policy"):
        P.owned("friction=0.6", "policy node")
    with pytest.raises(ValueError, match="^expected name=value pairs"):
        P.owned(0.6, "simulator")


def test_physics_families_replace_the_training_ranges_and_keep_every_other_setting():
    base = SimConfig(physics_seed=3, contact_radius=0.005)
    assert P.sim_config({}, base) is base and P.sim_config({"camera_yaw": 2.0}, None) is None  # none on: unchanged
    config = P.sim_config(P.parse("friction=0.6,cable_length=20,particle_mass=0.2:0.4"), base)
    assert config.friction_range == (0.6, 0.6) and config.num_particles_range == (20, 20)
    assert config.particle_mass_range == (0.2, 0.4)
    assert (config.physics_seed, config.contact_radius, config.stretch_range) == (3, 0.005, base.stretch_range)


def test_the_camera_that_renders_moves_while_the_one_the_vision_assumes_stays():
    nominal = TopCamera.covering_workspace(128)
    assert P.cameras({}, nominal) == (nominal, nominal)
    rendering, assumed = P.cameras(P.parse("camera_offset=10,camera_yaw=2"), nominal)
    assert assumed is nominal
    assert rendering.position == pytest.approx((nominal.position[0], nominal.position[1] + 0.01, nominal.position[2]))
    assert rendering.yaw == pytest.approx(math.radians(2.0))
