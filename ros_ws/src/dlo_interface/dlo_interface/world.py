"""The world every part of the graph shares: time, the workspace, the gripper, the cable. SI units throughout.

Frames and conventions: docs/ARCHITECTURE.md#world. The geometric constants come from the authors' public
SoftGym/Flex implementation (docs/ARCHITECTURE.md#constants); the simulator's own tunables are
``dlo_interface.sim_config.SimConfig``. Each constant has this one home: the simulator, perception, the policy,
a driver and bag analysis read it here.
"""

from __future__ import annotations

# ---- time
DT = 0.01  # s, one simulation step (one "env-step")
SUBSTEPS_PER_ACTION = 8  # simulation steps per agent action (0.08 s)
CONTROL_PERIOD = DT * SUBSTEPS_PER_ACTION  # s, one control step (one action): 0.08

# ---- the gripper and its workspace
MAX_DISPLACEMENT = 0.0025  # m per step at |action| = 1 (0.25 m/s)
WORKSPACE_HALF_WIDTH = 0.3  # m, gripper x and y are clipped to [-0.3, 0.3]
FINGER_RADIUS = 0.0125  # m, capsule radius of each finger
FINGER_HALF_LENGTH = 0.0075  # m, half-length of the capsule's axis segment (along gripper y)
FINGER_CLEARANCE = 0.0085  # m, gap between the two finger surfaces
GRIPPER_HEIGHT = 0.1  # m, height of the gripper centre (midway between the finger axes)
FINGER_AXIS_OFFSET = FINGER_RADIUS + 0.5 * FINGER_CLEARANCE  # m, each finger's axis above/below the gripper centre
GRIPPER_START_BEHIND = 0.005  # m, the gripper starts this far behind (-x) the fixed end
# SimConfig.start_pose: where the gripper starts, (behind the fixed end in -x, below it in -z) [m]. "authors": their
# Picker.reset puts the lower finger's axis 8 mm behind and 19 mm below particle 0, the upper 14.5 mm above it
# (SoftSlidingGym action_space_sliding.py:99): the gripper centre 8 mm behind and 2.25 mm below
START_POSES = {"ours": (GRIPPER_START_BEHIND, 0.0), "authors": (0.008, 0.00225)}

# ---- the cable
FIXED_END = (-0.25, 0.0, 0.1)  # m, where particle 0 is pinned
P_MAX = 60  # particles per environment, padded
PARTICLE_RADIUS = 0.008  # m, Flex interaction radius: held rule and rendered cable width
REST_SPACING = 0.0043  # m, rest distance between consecutive particles
NOMINAL_INVERSE_MASS = 2.0  # 1/kg, w_nom (particle mass 0.5 kg)
PARTICLE_MASS = 1.0 / NOMINAL_INVERSE_MASS  # kg, the nominal particle mass
GRAVITY = 9.8  # m/s^2
