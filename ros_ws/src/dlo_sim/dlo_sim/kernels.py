"""Taichi fields and kernels of the batched rope: XPBD physics, grip, explosion check, and one
read-back kernel (``observe``: positions, held set, gripper, top-view render).

Layout: one environment per outer (parallel) loop iteration; everything inside an environment
runs serially (Gauss-Seidel), so an environment's result does not depend on the batch around it.
Per-environment arrays are padded to ``P_MAX`` particles; loops stop at ``n[e]``.
"""

import math

from dlo_common.taichi_runtime import init as init_taichi  # before taichi: no "[Taichi] version" banner (see there)

# isort: split
import taichi as ti
from dlo_interface.camera import IMAGE_CABLE, IMAGE_GRIPPER
from dlo_interface.grip import AUTHORS_MAX_NEIGHBOUR_DISTANCE, GRIP_SLIP_STRAIN  # dlo_interface.grip states the rules in numpy
from dlo_interface.task import AUTHORS_HELD_ABOVE, AUTHORS_HELD_DISTANCE, AUTHORS_HELD_HALF_WIDTH
from dlo_interface.world import (
    DT,
    FINGER_AXIS_OFFSET,
    FINGER_HALF_LENGTH,
    FINGER_RADIUS,
    FIXED_END,
    GRAVITY,
    GRIPPER_HEIGHT,
    MAX_DISPLACEMENT,
    NOMINAL_INVERSE_MASS,
    P_MAX,
    PARTICLE_RADIUS,
    REST_SPACING,
    START_POSES,
    WORKSPACE_HALF_WIDTH,
)

HELD_DISTANCE = PARTICLE_RADIUS + FINGER_RADIUS + REST_SPACING  # m, held rule (docs/ARCHITECTURE.md#constants)
MAX_CORRECTION = 0.25 * REST_SPACING  # m, per sub-step cap on a particle's direct-solve correction
SELF_EXCLUDE = 3  # particles closer than this along the chain never self-collide
THREAD_POOL_GRAIN = 512  # loop items Taichi 1.7 hands one CPU thread at the least (measured; see RopeKernels.__init__)


def baked_in(num_envs: int, cfg, camera, camera_per_env: bool = False) -> dict:
    """What a :class:`RopeKernels`' kernels take as compile-time constants (its attributes of these names): two
    RopeKernels with the same values run the same machine code (:func:`kernels_for` reuses one on that ground)."""
    behind, below = START_POSES[cfg.start_pose]
    h = DT / cfg.substeps  # s, sub-step
    yaw = float(getattr(camera, "yaw", 0.0))  # compile-time: 0 (every camera but a perturbed one) compiles today's
    return {
        "num_envs": int(num_envs),
        # Taichi 1.7's CPU thread pool gives a thread work only in runs of >= 512 loop items, so a
        # loop over a few hundred envs runs on one core. The stepping kernels spread each env over
        # ``spread`` items (only the first does the work), so every core gets envs.
        "spread": 1 if num_envs == 1 else -(-THREAD_POOL_GRAIN * 2 // num_envs),
        "substeps": int(cfg.substeps),
        "h": h,
        "damping_factor": float(pow(2.718281828459045, -cfg.damping * h)),
        "r": float(cfg.contact_radius),
        "max_speed": float(cfg.max_speed),
        "max_distance": float(cfg.max_distance),
        "single_particle_grip": bool(cfg.single_particle_grip),  # compile-time: off compiles today's kernel
        "authors_carry": cfg.carry_law == "authors",  # compile-time: "paper" compiles today's kernel
        "gripper_start": (float(FIXED_END[0] - behind), float(FIXED_END[1]), float(GRIPPER_HEIGHT - below)),
        "cam_f": (float(camera.fx), float(camera.fy)),
        "cam_c": (float(camera.cx), float(camera.cy)),
        "cam_pos": tuple(float(p) for p in camera.position),
        "cam_rotated": yaw != 0.0,
        "cam_turn": (math.cos(yaw), math.sin(yaw)),
        "cam_size": (int(camera.height), int(camera.width)),
        # compile-time: off compiles today's kernel; on, each env's camera is moved (cam_shift [m], world x, y) and
        # turned (cam_yaw: cos, sin) from ``camera`` by its own amount (per-episode camera randomisation)
        "cam_per_env": bool(camera_per_env),
    }


# Released RopeKernels by what their kernels bake in. Taichi compiles a data-oriented object's kernels for that
# object (2-4 s, 5-13 s without its offline cache, per object), so a process that builds simulators one after the
# other (tests, evaluations, tools) reuses a released one of the same constants instead: the same machine code.
_RELEASED: dict[tuple, list] = {}


def kernels_for(num_envs: int, cfg, camera, camera_per_env: bool = False) -> "RopeKernels":
    """A :class:`RopeKernels` in the state of a new one: a released one with the same :func:`baked_in` values (every
    field set to what a new field holds), else a new one. Give it back with :func:`release` when its user is gone."""
    key = tuple(sorted(baked_in(num_envs, cfg, camera, camera_per_env).items()))
    pool = _RELEASED.get(key)
    if not pool:
        kernels = RopeKernels(num_envs, cfg, camera, camera_per_env)
        kernels.pool_key = key
        return kernels
    kernels = pool.pop()
    kernels.clear()
    return kernels


def release(kernels: "RopeKernels") -> None:
    """Give a RopeKernels from :func:`kernels_for` back for reuse (its user must not touch it afterwards)."""
    _RELEASED.setdefault(kernels.pool_key, []).append(kernels)


@ti.data_oriented
class RopeKernels:
    """All Taichi state of ``num_envs`` ropes + grippers, and the kernels that advance and draw them."""

    def __init__(self, num_envs: int, cfg, camera, camera_per_env: bool = False):
        init_taichi()
        for name, value in baked_in(num_envs, cfg, camera, camera_per_env).items():
            setattr(self, name, value)
        self.cam_shift = ti.Vector.field(2, ti.f32, num_envs)
        self.cam_yaw = ti.Vector.field(2, ti.f32, num_envs)
        self.cam_yaw.fill(ti.Vector([1.0, 0.0]))

        shape = (num_envs, P_MAX)
        self.x = ti.Vector.field(3, ti.f32, shape)  # m, positions (predicted during a sub-step)
        self.x_old = ti.Vector.field(3, ti.f32, shape)  # m, positions at the start of the sub-step
        self.v = ti.Vector.field(3, ti.f32, shape)  # m/s
        self.w = ti.field(ti.f32, shape)  # 1/kg, inverse mass this step (grip law, pin, pick)
        self.carry = ti.field(ti.f32, shape)  # fraction of the gripper motion a particle follows
        self.seg_dir = ti.Vector.field(3, ti.f32, shape)  # unit direction of segment (k, k+1)
        self.sup = ti.field(ti.f32, shape)  # Thomas algorithm: normalised super-diagonal
        self.rhs = ti.field(ti.f32, shape)  # Thomas algorithm: right-hand side, then multipliers
        self.n = ti.field(ti.i32, num_envs)  # particles in use
        self.alpha_stretch = ti.field(ti.f32, num_envs)  # m/N
        self.alpha_bend = ti.field(ti.f32, num_envs)  # m/N
        self.mu = ti.field(ti.f32, num_envs)  # Coulomb friction, table and fingers
        self.gripper = ti.Vector.field(3, ti.f32, num_envs)  # m, gripper centre
        self.closure = ti.field(ti.f32, num_envs)  # c in [0, 1]
        self.cmd = ti.Vector.field(3, ti.f32, num_envs)  # action [dx, dy, c] in [-1, 1]
        self.active = ti.field(ti.i32, num_envs)  # 1 = advanced by ``advance``
        self.pick = ti.field(ti.i32, num_envs)  # particle dragged kinematically (-1: none)
        self.pick_vel = ti.Vector.field(3, ti.f32, num_envs)  # m/s of the dragged particle
        self.bad = ti.field(ti.i32, num_envs)  # 1 = NaN/inf/explosion seen

    def clear(self) -> None:
        """Every field to what a new field holds (zeros; ``cam_yaw`` (1, 0), as __init__ sets it)."""
        from taichi.lang.field import Field  # scalar and vector fields alike

        for value in vars(self).values():
            if isinstance(value, Field):
                value.fill(0)
        self.cam_yaw.fill(ti.Vector([1.0, 0.0]))

    # ---------------------------------------------------------------- reset
    @ti.kernel
    def lay_straight(self, mask: ti.types.ndarray()):
        """Reset masked envs: straight cable along +x from the fixed end, gripper at the start, at rest."""
        for e in range(self.num_envs):
            if mask[e] != 0:
                for i in range(P_MAX):
                    p = ti.Vector([FIXED_END[0] + i * REST_SPACING, FIXED_END[1], FIXED_END[2]])
                    if i >= self.n[e]:
                        p = ti.Vector([0.0, 0.0, 0.0])
                    self.x[e, i] = p
                    self.x_old[e, i] = p
                    self.v[e, i] = ti.Vector([0.0, 0.0, 0.0])
                self.gripper[e] = ti.Vector(self.gripper_start)
                self.closure[e] = 0.0
                self.pick[e] = -1
                self.bad[e] = 0

    # ---------------------------------------------------------------- physics
    @ti.func
    def grip_inverse_mass(self, c):
        """The paper's grip law (mirror of ``grip.inverse_mass``) [1/kg]."""
        w_nom = NOMINAL_INVERSE_MASS
        return ti.max(2.25 * w_nom - 2.5 * w_nom * ti.max(c, 0.5), 0.0)

    @ti.func
    def is_held(self, e, i, g):
        """Held rule: within HELD_DISTANCE of the lower finger's axis (in x-z), inside the finger's
        extent along y, and above that axis."""
        q = self.x[e, i]
        dx = q.x - g.x
        dz = q.z - (g.z - FINGER_AXIS_OFFSET)
        return (
            ti.abs(q.y - g.y) <= FINGER_HALF_LENGTH + FINGER_RADIUS
            and dx * dx + dz * dz <= HELD_DISTANCE * HELD_DISTANCE
            and dz > 0.0
        )

    @ti.func
    def single_grip_particle(self, e, g):
        """The single-particle grip's particle (``dlo_interface.grip.single_grip_particle``): the held one
        nearest the finger axis in x, never particle 0, ties to the lower index; -1 if none is held."""
        chosen = -1
        nearest = 0.0
        for i in range(1, self.n[e]):
            if self.is_held(e, i, g):
                d = ti.abs(self.x[e, i].x - g.x)
                if chosen < 0 or d < nearest:
                    chosen = i
                    nearest = d
        return chosen

    @ti.func
    def authors_grip_particle(self, e, g):
        """The authors' carry law's particle (``dlo_interface.grip.authors_grip_particle``): in their narrow held set
        (``dlo_interface.task.held_mask_authors``), the one nearest the finger axis in x, never particle 0, ties to
        the lower index; -1 if that set is empty."""
        chosen = -1
        nearest = 0.0
        for i in range(1, self.n[e]):
            q = self.x[e, i]
            dx = q.x - g.x
            dz = q.z - (g.z - FINGER_AXIS_OFFSET)
            if (
                ti.abs(q.y - g.y) < AUTHORS_HELD_HALF_WIDTH
                and dx * dx + dz * dz < AUTHORS_HELD_DISTANCE**2
                and dz > AUTHORS_HELD_ABOVE
            ):
                d = ti.abs(dx)
                if chosen < 0 or d < nearest:
                    chosen = i
                    nearest = d
        return chosen

    @ti.func
    def authors_cancel(self, e, dg):
        """The authors' carry law's stretch limit: the sub-step's gripper motion ``dg`` is cancelled (0) when it
        would take the carried particle further than AUTHORS_MAX_NEIGHBOUR_DISTANCE from a neighbour."""
        for i in range(1, self.n[e]):
            if self.carry[e, i] > 0.0:
                q = self.x[e, i] + dg
                if (q - self.x[e, i - 1]).norm() > AUTHORS_MAX_NEIGHBOUR_DISTANCE:
                    dg = ti.Vector([0.0, 0.0, 0.0])
                elif i + 1 < self.n[e] and (q - self.x[e, i + 1]).norm() > AUTHORS_MAX_NEIGHBOUR_DISTANCE:
                    dg = ti.Vector([0.0, 0.0, 0.0])
        return dg

    @ti.func
    def update_grip(self, e, g, c):
        """Held rule + grip law: inverse mass and carried fraction of every particle for this step.
        With ``single_particle_grip`` the law acts on one held particle only (``single_grip_particle``)."""
        w_held = self.grip_inverse_mass(c)
        chosen = -1
        if ti.static(self.authors_carry):
            if c > 0.5:
                chosen = self.authors_grip_particle(e, g)
        elif ti.static(self.single_particle_grip):
            chosen = self.single_grip_particle(e, g)
        for i in range(self.n[e]):
            inside = self.is_held(e, i, g)
            if ti.static(self.single_particle_grip or self.authors_carry):
                inside = i == chosen
            w = NOMINAL_INVERSE_MASS
            carry = 0.0
            if inside:
                w = w_held
                carry = 1.0 - w_held / NOMINAL_INVERSE_MASS
                if ti.static(self.authors_carry):
                    carry = 1.0  # moved by the whole displacement; w_held still weighs it in the constraints
            if i == 0 or i == self.pick[e]:
                w = 0.0
                carry = 0.0
            self.w[e, i] = w
            self.carry[e, i] = carry

    @ti.func
    def predict(self, e, dg):
        """Explicit step: damping, gravity, carried fraction of the gripper motion ``dg`` [m]."""
        h = self.h
        for i in range(1, self.n[e]):
            q = self.x[e, i]
            self.x_old[e, i] = q
            if i == self.pick[e]:
                dragged = q + self.pick_vel[e] * h
                dragged.x = ti.min(ti.max(dragged.x, -WORKSPACE_HALF_WIDTH), WORKSPACE_HALF_WIDTH)
                dragged.y = ti.min(ti.max(dragged.y, -WORKSPACE_HALF_WIDTH), WORKSPACE_HALF_WIDTH)
                anchor = ti.Vector([FIXED_END[0], FIXED_END[1], FIXED_END[2]])
                if (dragged - anchor).norm() < 0.9 * i * REST_SPACING:  # never pull the pinned cable taut
                    self.x[e, i] = dragged
            else:
                v = self.v[e, i] * self.damping_factor + ti.Vector([0.0, 0.0, -GRAVITY * h])
                f = self.carry[e, i]
                if ti.static(self.authors_carry):
                    if f > 0.0:  # set to the displaced position (the step starts there), then free with w
                        self.x_old[e, i] = q + dg
                        self.x[e, i] = q + dg
                        if self.w[e, i] > 0.0:
                            self.x[e, i] += v * h
                    else:
                        self.x[e, i] = q + v * h
                else:
                    self.x[e, i] = (1.0 - f) * (q + v * h) + f * (q + dg)

    @ti.func
    def taut_reach(self, i):
        """Straight-line distance [m] from the fixed end at which particle i's cable is pulled taut."""
        return (1.0 + GRIP_SLIP_STRAIN) * i * REST_SPACING

    @ti.func
    def stall_firm_grip(self, e, dg):
        """A firm grip (c >= 0.9: held particles fully carried) on a cable pulled straight from the
        fixed end stops the gripper: the part of the sub-step motion ``dg`` [m] that would take a
        held particle beyond its rest length along the cable from the fixed end is removed (it may
        still move sideways or back). This is the robot's force limit; a lighter grip slides instead.
        ``dlo_interface.grip.stall_firm_grip`` is the same rule in numpy (test_kernel_rules checks they agree)."""
        anchor = self.x[e, 0]
        for i in range(1, self.n[e]):
            if self.carry[e, i] >= 1.0:
                d = self.x[e, i] - anchor
                reach = self.taut_reach(i)
                if (d + dg).norm() > reach:
                    # the gripper moves in the horizontal plane only (docs/ARCHITECTURE.md#world): remove the
                    # part of dg along the horizontal direction away from the fixed end, never add z
                    r = ti.Vector([d.x, d.y, 0.0])
                    r /= ti.max(r.norm(), 1e-9)
                    outward = dg.dot(r)
                    if outward > 0.0:
                        dg -= outward * r
        return dg

    @ti.func
    def slip_taut_grip(self, e):
        """Finite grip: a gripped particle (carried, so the stretch solve cannot hold it back) is kept
        within (1 + GRIP_SLIP_STRAIN) of its rest length along the cable from the fixed end (a long-range
        attachment, Kim et al. 2012). Pulling a taut cable further makes it slide through the fingers
        instead of stretching it."""
        anchor = self.x[e, 0]
        for i in range(1, self.n[e]):
            if self.carry[e, i] > 0.0:
                d = self.x[e, i] - anchor
                reach = self.taut_reach(i)
                length = d.norm()
                if length > reach:
                    self.x[e, i] = anchor + d * (reach / length)

    @ti.func
    def distance_constraint(self, e, i, j, rest, alpha_tilde):
        """One XPBD projection of |x_j - x_i| = rest; returns the current distance [m]."""
        d = self.x[e, j] - self.x[e, i]
        length = d.norm()
        w_sum = self.w[e, i] + self.w[e, j]
        if w_sum > 0.0 and length > 1e-9:
            corr = (length - rest) / (w_sum + alpha_tilde) / length * d
            self.x[e, i] += self.w[e, i] * corr
            self.x[e, j] -= self.w[e, j] * corr
        return length

    @ti.func
    def solve_bending(self, e):
        """Bending as (i-1, i+1) distance constraints, one Gauss-Seidel pass. One-sided: they only
        push apart (resist bending), never pull together, so a taut cable does not buckle."""
        a_b = self.alpha_bend[e] / (self.h * self.h)
        rest = 2.0 * REST_SPACING
        for i in range(1, self.n[e] - 1):
            d = self.x[e, i + 1] - self.x[e, i - 1]
            if d.dot(d) < rest * rest:
                self.distance_constraint(e, i - 1, i + 1, rest, a_b)

    @ti.func
    def solve_stretch(self, e):
        """All (i, i+1) stretch constraints. First a direct solve: the linearised XPBD system is
        tridiagonal (Deul et al. 2018), solved by the Thomas algorithm, each particle's correction
        clamped to MAX_CORRECTION (robust where contacts fight a taut cable); then one Gauss-Seidel
        sweep. Returns the longest segment [m] (bounds how far self-collision may skip)."""
        a_s = self.alpha_stretch[e] / (self.h * self.h)
        m = self.n[e] - 1  # constraints
        for k in range(m):
            d = self.x[e, k + 1] - self.x[e, k]
            length = d.norm()
            self.seg_dir[e, k] = d / ti.max(length, 1e-9)
            self.rhs[e, k] = REST_SPACING - length  # -C_k
        # forward elimination: diagonal w_k + w_k+1 + a_s, off-diagonal -w_k+1 (n_k . n_k+1)
        for k in range(m):
            b = self.w[e, k] + self.w[e, k + 1] + a_s
            rhs = self.rhs[e, k]
            if k > 0:
                o_prev = -self.w[e, k] * self.seg_dir[e, k - 1].dot(self.seg_dir[e, k])
                b -= o_prev * self.sup[e, k - 1]
                rhs -= o_prev * self.rhs[e, k - 1]
            o = 0.0
            if k + 1 < m:
                o = -self.w[e, k + 1] * self.seg_dir[e, k].dot(self.seg_dir[e, k + 1])
            self.sup[e, k] = o / b
            self.rhs[e, k] = rhs / b
        for j in range(1, m):  # back substitution: rhs becomes the multipliers
            k = m - 1 - j
            self.rhs[e, k] -= self.sup[e, k] * self.rhs[e, k + 1]
        for i in range(1, m + 1):  # dx_i = w_i (n_i-1 dl_i-1 - n_i dl_i)
            pull = self.seg_dir[e, i - 1] * self.rhs[e, i - 1]
            if i < m:
                pull -= self.seg_dir[e, i] * self.rhs[e, i]
            dx = self.w[e, i] * pull
            size = dx.norm()
            if size > MAX_CORRECTION:
                dx *= MAX_CORRECTION / size
            self.x[e, i] += dx
        longest = 0.0
        for i in range(m):
            longest = ti.max(longest, self.distance_constraint(e, i, i + 1, REST_SPACING, a_s))
        return longest

    @ti.func
    def solve_self_collision(self, e, longest):
        """Push apart particle pairs closer than two contact radii (|i - j| >= SELF_EXCLUDE).

        O(P^2) with an early-out: a pair at distance d proves the next (d - 2r) / longest particles
        along the chain are out of reach, so they are skipped."""
        n = self.n[e]
        two_r = 2.0 * self.r
        reach = ti.max(longest, 1e-4)
        for i in range(n):
            j = i + SELF_EXCLUDE
            while j < n:
                d = self.x[e, j] - self.x[e, i]
                dist2 = d.dot(d)
                skip = 1
                if dist2 < two_r * two_r:
                    w_sum = self.w[e, i] + self.w[e, j]
                    if w_sum > 0.0 and dist2 > 1e-18:
                        dist = ti.sqrt(dist2)
                        corr = (dist - two_r) / (w_sum * dist) * d
                        self.x[e, i] += self.w[e, i] * corr
                        self.x[e, j] -= self.w[e, j] * corr
                else:
                    skip = ti.min(ti.max(ti.cast((ti.sqrt(dist2) - two_r) / reach, ti.i32), 1), n)
                j += skip

    @ti.func
    def contact(self, e, i, normal, depth, surface_motion):
        """Resolve one contact of particle i: push out by ``depth`` along ``normal`` and apply
        Coulomb friction (position-based) to its motion relative to the surface this sub-step."""
        q = self.x[e, i] + depth * normal
        slip = (q - self.x_old[e, i]) - surface_motion
        tangent = slip - slip.dot(normal) * normal
        t_len = tangent.norm()
        budget = self.mu[e] * depth
        if t_len <= budget:
            q -= tangent
        else:
            q -= tangent * (budget / t_len)
        self.x[e, i] = q

    @ti.func
    def solve_fingers(self, e, g, dg):
        """Keep particles outside both finger capsules (axis along y, centred at g +- offset)."""
        reach = FINGER_RADIUS + self.r
        for k in ti.static(range(2)):
            sign = 1.0 - 2.0 * k
            cz = g.z + sign * FINGER_AXIS_OFFSET
            for i in range(1, self.n[e]):
                if self.w[e, i] > 0.0:
                    q = self.x[e, i]
                    axis_y = g.y + ti.min(ti.max(q.y - g.y, -FINGER_HALF_LENGTH), FINGER_HALF_LENGTH)
                    d = q - ti.Vector([g.x, axis_y, cz])
                    dist2 = d.dot(d)
                    if dist2 < reach * reach:
                        dist = ti.sqrt(dist2)
                        normal = ti.Vector([0.0, 0.0, -sign])
                        if dist > 1e-9:
                            normal = d / dist
                        surface_motion = dg
                        if ti.static(self.authors_carry):  # the carried particle starts the step displaced
                            surface_motion = dg * (1.0 - self.carry[e, i])
                        self.contact(e, i, normal, reach - dist, surface_motion)

    @ti.func
    def solve_table(self, e):
        """Table z = 0: particles stay ``contact_radius`` above it, with Coulomb friction."""
        for i in range(1, self.n[e]):
            depth = self.r - self.x[e, i].z
            if depth > 0.0 and self.w[e, i] > 0.0:
                self.contact(e, i, ti.Vector([0.0, 0.0, 1.0]), depth, ti.Vector([0.0, 0.0, 0.0]))

    @ti.func
    def update_velocities(self, e):
        for i in range(1, self.n[e]):
            self.v[e, i] = (self.x[e, i] - self.x_old[e, i]) / self.h

    @ti.func
    def exploded(self, e) -> ti.i32:
        """1 if any particle is NaN/inf, too fast or too far."""
        ok = 1
        for i in range(self.n[e]):
            p = self.x[e, i]
            v = self.v[e, i]
            if not (ti.abs(p).max() < self.max_distance and v.norm_sqr() < self.max_speed * self.max_speed):
                ok = 0
            for k in ti.static(range(3)):  # NaN/inf by exponent bits: immune to fast-math folding
                if ti.bit_cast(p[k], ti.i32) & 0x7F800000 == 0x7F800000:
                    ok = 0
                if ti.bit_cast(v[k], ti.i32) & 0x7F800000 == 0x7F800000:
                    ok = 0
        return 1 - ok

    @ti.func
    def step_env(self, e):
        """One 0.01 s step of environment e under its command ``cmd[e]``."""
        a = self.cmd[e]
        c = 0.5 * (a.z + 1.0)
        g0 = self.gripper[e]
        g1 = g0 + ti.Vector([a.x * MAX_DISPLACEMENT, a.y * MAX_DISPLACEMENT, 0.0])
        g1.x = ti.min(ti.max(g1.x, -WORKSPACE_HALF_WIDTH), WORKSPACE_HALF_WIDTH)
        g1.y = ti.min(ti.max(g1.y, -WORKSPACE_HALF_WIDTH), WORKSPACE_HALF_WIDTH)
        self.closure[e] = c
        self.update_grip(e, g0, c)
        dg_commanded = (g1 - g0) / self.substeps
        g = g0
        for _k in range(self.substeps):
            dg = dg_commanded
            if ti.static(self.authors_carry):
                dg = self.authors_cancel(e, dg_commanded)
            else:
                dg = self.stall_firm_grip(e, dg_commanded)
            g = g + dg
            self.predict(e, dg)
            if ti.static(not self.authors_carry):
                self.slip_taut_grip(e)
            self.solve_bending(e)
            longest = self.solve_stretch(e)
            self.solve_self_collision(e, longest)
            self.solve_fingers(e, g, dg)
            self.solve_table(e)
            self.update_velocities(e)
        self.gripper[e] = g
        self.bad[e] = self.exploded(e)

    # ---------------------------------------------------------------- rendering
    @ti.func
    def project(self, e, p):
        """World point [m] -> (u, v) pixel coordinates in env e's camera and metres-to-pixels scale at its depth."""
        depth = self.cam_pos[2] - p.z
        dx = p.x - self.cam_pos[0]
        dy = p.y - self.cam_pos[1]
        if ti.static(self.cam_rotated):  # the camera turned about its optical axis (TopCamera.yaw)
            turned_x = self.cam_turn[0] * dx + self.cam_turn[1] * dy
            dy = self.cam_turn[0] * dy - self.cam_turn[1] * dx
            dx = turned_x
        if ti.static(self.cam_per_env):  # env e's own camera: moved, then turned about its axis
            dx -= self.cam_shift[e].x
            dy -= self.cam_shift[e].y
            turn = self.cam_yaw[e]
            turned_x = turn.x * dx + turn.y * dy
            dy = turn.x * dy - turn.y * dx
            dx = turned_x
        u = self.cam_c[0] + self.cam_f[0] * dx / depth
        v = self.cam_c[1] - self.cam_f[1] * dy / depth
        return ti.Vector([u, v]), self.cam_f[0] / depth

    @ti.func
    def draw_capsule(self, image: ti.template(), e, a, b, ra, rb, value):
        """Fill pixels whose centre lies within the capsule a-b (pixel coords, radii ra -> rb)."""
        lo = ti.min(a - ra, b - rb)
        hi = ti.max(a + ra, b + rb)
        u0 = ti.max(ti.cast(ti.floor(lo.x), ti.i32), 0)
        v0 = ti.max(ti.cast(ti.floor(lo.y), ti.i32), 0)
        u1 = ti.min(ti.cast(ti.floor(hi.x), ti.i32), self.cam_size[1] - 1)
        v1 = ti.min(ti.cast(ti.floor(hi.y), ti.i32), self.cam_size[0] - 1)
        ab = b - a
        ab2 = ti.max(ab.dot(ab), 1e-12)
        for pv in range(v0, v1 + 1):
            for pu in range(u0, u1 + 1):
                q = ti.Vector([pu + 0.5, pv + 0.5])
                t = ti.min(ti.max((q - a).dot(ab) / ab2, 0.0), 1.0)
                rad = ra + t * (rb - ra)
                d = q - (a + t * ab)
                if d.dot(d) <= rad * rad:
                    image[e, pv, pu] = ti.cast(value, ti.u8)

    @ti.func
    def render_env(self, image: ti.template(), e):
        """Top view of env e into ``image[e]`` (H, W), which must hold background (0): cable
        capsules 255, the top finger's footprint 128 over them."""
        for i in range(self.n[e] - 1):
            a, sa = self.project(e, self.x[e, i])
            b, sb = self.project(e, self.x[e, i + 1])
            self.draw_capsule(image, e, a, b, PARTICLE_RADIUS * sa, PARTICLE_RADIUS * sb, IMAGE_CABLE)
        g = self.gripper[e]
        top = g.z + FINGER_AXIS_OFFSET
        a, s = self.project(e, ti.Vector([g.x, g.y - FINGER_HALF_LENGTH, top]))
        b, _ = self.project(e, ti.Vector([g.x, g.y + FINGER_HALF_LENGTH, top]))
        self.draw_capsule(image, e, a, b, FINGER_RADIUS * s, FINGER_RADIUS * s, IMAGE_GRIPPER)

    # ---------------------------------------------------------------- the one kernel
    @ti.func
    def read_back(self, e, positions: ti.template(), held: ti.template(), gripper: ti.template()):
        """Env e's positions [m] (padded rows 0), held mask (held rule) and gripper x, y, z [m], c."""
        g = self.gripper[e]
        for k in ti.static(range(3)):
            gripper[e, k] = g[k]
        gripper[e, 3] = self.closure[e]
        for i in range(P_MAX):
            for k in ti.static(range(3)):
                positions[e, i, k] = self.x[e, i][k]
            held[e, i] = ti.u8(1) if i < self.n[e] and self.is_held(e, i, g) else ti.u8(0)

    @ti.func
    def advance_env(self, e, actions: ti.template(), n_steps) -> ti.i32:
        """``n_steps`` (>= 0) steps of 0.01 s of env e, if active, under ``actions[e]``; 1 if it exploded."""
        bad = 0
        if self.active[e] != 0 and n_steps > 0:
            self.cmd[e] = ti.Vector([actions[e, 0], actions[e, 1], actions[e, 2]])
            self.bad[e] = 0
            for _ in range(n_steps):
                if self.bad[e] == 0:
                    self.step_env(e)
            bad = self.bad[e]
        return bad

    @ti.kernel
    def advance(self, actions: ti.types.ndarray(dtype=ti.f32, ndim=2), n_steps: ti.i32) -> ti.i32:
        """``n_steps`` steps of 0.01 s for every active env under ``actions`` (N, 3); returns how
        many envs exploded."""
        n_bad = 0
        ti.loop_config(serialize=self.num_envs == 1)  # a lone env skips the thread pool
        for item in range(self.num_envs * self.spread):
            if item % self.spread == 0:
                n_bad += self.advance_env(item // self.spread, actions, n_steps)
        return n_bad

    @ti.kernel
    def advance_and_read(
        self,
        actions: ti.types.ndarray(dtype=ti.f32, ndim=2),
        n_steps: ti.i32,
        positions: ti.types.ndarray(dtype=ti.f32, ndim=3),
        held: ti.types.ndarray(dtype=ti.u8, ndim=2),
        gripper: ti.types.ndarray(dtype=ti.f32, ndim=2),
        image: ti.types.ndarray(dtype=ti.u8, ndim=3),
        draw: ti.i32,
    ) -> ti.i32:
        """``advance`` (``n_steps`` may be 0), then everything the task and the observations read, in
        the same launch: positions (N, P_MAX, 3), held (N, P_MAX) 0/1, gripper (N, 4); if ``draw``
        also the top view into ``image`` (N, H, W), given all 0 (else it is not touched)."""
        n_bad = 0
        ti.loop_config(serialize=self.num_envs == 1)
        for item in range(self.num_envs * self.spread):
            if item % self.spread == 0:
                e = item // self.spread
                n_bad += self.advance_env(e, actions, n_steps)
                self.read_back(e, positions, held, gripper)
                if draw != 0:
                    self.render_env(image, e)
        return n_bad
