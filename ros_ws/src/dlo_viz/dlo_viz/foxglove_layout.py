"""The Foxglove layout of the dlo-vitac graph (docs/foxglove/dlo_vitac.json), generated here.

    python -m dlo_viz.foxglove_layout [--out docs/foxglove/dlo_vitac.json] [--check]

The file is a layout as the Foxglove app exports it (``configById`` + a ``layout`` tree of
splits; import it with Layouts -> Import from file). The panel configurations are built with
foxglove-sdk's typed layout classes (``foxglove.layouts``), so the keys are the app's own. It
works on a live connection (``dlo_viz foxglove_bridge``) and on a recorded bag opened in
Foxglove alike: every panel reads topics both carry, timed by receive time (the recorder's log
time in a bag).

Panels: 3D (fixed frame ``world``: the particle cloud coloured by its ``held`` field, the cable
line and the two fingers from ``/dlo/markers``), the top camera image (with its camera_info),
and plots over time: closure (measured, commanded, and the unitless observation series: vision
confidence), one panel per other unit of the observation series (the distilled angles [rad] and
offsets [m] of touch and vision, gripper frame), reward, the held particle index, and the outcome of
both rules (a state-transitions panel: 0 none, 1 hold_the_end, 2 stop_before, 3 reach_end_but_drop,
4 drop_before). The observation series are the ``plot`` series of the registry's observation topics
(``dlo_common.topics``, paths ``<topic>.<field>``, SI as the messages carry them), labelled as the
episode plots label them (``dlo_bag.analysis.series_label``): a modality added there gets its plots
here with no change (a new unit a panel of its own).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path
from typing import Any

from dlo_bag.analysis import series_label
from dlo_common.topics import plot_series_by_unit, topic

LAYOUT_FILE = Path("docs") / "foxglove" / "dlo_vitac.json"
TIMESTAMP = "receiveTime"  # live: when the bridge received it; bag: the recorder's receive time

COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd")

# The panel of a unit of the observation series, (id suffix, title); any other unit: ("observations_<unit>",
# "observations [<unit>]"). The unitless series ("-") join the closure's panel.
UNIT_PANELS = {"rad": ("angles", "pose angles [rad] (gripper frame)"), "m": ("offsets", "pose offsets [m] (gripper frame)")}


def _topic(key: str) -> str:
    """A topic's name from the registry (dlo_common.topics) by its key: a panel reads only topics of the graph."""
    return topic(key).name


def _field(key: str, field: str) -> str:
    """A message path for a plot, ``/dlo/gripper/state.closure``."""
    return f"{_topic(key)}.{field}"


def _plain(model: Any) -> Any:
    """A foxglove.layouts model as plain JSON data (None fields dropped, as the SDK writes it)."""
    return json.loads(model.to_json())


def _series(path: str, label: str, i: int, **extra) -> Any:
    import foxglove.layouts as fl

    return fl.PlotSeries(
        value=path, label=label, enabled=True, timestamp_method=TIMESTAMP, color=COLORS[i % len(COLORS)], **extra
    )


def _plot(title: str, series: list, **config) -> dict:
    import foxglove.layouts as fl

    cfg = _plain(fl.PlotConfig(paths=series, **config))
    cfg["title"] = title
    return cfg


def observation_series() -> dict[str, list]:
    """{unit: [(path, label)]} of the plot series of the registry's observation topics (``dlo_common.topics``),
    units and series in registry order."""
    return {
        unit: [(f"{t.name}.{series.field}", series_label(t, series)) for t, series in pairs]
        for unit, pairs in plot_series_by_unit("observation").items()
    }


def unit_id(unit: str) -> str:
    """A unit as a panel id's part, one to one: letters and digits kept, any other character as _ and its code in hex
    ("N m" -> "N_20m", "N.m" -> "N_2em"), so two units never share a panel."""
    return re.sub(r"[^A-Za-z0-9]", lambda m: f"_{ord(m.group()):x}", unit)


def _unit_plot(unit: str, series: list) -> tuple[str, dict]:
    """(panel id, config) of the Plot panel of one unit's observation series [(path, label)] (:data:`UNIT_PANELS`)."""
    suffix, title = UNIT_PANELS.get(unit) or ("observations_" + unit_id(unit), f"observations [{unit}]")
    return f"Plot!dlo_{suffix}", _plot(
        title, [_series(path, label, i) for i, (path, label) in enumerate(series)], y_axis_label=unit
    )


def panel_configs() -> dict[str, dict]:
    """{panel id: config} of every panel (ids as the app writes them: 'Type!suffix')."""
    import foxglove.layouts as fl

    three_d = fl.ThreeDeeConfig(
        follow_tf="world",
        fixed_frame="world",
        follow_mode="follow-none",
        camera_state=fl.ThreeDeeCameraState(
            distance=0.9,
            perspective=True,
            phi=55.0,
            theta_offset=-90.0,
            target=(0.0, 0.0, 0.05),
            target_offset=(0.0, 0.0, 0.0),
            target_orientation=(0.0, 0.0, 0.0, 1.0),
            fovy=45.0,
            near=0.01,
            far=100.0,
        ),
        scene=fl.BaseRendererSceneSettings(background_color="#202020"),
        layers={
            "grid": fl.BaseRendererGridLayerSettings(
                visible=True,
                frame_id="world",
                size=0.6,
                divisions=12,
                line_width=1.0,
                color="#ffffff40",
                position=(0.0, 0.0, 0.0),
                rotation=(0.0, 0.0, 0.0),
                layer_id="foxglove.Grid",
                order=1,
            )
        },
        topics={
            _topic("particles"): fl.BaseRendererPointCloudTopicSettings(
                visible=True,
                point_size=9.0,
                point_shape="circle",
                color_mode="colormap",
                color_field="held",
                color_map="turbo",
                min_value=0.0,
                max_value=1.0,
            ),
            _topic("markers"): fl.BaseRendererRosMarkerTopicSettings(visible=True),
        },
    )
    image = fl.ImageConfig(image_mode=fl.ImageModeConfig(image_topic=_topic("image"), calibration_topic=_topic("camera_info")))
    outcome = fl.StateTransitionsConfig(
        paths=[
            fl.StateTransitionsSeries(
                value=_field("task", "outcome"), label="outcome, paper rule", timestamp_method=TIMESTAMP, enabled=True
            ),
            fl.StateTransitionsSeries(
                value=_field("task", "outcome_authors"), label="outcome, authors' rule", timestamp_method=TIMESTAMP, enabled=True
            ),
            fl.StateTransitionsSeries(
                value=_field("task", "done"), label="episode done", timestamp_method=TIMESTAMP, enabled=True
            ),
        ]
    )
    observed = observation_series()
    unitless = observed.pop("-", [])
    configs = {
        "3D!dlo_scene": {**_plain(three_d), "title": "rope, gripper and fingers (world frame)"},
        "Image!dlo_camera": {**_plain(image), "title": "top camera"},
        "Plot!dlo_closure": _plot(
            "closure [-]",
            [
                _series(_field("gripper", "closure"), "c_G measured", 0),
                _series(_field("command", "closure"), "c_G commanded", 1, line_style="dashed"),
                *(_series(path, label, 2 + i) for i, (path, label) in enumerate(unitless)),
            ],
            min_y_value=-0.05,
            max_y_value=1.05,
            y_axis_label="closure",
        ),
        **dict(_unit_plot(unit, series) for unit, series in observed.items()),
        "Plot!dlo_reward": _plot("reward [-]", [_series(_field("task", "reward"), "reward per step", 0)], y_axis_label="reward"),
        "Plot!dlo_held": _plot(
            "held particle index (0 = fixed end)",
            [
                _series(_field("task", "mean_held_index"), "mean held (paper rule)", 0),
                _series(_field("task", "mean_held_index_authors"), "mean held (authors' rule)", 1),
                _series(_field("task", "num_particles"), "n_c particles", 2, line_style="dotted"),
            ],
            y_axis_label="particle index",
        ),
        "StateTransitions!dlo_outcome": {**_plain(outcome), "title": "outcome (both rules) and done"},
    }
    return configs


def build_layout() -> dict:
    """The layout as the Foxglove app exports it (the panels of :func:`panel_configs`, in its order)."""

    def column(*ids: str) -> Any:  # equal heights
        if len(ids) == 1:
            return ids[0]
        return {"direction": "column", "first": ids[0], "second": column(*ids[1:]), "splitPercentage": round(100.0 / len(ids), 2)}

    configs = panel_configs()
    views = ("3D!dlo_scene", "Image!dlo_camera")
    layout_tree = {
        "direction": "row",
        "first": {"direction": "column", "first": views[0], "second": views[1], "splitPercentage": 62},
        "second": column(*(panel for panel in configs if panel not in views)),  # the plots, outcome last
        "splitPercentage": 52,
    }
    return {
        "configById": configs,
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1.0},
        "layout": layout_tree,
    }


def layout_text() -> str:
    return json.dumps(build_layout(), indent=2, ensure_ascii=False, sort_keys=False) + "\n"


def layout_topics(layout: dict | None = None) -> set[str]:
    """Every topic a panel of the layout reads."""
    layout = layout or build_layout()
    topics: set[str] = set()
    for cfg in layout["configById"].values():
        topics.update(cfg.get("topics", {}))
        mode = cfg.get("imageMode", {})
        topics.update(t for t in (mode.get("imageTopic"), mode.get("calibrationTopic")) if t)
        for series in cfg.get("paths", []):
            topics.add(series["value"].split(".", 1)[0])
    return topics


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="Write (or --check) the dlo-vitac Foxglove layout.")
    parser.add_argument("--out", type=Path, default=None, help=f"output file (default: <repo>/{LAYOUT_FILE})")
    parser.add_argument("--check", action="store_true", help="exit 1 if the file differs from the generated layout")
    args = parser.parse_args(argv)
    out = args.out or Path(__file__).resolve().parents[4] / LAYOUT_FILE
    text = layout_text()
    if args.check:
        same = out.is_file() and out.read_text(encoding="utf-8") == text
        print(f"{out}: {'up to date' if same else 'differs from the generated layout'}")
        return 0 if same else 1
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text, encoding="utf-8")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
