"""The scene a network was trained in: the grid and candidate views its shards were made with.

A checkpoint records it (``scene_record``) so that a run with other settings refuses it in one
line (``check_scene``) instead of feeding it grids of another voxel size or scoring views it
never saw. Checkpoints of imported data (the authors' shards record no settings) carry none and
are not checked.
"""

from __future__ import annotations

from nbvdata.config import ConfigError, SimConfig, from_dict

SCENE_KEYS = ("grid_size", "grid_extent", "views_count", "views_radius", "views_layout")


class SceneMismatch(ConfigError):
    """A checkpoint trained in another scene than the run's; the message names the difference."""


def scene_record(config: SimConfig) -> dict:
    """The settings a network depends on: grid size and cube side (metres, resolved), and the
    candidate views' count, radius and layout."""
    grid = config.scene_grid
    return {"grid_size": grid.size, "grid_extent": round(float(grid.extent), 9), "views_count": config.views.count,
            "views_radius": float(config.views.radius), "views_layout": config.views.layout}


def scene_record_of(settings: dict | None) -> dict | None:
    """``scene_record`` of a shard's recorded settings (a dict), or None when it records none."""
    if not settings:
        return None
    try:
        return scene_record(from_dict(SimConfig, settings))
    except ConfigError:
        return None


def check_scene(recorded: dict | None, config: SimConfig, checkpoint: object) -> None:
    """SceneMismatch when ``recorded`` (a checkpoint's scene, or None = unknown: accepted)
    differs from ``config``'s."""
    if not recorded:
        return
    current = scene_record(config)
    differ = [f"{key} {recorded.get(key)!r} (the run has {current[key]!r})" for key in SCENE_KEYS
              if recorded.get(key) != current[key]]
    if differ:
        raise SceneMismatch(f"{checkpoint}: trained with other settings than this run's: {'; '.join(differ)}: pass "
                            "a checkpoint trained on shards made with these settings, or run with the checkpoint's "
                            "(--config/--set)")
