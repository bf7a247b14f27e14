"""Episode videos from a recorded bag: one MP4 (H.264) or GIF per episode, one frame per control step.

Each frame shows the top camera's image of that step, a side view (x-z) of the particles (held
ones red) with the two fingers and the fixed end, and a strip of signals over the whole episode with
a cursor at the current step: the closure, the observations as the episode plots draw them (the plot
series of the registry's observation topics, ``dlo_common.topics``, one row per unit: unitless ones with
the closure, angles [rad], offsets [mm], a row for each other unit; ``dlo_bag.analysis.observation_axes``)
and the reward; the title names the episode,
seed and return, the policy (``dlo-analyze`` passes the bag's own record: ``dlo_bag.analysis.policy_label``)
and the outcome under both rules (paper text, authors' code). Frames
are drawn with matplotlib (Agg, no display) and encoded by the ffmpeg that ``imageio-ffmpeg``
ships (libx264, yuv420p, +faststart: plays in browsers and players; GIF: a palette per video).

Real time by default: a control step lasts 0.08 s, so ``fps = 12.5 * speed``.

    from dlo_bag.video import render_episode_video
    render_episode_video(episode, streams, summary, "out/episode_0000.mp4", policy="sac")
"""

from __future__ import annotations

import textwrap
import time
from pathlib import Path

import numpy as np
from dlo_interface.cloud import unpack_particles
from dlo_interface.world import CONTROL_PERIOD, FINGER_AXIS_OFFSET, FINGER_RADIUS, FIXED_END

from .analysis import observation_axes, unit_axis_label
from .episode_series import episode_series

FORMATS = ("mp4", "gif")
REALTIME_FPS = 1.0 / CONTROL_PERIOD  # 12.5 frames per second = one control step per frame
DEFAULT_WIDTH = {"mp4": 960, "gif": 480}
ASPECT = 0.75  # height / width


class VideoError(RuntimeError):
    """The video cannot be written (encoder missing or failing)."""


STRIP_ROW = 0.6  # height of a strip row, relative to the views' 3.0 (the paper's graph: 4 rows)
TITLE_CHARS = 100  # characters of a title line in a frame of any width (the font follows the width): a longer
# policy label is wrapped onto a second line


def video_title(episode: int, summary: dict, policy: str | None) -> str:
    """Three lines: the episode (episode, seed, return), the policy that drove it (``policy``: a label such as
    ``dlo_bag.analysis.policy_label`` makes of the bag's record; None: 'not recorded'; wrapped onto a fourth line
    beyond TITLE_CHARS), then the outcome under both rules."""
    seed = summary.get("seed", "?")
    ret = summary.get("episode_return", summary.get("recorded_return"))
    head = f"episode {episode}  ·  seed {seed}" + (f"  ·  return {ret:.2f}" if ret is not None else "")
    if summary.get("complete", True):
        tail = f"outcome: {summary.get('outcome', '?')} (paper rule)  ·  {summary.get('outcome_authors', '?')} (authors' rule)"
    else:
        tail = "episode unfinished in the bag: no outcome"
    who = textwrap.fill(f"policy {policy or 'not recorded'}", TITLE_CHARS, break_on_hyphens=False)
    return head + "\n" + who + "\n" + tail


class EpisodeFrames:
    """Draws the frames of one episode (matplotlib Agg canvas reused for every frame)."""

    def __init__(
        self, episode: int, streams: dict, summary: dict, *, policy: str | None = None, width: int = DEFAULT_WIDTH["mp4"]
    ) -> None:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
        from matplotlib.patches import Circle
        from matplotlib.ticker import MaxNLocator

        self.series = s = episode_series(episode, streams)
        self.steps = [int(k) for k in s.steps]
        self.images = streams.get("image", {})
        self.particles = streams.get("particles", {})
        self.width = int(width) // 2 * 2
        self.height = int(round(self.width * ASPECT)) // 2 * 2  # even sizes: yuv420p
        dpi = 100
        scale = self.width / 960.0  # fonts and lines follow the frame size
        fig = Figure(figsize=(self.width / dpi, self.height / dpi), dpi=dpi)
        self.canvas = FigureCanvasAgg(fig)
        self.fig = fig
        fs = max(5.0, 9.0 * scale)
        title = fig.suptitle(video_title(episode, summary, policy), fontsize=fs * 1.15, y=0.985)
        # the strip's rows: the closure with the unitless observation series, a row per other unit of the observations
        # (the episode plots' axes, dlo_bag.analysis: a unit the episode has no value of has none), the reward
        observed = observation_axes(s)
        strips = [("closure [-]", [("closure c_G", s["closure"], {}), *observed.pop("-", [])])]
        strips += [(unit_axis_label(unit), lines) for unit, lines in observed.items()]
        strips.append(("reward [-]", [("reward", s["reward"], {})]))
        outer = fig.add_gridspec(
            2, 1, height_ratios=[3.0, STRIP_ROW * len(strips)], left=0.08, right=0.86, top=0.83, bottom=0.075, hspace=0.2
        )
        views = outer[0].subgridspec(1, 2, width_ratios=[1.0, 2.0], wspace=0.22)
        # top camera
        self.ax_cam = fig.add_subplot(views[0])
        first_image = self._image(self.steps[0]) if self.steps else np.zeros((8, 8), np.uint8)
        self.im = self.ax_cam.imshow(first_image, cmap="gray", vmin=0, vmax=255, interpolation="nearest")
        self.ax_cam.set_title("top camera (cable 255, gripper 128)", fontsize=fs)
        self.ax_cam.set_xticks([])
        self.ax_cam.set_yticks([])
        # side view: particles, fingers, fixed end, table
        self.ax_side = ax = fig.add_subplot(views[1])
        xs, zs = self._extent()
        ax.set_xlim(*xs)
        ax.set_ylim(*zs)
        ax.set_aspect("equal", adjustable="box")
        ax.xaxis.set_major_locator(MaxNLocator(nbins=6))  # x tick labels apart at any frame width
        ax.axhline(0.0, color="0.5", lw=1.0 * scale)
        ax.set_title("side view (x-z): particles, held in red, fingers", fontsize=fs)
        ax.set_xlabel("x [m]", fontsize=fs)
        ax.set_ylabel("z [m]", fontsize=fs)
        ax.tick_params(labelsize=fs * 0.85)
        (self.line,) = ax.plot([], [], "-", color="0.6", lw=1.0 * scale, zorder=1)
        self.dots = ax.scatter([], [], s=10 * scale**2, zorder=2)
        self.fingers = [Circle((0, 0), FINGER_RADIUS, color="tab:blue", alpha=0.5, zorder=3) for _ in range(2)]
        for finger in self.fingers:
            ax.add_patch(finger)
        fixed = self._fixed_end()
        ax.plot([fixed[0]], [fixed[2]], marker="s", color="k", ms=6 * scale, zorder=4, ls="none", label="fixed end")
        ax.plot([], [], "o", color="tab:red", ms=4 * scale, label="held particle")
        ax.plot([], [], "o", color="tab:blue", alpha=0.5, ms=8 * scale, label="finger (closure)")
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=fs * 0.85, frameon=False)
        # the status line just below the title, however many lines it has (a long policy label wraps)
        below = title.get_window_extent(self.canvas.get_renderer()).transformed(fig.transFigure.inverted()).y0
        self.status = fig.text(0.5, below - 0.012, "", ha="center", va="top", fontsize=fs, family="monospace")
        # strip over the episode, with a cursor
        steps = np.asarray(self.steps)
        strip_grid = outer[1].subgridspec(len(strips), 1, hspace=0.15)
        self.cursors = []
        share = None
        self.strip_axes = []
        for row, (label, lines) in enumerate(strips):
            a = fig.add_subplot(strip_grid[row], sharex=share)
            share = share or a
            for name, values, style in lines:
                a.plot(steps, values, **{"lw": 1.1 * scale, **style}, label=name)
            if row == 0 and all(np.nanmin(v) >= 0.0 and np.nanmax(v) <= 1.0 for _, v, _ in lines if np.isfinite(v).any()):
                a.set_ylim(-0.05, 1.05)  # closure and the unitless series in [0, 1]: the whole range
            a.set_ylabel(label.replace(" [", "\n["), fontsize=fs * 0.85)  # "angle\n[rad]": fits the row's height
            a.tick_params(labelsize=fs * 0.8)
            a.legend(loc="center left", bbox_to_anchor=(1.005, 0.5), fontsize=fs * 0.8, frameon=False, ncol=1)
            for mark, color in ((s.first_at_end, "tab:green"), (s.first_at_end_authors, "tab:purple")):
                if mark is not None:
                    a.axvline(mark, color=color, ls=":", lw=1.0 * scale)
            self.cursors.append(a.axvline(steps[0] if len(steps) else 0, color="k", lw=1.2 * scale))
            self.strip_axes.append(a)
            if row < len(strips) - 1:
                a.tick_params(labelbottom=False)
        if len(steps):
            share.set_xlim(steps[0], max(steps[-1], steps[0] + 1))
        self.strip_axes[-1].set_xlabel(
            "control step (0.08 s each); dotted: first at the end (green paper rule, purple authors' rule)", fontsize=fs * 0.85
        )

    def _image(self, step: int) -> np.ndarray:
        msg = self.images.get(step)
        if msg is None:
            return np.zeros((8, 8), np.uint8)
        return np.frombuffer(bytes(msg.data), np.uint8).reshape(int(msg.height), int(msg.step))[:, : int(msg.width)]

    def _extent(self):
        pts = [unpack_particles(self.particles[k])[0] for k in self.steps if k in self.particles]
        s = self.series
        xs = [p[:, 0] for p in pts] + [s["x"][~np.isnan(s["x"])]]
        zs = [p[:, 2] for p in pts] + [s["z"][~np.isnan(s["z"])] + FINGER_AXIS_OFFSET + FINGER_RADIUS]
        x = np.concatenate(xs) if xs else np.array([-0.3, 0.3])
        z = np.concatenate(zs) if zs else np.array([0.0, 0.15])
        x = x[np.isfinite(x)]
        z = z[np.isfinite(z)]
        if not len(x):
            x = np.array([-0.3, 0.3])
        if not len(z):
            z = np.array([0.0, 0.15])
        pad = 0.02
        return (float(x.min()) - pad, float(x.max()) + pad), (min(-0.005, float(z.min()) - pad), float(z.max()) + pad)

    def _fixed_end(self) -> np.ndarray:
        for k in self.steps:
            if k in self.particles:
                return unpack_particles(self.particles[k])[0][0]
        return np.asarray(FIXED_END, dtype=float)

    def frame(self, index: int) -> np.ndarray:
        """RGB frame (height, width, 3) uint8 of the ``index``-th step of the episode."""
        step = self.steps[index]
        s = self.series
        self.im.set_data(self._image(step))
        if step in self.particles:
            xyz, held = unpack_particles(self.particles[step])
            self.line.set_data(xyz[:, 0], xyz[:, 2])
            self.dots.set_offsets(np.c_[xyz[:, 0], xyz[:, 2]])
            self.dots.set_color(np.where(held[:, None], [[0.84, 0.15, 0.16]], [[0.12, 0.47, 0.71]]))
        closure = s["closure"][index]
        for finger, sign in zip(self.fingers, (1.0, -1.0), strict=True):
            finger.center = (s["x"][index], s["z"][index] + sign * FINGER_AXIS_OFFSET)
            finger.set_alpha(0.25 + 0.65 * (0.0 if np.isnan(closure) else float(closure)))
        for cursor in self.cursors:
            cursor.set_xdata([step, step])
        n_held = s["n_held"][index]
        n_c = s["num_particles"][index]
        biggest = s["max_held_index"][index]
        at = " AT THE END" if s["at_end"][index] else ""
        self.status.set_text(
            f"step {step:3d}  t = {step * CONTROL_PERIOD:5.2f} s  closure {closure:4.2f}  held "
            f"{0 if np.isnan(n_held) else int(n_held):2d} (largest index {int(biggest):2d} of "
            f"{0 if np.isnan(n_c) else int(n_c) - 1}){at}"
        )
        self.canvas.draw()
        rgba = np.asarray(self.canvas.buffer_rgba())
        return np.ascontiguousarray(rgba[:, :, :3])

    def __len__(self) -> int:
        return len(self.steps)

    def close(self) -> None:
        self.fig.clear()


def _writer(path: Path, size: tuple[int, int], fps: float, fmt: str):
    import imageio_ffmpeg

    if fmt == "mp4":
        gen = imageio_ffmpeg.write_frames(
            str(path),
            size,
            fps=fps,
            codec="libx264",
            pix_fmt_out="yuv420p",
            quality=7,
            macro_block_size=2,
            ffmpeg_log_level="error",
            output_params=["-movflags", "+faststart"],
        )
    else:
        palette = (
            "split[a][b];[a]palettegen=max_colors=96:stats_mode=diff[p];"
            "[b][p]paletteuse=dither=bayer:bayer_scale=4:diff_mode=rectangle"
        )
        gen = imageio_ffmpeg.write_frames(
            str(path),
            size,
            fps=fps,
            codec="gif",
            pix_fmt_out="pal8",
            quality=None,
            macro_block_size=2,
            ffmpeg_log_level="error",
            output_params=["-vf", palette, "-loop", "0"],
        )
    gen.send(None)
    return gen


def render_episode_video(
    episode: int,
    streams: dict,
    summary: dict,
    path,
    *,
    fmt: str = "mp4",
    policy: str | None = None,
    speed: float = 1.0,
    width: int | None = None,
    progress=None,
) -> dict:
    """Write one episode's video to ``path``; returns {frames, seconds, fps, render_fps, bytes}.

    ``speed`` 1.0 = real time (12.5 frames/s); ``width`` in pixels (height = 3/4 of it); ``progress``:
    called with 1 after each frame is encoded (e.g. a tqdm bar's ``update``).
    """
    if fmt not in FORMATS:
        raise ValueError(f"video format must be one of {FORMATS}, got {fmt!r}")
    if not speed > 0:
        raise ValueError(f"video speed must be > 0, got {speed}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    frames = EpisodeFrames(episode, streams, summary, policy=policy, width=width or DEFAULT_WIDTH[fmt])
    if not len(frames):
        raise VideoError(f"episode {episode} has no recorded steps")
    fps = REALTIME_FPS * speed
    tmp = path.with_name(path.stem + ".partial" + path.suffix)
    try:
        gen = _writer(tmp, (frames.width, frames.height), fps, fmt)
        try:
            for i in range(len(frames)):
                gen.send(frames.frame(i).tobytes())
                if progress is not None:
                    progress(1)
        finally:
            gen.close()
        tmp.replace(path)
    except (OSError, RuntimeError, StopIteration) as err:
        tmp.unlink(missing_ok=True)
        raise VideoError(f"cannot write {path}: {err}") from None
    finally:
        frames.close()
    seconds = time.perf_counter() - t0
    return {
        "path": str(path),
        "frames": len(frames),
        "duration_s": round(len(frames) / fps, 2),
        "fps": fps,
        "render_s": round(seconds, 3),
        "render_fps": round(len(frames) / seconds, 2),
        "bytes": path.stat().st_size,
        "width": frames.width,
        "height": frames.height,
    }
