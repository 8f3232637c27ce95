"""The scene a network was trained in: the grid and candidate views its shards were made with.

A checkpoint records it (``scene_record``) so that a run with other settings refuses it in one
line (``check_scene``) instead of feeding it grids of another voxel size or scoring views it
never saw. Checkpoints of imported data (the authors' shards record no settings) carry none and
are not checked.

Training data is one scene: shards whose recorded settings differ anywhere but ``episode`` (how
many runs, how they move: rounds of one scene may differ there) and ``state`` (what a shard keeps
besides the grids: clouds or none; a cloud network refuses shards without them on its own) are
refused together
(``scene_difference``), unless mixing them is asked for (``nbvtrain fit --mixed-scenes``). A
network trained on mixed scenes records ``mixed_scene_record``: ``mixed`` true and, for each
key, the list of values its shards had; ``check_scene`` then accepts a run whose value is any
of them.
"""

from __future__ import annotations

from nbvdata.core.config import ConfigError, SimConfig, from_dict, to_dict

__all__ = ["SceneMismatch", "scene_record", "scene_record_of", "mixed_scene_record", "scene_settings",
           "scene_difference", "check_scene"]

SCENE_KEYS = ("grid_size", "grid_extent", "views_count", "views_radius", "views_layout")
NOT_SCENE = ("episode", "state")  # sections of a shard's settings that shards of one scene may differ in


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


def mixed_scene_record(records: list[dict | None]) -> dict:
    """The scene of a network trained on shards of several scenes: ``mixed`` and, per key of
    ``scene_record``, the sorted distinct values of the shards that record one (None: unknown)."""
    known = [record for record in records if record]
    return {"mixed": True, **({key: sorted({record[key] for record in known}) for key in SCENE_KEYS} if known else {})}


def scene_settings(settings: dict | None) -> dict[str, object]:
    """A shard's recorded settings (its ``config``) as {"section.key": value}, all but the
    ``NOT_SCENE`` sections; defaults filled in where they are a ``SimConfig``'s (so a setting
    added later compares equal to its default), as recorded otherwise (imported data)."""
    if not isinstance(settings, dict):
        return {}
    try:
        settings = to_dict(from_dict(SimConfig, settings))
    except ConfigError:
        pass
    flat = {}
    for section, values in settings.items():
        if section in NOT_SCENE:
            continue
        if isinstance(values, dict):
            flat.update((f"{section}.{key}", value) for key, value in values.items())
        else:
            flat[section] = values
    return flat


def scene_difference(settings: dict | None, other: dict | None) -> tuple[str, object, object] | None:
    """(key, value, other value) of the first setting in which two shards' recorded settings
    (``scene_settings``; a key one lacks: None) make other scenes, or None when they are one."""
    first, second = scene_settings(settings), scene_settings(other)
    for key in [*first, *(key for key in second if key not in first)]:
        if first.get(key) != second.get(key):
            return key, first.get(key), second.get(key)
    return None


def check_scene(recorded: dict | None, config: SimConfig, checkpoint: object) -> None:
    """SceneMismatch when ``recorded`` (a checkpoint's scene, or None = unknown: accepted)
    differs from ``config``'s; a mixed scene (``mixed_scene_record``) accepts any of its values."""
    if not recorded:
        return
    current = scene_record(config)
    if recorded.get("mixed"):
        differ = [f"{key} {' or '.join(map(repr, recorded[key]))} in its mixed scenes (the run has {current[key]!r})"
                  for key in SCENE_KEYS if key in recorded and current[key] not in recorded[key]]
    else:
        differ = [f"{key} {recorded.get(key)!r} (the run has {current[key]!r})" for key in SCENE_KEYS
                  if recorded.get(key) != current[key]]
    if differ:
        raise SceneMismatch(f"{checkpoint}: trained with other settings than this run's: {'; '.join(differ)}: pass "
                            "a checkpoint trained on shards made with these settings, or run with the checkpoint's "
                            "(--config/--set)")
