"""The README picture: one randomised initial cable from the top camera and from the side.

Usage: python -m dlo_sim.figure [--seed 3] [--out docs/img/dlo_sim_initial_cable.png]
"""

import argparse

from dlo_interface.world import FINGER_CLEARANCE, FINGER_RADIUS

from .rope import RopeSim


def draw(seed: int, out: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sim = RopeSim(1)
    sim.reset([seed])
    image = sim.render()[0]
    n = sim.num_particles[0]
    x = sim.positions()[0, :n]
    g = sim.gripper_state()[0]
    p = sim.params
    cam = sim.camera

    fig, (top, side) = plt.subplots(1, 2, figsize=(8.0, 3.4), gridspec_kw={"width_ratios": [1, 1.5]})
    top.imshow(image, cmap="gray", vmin=0, vmax=255, interpolation="nearest")
    top.set_title(f"top camera {cam.width}x{cam.height} (cable 255, gripper 128)", fontsize=8)
    top.set_xlabel("u [px]", fontsize=8)
    top.set_ylabel("v [px]", fontsize=8)
    held = sim.held_mask()[0, :n]
    side.plot(x[:, 0], x[:, 2], "-", color="0.6", lw=1)
    side.scatter(x[~held, 0], x[~held, 2], s=6, color="tab:blue", label="particles")
    side.scatter(x[held, 0], x[held, 2], s=8, color="tab:red", label="held")
    for sign in (1.0, -1.0):
        side.add_patch(
            plt.Circle((g[0], g[2] + sign * (FINGER_RADIUS + 0.5 * FINGER_CLEARANCE)), FINGER_RADIUS, color="0.3", alpha=0.5)
        )
    side.axhline(0.0, color="k", lw=0.8)
    side.set_aspect("equal")
    side.set_xlim(min(x[:, 0].min(), g[0]) - 0.02, x[:, 0].max() + 0.02)
    side.set_ylim(-0.005, 0.135)
    side.set_xlabel("x [m]", fontsize=8)
    side.set_ylabel("z [m]", fontsize=8)
    side.set_title(
        f"side view, seed {seed}: {n} particles, stretch {p['stretch'][0]:.2f}, "
        f"bending {p['bending'][0]:.2f}, friction {p['friction'][0]:.2f}",
        fontsize=8,
    )
    side.legend(fontsize=7, loc="upper right")
    for ax in (top, side):
        ax.tick_params(labelsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=90)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--out", default="docs/img/dlo_sim_initial_cable.png")
    args = parser.parse_args()
    draw(args.seed, args.out)


if __name__ == "__main__":
    main()
