"""Physics behaviour of the batched rope simulator (dlo_sim.RopeSim). No wall-time assertions."""

import numpy as np
import pytest
from dlo_interface.camera import IMAGE_CABLE, IMAGE_GRIPPER
from dlo_interface.grip import carried_fraction, inverse_mass
from dlo_interface.sim_config import SimConfig
from dlo_interface.world import FIXED_END, GRIPPER_HEIGHT, MAX_DISPLACEMENT, NOMINAL_INVERSE_MASS, P_MAX, REST_SPACING
from dlo_sim import RopeSim

N = 8


@pytest.fixture(scope="module")
def sim():
    """One shared 8-env simulator (Taichi state is process-global; kernels compile once)."""
    return RopeSim(N)


@pytest.fixture(scope="module")
def sim1():
    return RopeSim(1)


def actions(dx=0.0, dy=0.0, c=0.0, n=N):
    a = np.zeros((n, 3), np.float32)
    a[:] = (dx, dy, 2.0 * c - 1.0)
    return a


def segment_ratios(sim):
    x, n = sim.positions(), sim.num_particles
    return [np.linalg.norm(np.diff(x[e, : n[e]], axis=0), axis=1) / REST_SPACING for e in range(sim.num_envs)]


def kinetic_energy(sim):
    v = sim.velocities()
    return 0.5 / NOMINAL_INVERSE_MASS * (v**2).sum(axis=(1, 2))


def test_grip_law_regimes():
    w = NOMINAL_INVERSE_MASS
    assert inverse_mass([0.0, 0.3, 0.5], w) == pytest.approx([w, w, w])
    assert inverse_mass(0.7, w) == pytest.approx(0.5 * w)
    assert inverse_mass([0.9, 1.0], w) == pytest.approx([0.0, 0.0])
    assert carried_fraction([0.2, 0.7, 1.0]) == pytest.approx([0.0, 0.5, 1.0])


def test_reset_randomises_within_paper_ranges(sim):
    sim.reset(np.arange(N))
    p = sim.params
    assert np.all((p["num_particles"] >= 30) & (p["num_particles"] <= 60))
    assert np.all((p["stretch"] >= 0.8) & (p["stretch"] <= 1.4))
    assert np.all((p["bending"] >= 0.8) & (p["bending"] <= 2.4))
    assert np.all((p["friction"] >= 0.04) & (p["friction"] <= 0.3))
    assert np.allclose(sim.cable_length, (p["num_particles"] - 1) * REST_SPACING)
    x = sim.positions()
    assert np.allclose(x[:, 0], FIXED_END)
    assert np.all(x[~sim.particle_mask()] == 0.0)
    g = sim.gripper_state()
    assert np.allclose(g[:, 2], GRIPPER_HEIGHT) and np.allclose(g[:, 3], 0.0)
    assert np.all(sim.n_held() > 0), "the cable starts between the fingers"
    assert np.all(sim.mean_held_index() < 5)


def test_rest_length_kept_under_gravity(sim):
    """Stated tolerance: per segment within 10 % of the rest spacing, on average within 2 %."""
    sim.reset(np.arange(N))
    sim.step_physics(actions(), 100)
    for ratios in segment_ratios(sim):
        assert ratios.max() < 1.10 and ratios.min() > 0.9
        assert abs(ratios.mean() - 1.0) < 0.02


def test_stretch_stiffness_is_visible(sim):
    ids = np.arange(N)
    means = []
    for stretch in (0.8, 1.4):
        sim.reset(ids, params={"stretch": np.full(N, stretch)})
        means.append(np.mean([r.max() for r in segment_ratios(sim)]))
    assert means[0] > means[1] + 0.01


def test_no_table_penetration_while_dragged(sim):
    sim.reset(np.arange(N) + 10)
    r = sim.config.contact_radius
    for dy in (1.0, -1.0):
        for _ in range(5):
            sim.step(actions(dx=0.5, dy=dy, c=0.7))
            z = sim.positions()[sim.particle_mask()][:, 2]
            assert z.min() >= r - 1e-5


def test_hanging_cable_settles(sim):
    """A straight horizontal cable released from the fixed end swings down; damping and contact
    make its kinetic energy decay."""
    sim.reset(np.arange(N), params={"num_particles": np.full(N, 40)})
    x = np.zeros((N, P_MAX, 3), np.float32)
    x[:, :40] = np.array(FIXED_END) + np.arange(40)[:, None] * np.array([REST_SPACING, 0.0, 0.0])
    sim.set_positions(x)
    energy = []
    for _ in range(40):
        sim.step(actions())
        energy.append(kinetic_energy(sim))
    energy = np.array(energy)
    assert np.all(energy[-1] < 0.01 * energy.max(axis=0))
    assert np.all(energy[-5:].max(axis=0) < 0.02 * energy.max(axis=0))


def test_cable_on_table_does_not_drift(sim):
    sim.reset(np.arange(N) + 20)
    sim.step_physics(actions(), 100)
    before = sim.positions()
    on_table = sim.particle_mask() & (before[..., 2] < sim.config.contact_radius + 1e-3)
    sim.step_physics(actions(), 200)
    moved = np.linalg.norm(sim.positions() - before, axis=-1)[on_table]
    assert on_table.sum() > 10 * N
    assert moved.max() < 1e-3


def drive(sim, c, n_actions, seeds):
    sim.reset(seeds)
    start_x = sim.positions()
    g0 = sim.gripper_state()
    held0 = sim.held_mask()
    p_i0 = sim.mean_held_index()
    for _ in range(n_actions):
        sim.step(actions(dx=1.0, c=c))
    return start_x, g0, held0, p_i0


def grip_mid_cable(sim, seeds):
    """Slide along the cable at c = 0.7 for 3 actions, so the fingers hold it away from the fixed end."""
    drive(sim, 0.7, 3, seeds)
    assert np.all(sim.mean_held_index() >= 6)


def test_firm_grip_carries_held_particles(sim):
    """c = 1 on slack cable (moving back towards the fixed end): the held particles move with the
    gripper (within the small slip of a finite grip against the compressed cable behind it)."""
    seeds = np.arange(N) + 30
    grip_mid_cable(sim, seeds)
    start_x, g0, held0 = sim.positions(), sim.gripper_state(), sim.held_mask()
    for _ in range(2):
        sim.step(actions(dx=-1.0, c=1.0))
    moved = sim.gripper_state()[:, :2] - g0[:, :2]
    assert np.allclose(moved[:, 0], -2 * 8 * MAX_DISPLACEMENT, atol=1e-6)
    carried = held0 & sim.held_mask()
    assert np.all(carried.sum(axis=1) >= 1)
    disp = (sim.positions() - start_x)[carried][:, :2]
    expected = np.repeat(moved, carried.sum(axis=1), axis=0)
    assert np.allclose(disp, expected, atol=6e-3)  # measured <= 4 mm of 40 mm
    assert 0.9 <= disp[:, 0].mean() / moved[0, 0] <= 1.01


def test_partial_grip_slides_with_drag(sim):
    """c = 0.7: the gripper slides along the cable (p_i grows) while dragging it forward more than
    an open grip does."""
    seeds = np.arange(N) + 40
    drag = {}
    for c in (0.2, 0.7):
        start_x, _, _, p_i0 = drive(sim, c, 4, seeds)
        p_i = sim.mean_held_index()
        mask = sim.particle_mask()
        drag[c] = ((sim.positions() - start_x)[..., 0] * mask).sum(1) / mask.sum(1)
        if c == 0.7:
            holding = p_i >= 0
            assert holding.sum() >= N // 2
            assert np.all(p_i[holding] > p_i0[holding] + 3), "the fingers slide along the cable"
    assert drag[0.7].mean() > drag[0.2].mean() + 0.005


def test_open_grip_lets_lifted_cable_fall(sim):
    """c = 0.2 while moving along the lifted cable: it slips through and out of the fingers."""
    drive(sim, 0.2, 14, np.arange(N) + 50)
    assert np.all(sim.n_held() == 0)
    assert np.all(sim.mean_held_index() == -1.0)


def test_higher_bending_stiffness_straighter_free_end(sim):
    def mean_turn(x, n):
        angles = []
        for e in range(len(n)):
            d = np.diff(x[e, n[e] // 2 : n[e]], axis=0)
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            angles.append(np.arccos(np.clip((d[1:] * d[:-1]).sum(1), -1, 1)).mean())
        return np.mean(angles)

    turn = []
    for bending in (0.8, 2.4):
        sim.reset(np.arange(N), params={"bending": np.full(N, bending)})
        turn.append(mean_turn(sim.positions(), sim.num_particles))
    assert turn[1] < 0.9 * turn[0]


def rollout(sim, seeds, env, n_actions=6):
    sim.reset(seeds)
    rng = np.random.default_rng(7)
    for _ in range(n_actions):
        a = np.zeros((sim.num_envs, 3), np.float32)
        a[env] = rng.uniform(-1, 1, 3)
        sim.step(a)
    return sim.positions()[env], sim.velocities()[env], sim.held_mask()[env]


def test_same_seed_bit_identical_and_different_seeds_differ(sim):
    seeds = np.arange(N) + 60
    first = rollout(sim, seeds, 3)
    second = rollout(sim, seeds, 3)
    for a, b in zip(first, second):
        assert np.array_equal(a, b)
    other = rollout(sim, seeds + 100, 3)
    assert not np.array_equal(first[0], other[0])


def test_batch_equals_single_environment(sim, sim1):
    seeds = np.arange(N) + 70
    batched = rollout(sim, seeds, 5)
    single = rollout(sim1, seeds[5:6], 0)
    for a, b in zip(batched, single):
        assert np.array_equal(a, b)


def test_reset_subset_leaves_other_envs_running(sim):
    sim.reset(np.arange(N))
    sim.step(actions(dx=0.3, c=0.6))
    before = sim.positions()
    g_before = sim.gripper_state()
    sim.reset([123, 124], env_ids=[2, 5])
    after = sim.positions()
    keep = np.setdiff1d(np.arange(N), [2, 5])
    assert np.array_equal(after[keep], before[keep])
    assert np.array_equal(sim.gripper_state()[keep], g_before[keep])
    assert list(sim.params["seed"][[2, 5]]) == [123, 124]
    assert not np.array_equal(after[2], before[2])


def test_nan_state_is_flagged_and_reset(sim):
    sim.reset(np.arange(N))
    x = sim.positions()
    x[1, 10] = np.nan
    sim.set_positions(x[1:2], env_ids=[1])
    sim.step(actions())
    flags = sim.unstable()
    assert flags[1] and flags.sum() == 1
    assert np.all(np.isfinite(sim.positions()))
    sim.step(actions())
    assert not sim.unstable().any()


def test_invalid_input(sim):
    with pytest.raises(ValueError, match="stretch_range"):
        SimConfig(stretch_range=(-1.0, 1.0))
    with pytest.raises(ValueError, match="num_particles_range"):
        SimConfig(num_particles_range=(0, 0))
    with pytest.raises(ValueError, match="num_envs"):
        RopeSim(0)
    with pytest.raises(ValueError, match="positive"):
        sim.reset(np.arange(N), params={"bending": np.full(N, -1.0)})
    sim.reset(np.arange(N))
    bad = actions()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        sim.step(bad)
    g0 = sim.gripper_state()
    with pytest.warns(RuntimeWarning, match="clipped"):
        sim.step_physics(actions(dx=5.0), 1)
    assert np.allclose(sim.gripper_state()[:, 0] - g0[:, 0], MAX_DISPLACEMENT, atol=1e-7)


def test_render_top_view(sim):
    sim.reset(np.arange(N))
    img = sim.render()
    cam = sim.camera
    assert img.shape == (N, cam.height, cam.width) and img.dtype == np.uint8
    assert set(np.unique(img)) <= {0, IMAGE_GRIPPER, IMAGE_CABLE}
    x, mask = sim.positions(), sim.particle_mask()
    for e in range(N):
        uv = np.floor(cam.world_to_pixel(x[e][mask[e]])).astype(int)
        seen = (uv >= 0).all(1) & (uv[:, 0] < cam.width) & (uv[:, 1] < cam.height)
        values = img[e, uv[seen, 1], uv[seen, 0]]
        assert seen.sum() > 10 and np.all(values != 0), "every particle in view is drawn (cable or gripper)"
        gu, gv = np.floor(cam.world_to_pixel(sim.gripper_state()[e, :3])).astype(int)
        assert img[e, gv, gu] == IMAGE_GRIPPER, "the gripper occludes the cable it holds"
        assert (img[e] == IMAGE_CABLE).sum() > 20


def test_single_particle_grip_carries_one_particle_the_held_one_nearest_the_finger_axis(sim):
    """SimConfig.single_particle_grip (the authors' grip, docs/FIDELITY.md row 5): with the gripper
    mid-cable and a firm grip, ONE particle gets the grip's inverse mass (0) and moves exactly with the
    finger: the held one nearest the finger axis in x, never particle 0; the other held particles keep
    w_nom and are not all carried along. Off (the default), every held particle is."""
    from dlo_interface.grip import single_grip_particle

    single = RopeSim(N, SimConfig(single_particle_grip=True))
    seeds = np.arange(N) + 30
    followers = {}
    for rope in (sim, single):
        grip_mid_cable(rope, seeds)
        rope.step(actions(dx=-1.0, c=1.0))  # back towards the fixed end: the cable to it is slack
        held0, x0, g0 = rope.held_mask(), rope.positions(), rope.gripper_state()
        rope.step_physics(actions(dy=1.0, c=1.0), 1)  # one 0.01 s step: one choice of the carried particles
        moved = rope.gripper_state()[:, :3] - g0[:, :3]
        assert np.allclose(moved[:, 1], MAX_DISPLACEMENT, atol=1e-7)
        w = rope._k.w.to_numpy()
        follows = np.abs(rope.positions() - x0 - moved[:, None, :]).max(axis=2) < 1e-6
        followers[rope is single] = []
        for e in range(N):
            n = int(rope.num_particles[e])
            held = np.flatnonzero(held0[e, :n])
            held = held[held >= 1]
            assert len(held) >= 3, "several particles between the fingers"
            gripped = np.flatnonzero(w[e, 1:n] == 0.0) + 1  # the grip's inverse mass at c = 1
            if rope is single:
                chosen = single_grip_particle(x0[e, :n], held0[e, :n], g0[e, 0])
                distance = np.abs(x0[e, held, 0] - g0[e, 0])
                assert gripped.tolist() == [chosen] and chosen == held[np.argmin(distance)], e
                assert follows[e, chosen] and not follows[e, held].all(), e
            else:
                assert gripped.tolist() == held.tolist() and follows[e, held].all(), e
            assert np.all(w[e, np.setdiff1d(held, gripped)] == NOMINAL_INVERSE_MASS)  # the others: free
            followers[rope is single].append(int(follows[e, held].sum()))
    assert sum(followers[True]) < sum(followers[False])


def test_physics_seed_gives_every_episode_one_physics_and_keeps_the_rest_of_the_draw(sim):
    """SimConfig.physics_seed (the authors' one physics draw, docs/FIDELITY.md row 8): every episode gets the
    stretch, bending and friction drawn from that seed, in the config's ranges; the particle count (and the
    rest of the episode's draw) is the episode seed's, as without it; -1 (the default) draws per episode;
    anything else is refused with one line."""
    from dlo_sim.rope import physics_draw

    one = RopeSim(N, SimConfig(physics_seed=7))
    seeds = np.arange(100, 100 + N)
    one.reset(seeds)
    sim.reset(seeds)
    theirs, ours = one.params, sim.params
    drawn = physics_draw(one.config)
    for key in ("stretch", "bending", "friction"):
        assert np.all(theirs[key] == np.float32(drawn[key])), key
        assert len(set(ours[key])) == N, key  # per episode without the option
    assert 0.8 <= drawn["stretch"] <= 1.4 and 0.8 <= drawn["bending"] <= 2.4 and 0.04 <= drawn["friction"] <= 0.3
    assert physics_draw(SimConfig(physics_seed=8)) != drawn
    assert np.array_equal(theirs["num_particles"], ours["num_particles"]) and len(set(ours["num_particles"])) > 1
    assert SimConfig().physics_seed == -1
    for bad in (-2, 1.5, True, "0"):
        with pytest.raises(ValueError, match="physics_seed must be an integer >= 0"):
            SimConfig(physics_seed=bad)
