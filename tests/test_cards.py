"""Dataset cards describe the grid as it was made: a fitted cube by its rule and resolved side
(never "of None m"), and every committed card's settings line is what nbvdata.datasets.card writes from
its manifest today."""

import json
import re
from pathlib import Path

import pytest

from nbvdata.core.config import SimConfig, load_config
from nbvdata.datasets.card import _grid_words, _made

ROOT = Path(__file__).resolve().parents[1]
MANIFESTS = sorted(path for path in (ROOT / "manifests").glob("*.json")
                   if re.fullmatch(r".+-\d+\.\d+\.\d+\.json", path.name))  # not the Croissant and Zenodo files


@pytest.mark.parametrize("object_size, side", [(0.136, "0.1382"), (0.24, "0.2438")])
def test_a_fitted_cube_is_described_by_its_rule_and_side(object_size, side):
    config = load_config(SimConfig, None, [f"mesh.object_size={object_size}"])
    assert f"{config.scene_grid.extent:.4g}" == side  # object_size * 32 / 31.5: largest side + half a voxel
    assert _grid_words(config.dataset_dict()) == (
        f"a 32^3 occupancy grid fitted to the object (cube = largest side + half a voxel: {side} m, the same for "
        f"every object, each scaled to a largest side of {object_size} m)")


def test_a_fixed_cube_is_described_by_its_side():
    config = load_config(SimConfig, None, ["grid.extent=0.32"])
    assert _grid_words(config.dataset_dict()) == "a 32^3 occupancy grid of 0.32 m"


@pytest.mark.parametrize("manifest", MANIFESTS, ids=[path.stem for path in MANIFESTS])
def test_each_committed_card_says_what_its_manifest_records(manifest):
    content = json.loads(manifest.read_text())
    (simulated,) = [line for line in manifest.with_suffix(".md").read_text().splitlines()
                    if line.startswith("- Simulated by")]
    assert simulated == _made(content)[0] and "None" not in simulated
