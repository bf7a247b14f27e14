"""The two sources of O_V (``vision_source``: env option, vision node parameter, launcher option): ``image``, the
top-view image as a camera gives it (``dlo_perception.vision.visual_pose``), and ``particles``, the paper's simplified
scalars by the authors' index walk (``dlo_perception.vision.visual_pose_particles``). Pure Python: the launcher and
run-directory code check and default it without starting Taichi."""

VISION_SOURCES = ("image", "particles")
DEFAULT_VISION_SOURCE = "image"  # what a camera gives: the default, for the graph and for real robots


def check_vision_source(source) -> str:
    """``source`` if it is one of VISION_SOURCES, else ValueError with a one-line reason."""
    if source not in VISION_SOURCES:
        raise ValueError(f"vision_source: expected one of {', '.join(VISION_SOURCES)}, got {source!r}")
    return source
