"""The simulator's settings: every tunable of the physics, validated on construction. SI units throughout.

A run records them (its env options), the launcher and the sim node check them, the robustness perturbations
widen their ranges; a simulator backend (``dlo_interface.simulator``) receives one. Where the XPBD rebuild
needs its own numbers (sub-steps, compliances, damping, the contact radius), the reason stands next to each.
"""

from __future__ import annotations

from dataclasses import dataclass

from dlo_interface.grip import CARRY_LAWS
from dlo_interface.world import FINGER_CLEARANCE, GRIPPER_HEIGHT, P_MAX, PARTICLE_MASS, START_POSES

# m, largest contact_radius. Above half the finger gap (FINGER_CLEARANCE / 2) a particle between the fingers is
# pushed out by both every sub-step, with friction from both: a pinch, as Flex's collisionDistance 0.005 gives
# (docs/FIDELITY.md). 6 mm keeps particles 3 apart at rest (12.9 mm) out of self-contact (SELF_EXCLUDE).
MAX_CONTACT_RADIUS = 0.006


@dataclass(frozen=True)
class SimConfig:
    """Every tunable of the simulator. ``validate()`` runs on construction.

    Stiffness parameters are the paper's dimensionless numbers; they map onto XPBD compliances
    [m/N] by ``stretch_compliance`` / ``bending_compliance`` (power laws, so a stiffer cable has
    a smaller compliance and the whole range stays stable).
    """

    substeps: int = 4  # XPBD sub-steps per 0.01 s step (one constraint pass each)
    damping: float = 2.0  # 1/s, velocity damping rate (v *= exp(-damping * h))
    contact_radius: float = 0.004  # m, cable half-thickness for table/finger/self contact
    stretch_range: tuple = (0.8, 1.4)  # randomised stretch stiffness (paper)
    bending_range: tuple = (0.8, 2.4)  # randomised bending stiffness (paper)
    friction_range: tuple = (0.04, 0.3)  # randomised Coulomb coefficient (paper)
    num_particles_range: tuple = (30, 60)  # randomised particle count, inclusive (paper)
    # every particle's mass [kg], drawn per episode (last of its draws: the others do not change); the paper keeps it
    # fixed. XPBD weighs a mass only against the compliances (the solves see w / k + alpha = (w + k alpha) / k):
    # m times the nominal mass is the nominal cable with both compliances x m / PARTICLE_MASS (dlo_sim.rope)
    particle_mass_range: tuple = (PARTICLE_MASS, PARTICLE_MASS)
    stretch_compliance_ref: float = 1.0e-6  # m/N at stretch stiffness 1
    stretch_exponent: float = 4.0  # compliance ~ stiffness^-exponent
    bending_compliance_ref: float = 2.0e-4  # m/N at bending stiffness 1
    bending_exponent: float = 3.0
    pick_moves: int = 4  # pick-and-drop moves shaping the initial cable
    pick_steps: int = 60  # steps a picked particle is dragged
    pick_max_speed: float = 0.0025  # m per step
    drop_steps: int = 30  # steps after each release
    settle_steps: int = 100  # steps after the last drop
    max_speed: float = 20.0  # m/s, a faster particle flags the environment as exploded
    max_distance: float = 2.0  # m, |x|,|y|,|z| beyond this flags the environment as exploded
    # the authors' grip (docs/FIDELITY.md row 5), off by default: the grip law acts on ONE particle, the
    # held one nearest the finger axis in x (never particle 0), re-chosen every 0.01 s step (dlo_interface.grip)
    single_particle_grip: bool = False
    # the authors' one physics draw (docs/FIDELITY.md row 8), off (-1) by default: >= 0 gives every episode the
    # stretch, bending and friction drawn from this seed; the particle count and the start shape still come
    # from the episode's seed (their cached start configurations vary only those)
    physics_seed: int = -1
    # how the grip carries the cable (dlo_interface.grip): "paper" (the paper's law, the finite grip) or "authors" (their
    # Picker: one particle from their narrow held set moved by the whole displacement above c 0.5, cancelled
    # beyond 10 mm from a neighbour; docs/FIDELITY.md rows 5-6), off ("paper") by default
    carry_law: str = "paper"
    # where the gripper starts and moves (START_POSES): "ours" (5 mm behind the fixed end, at its height) or "authors"
    # (8 mm behind, 2.25 mm lower; docs/FIDELITY.md), off ("ours") by default
    start_pose: str = "ours"

    @property
    def gripper_height(self) -> float:
        """Height [m] of the gripper centre, the plane it moves in (START_POSES)."""
        return GRIPPER_HEIGHT - START_POSES[self.start_pose][1]

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        """Raise ValueError with a clear message for any physically invalid setting."""
        self._validate_step()
        self._validate_ranges()
        self._validate_positive()
        self._validate_variants()

    def _validate_step(self) -> None:
        """Sub-steps, damping and the contact radius."""
        if int(self.substeps) < 1:
            raise ValueError(f"substeps must be >= 1, got {self.substeps}")
        if self.damping < 0:
            raise ValueError(f"damping must be >= 0 1/s, got {self.damping}")
        if not 0 < self.contact_radius <= MAX_CONTACT_RADIUS:
            raise ValueError(
                f"contact_radius must be in (0, {MAX_CONTACT_RADIUS}] m (above "
                f"{0.5 * FINGER_CLEARANCE} m the fingers pinch the cable between them, as Flex's "
                f"5 mm collision distance does), got {self.contact_radius}"
            )

    def _validate_ranges(self) -> None:
        """The per-episode draws' ranges: low <= high, each within its bounds."""
        for name in ("stretch_range", "bending_range"):
            lo, hi = getattr(self, name)
            if not 0 < lo <= hi:
                raise ValueError(f"{name} must satisfy 0 < low <= high (stiffness is positive), got {(lo, hi)}")
        lo, hi = self.friction_range
        if not 0 <= lo <= hi:
            raise ValueError(f"friction_range must satisfy 0 <= low <= high, got {(lo, hi)}")
        lo, hi = self.particle_mass_range
        if not 0 < lo <= hi:
            raise ValueError(f"particle_mass_range must satisfy 0 < low <= high kg, got {(lo, hi)}")
        lo, hi = self.num_particles_range
        if not 2 <= lo <= hi <= P_MAX:
            raise ValueError(f"num_particles_range must satisfy 2 <= low <= high <= {P_MAX}, got {(lo, hi)}")

    def _validate_positive(self) -> None:
        """Compliance laws and limits positive, shaping step counts >= 0."""
        for name in (
            "stretch_compliance_ref",
            "bending_compliance_ref",
            "stretch_exponent",
            "bending_exponent",
            "pick_max_speed",
            "max_speed",
            "max_distance",
        ):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        for name in ("pick_moves", "pick_steps", "drop_steps", "settle_steps"):
            if int(getattr(self, name)) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")

    def _validate_variants(self) -> None:
        """The authors' variants: physics seed, start pose, carry law, one-particle grip."""
        if isinstance(self.physics_seed, bool) or not isinstance(self.physics_seed, int) or self.physics_seed < -1:
            raise ValueError(f"physics_seed must be an integer >= 0 (or -1: drawn per episode), got {self.physics_seed!r}")
        if self.start_pose not in START_POSES:
            raise ValueError(f"start_pose must be one of {', '.join(START_POSES)}, got {self.start_pose!r}")
        if self.carry_law not in CARRY_LAWS:
            raise ValueError(f"carry_law must be one of {', '.join(CARRY_LAWS)}, got {self.carry_law!r}")
        if not isinstance(self.single_particle_grip, bool):
            raise ValueError(f"single_particle_grip must be true or false, got {self.single_particle_grip!r}")

    def stretch_compliance(self, stretch):
        """XPBD compliance [m/N] of the (i, i+1) distance constraint for a stretch stiffness."""
        return self.stretch_compliance_ref * stretch**-self.stretch_exponent

    def bending_compliance(self, bending):
        """XPBD compliance [m/N] of the (i-1, i+1) distance constraint for a bending stiffness."""
        return self.bending_compliance_ref * bending**-self.bending_exponent
