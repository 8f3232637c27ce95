"""The by-step grid statistics that compare a dataset with the authors' grids."""

import numpy as np

from nbvdata.cli import main
from nbvdata.datasets.gridstats import ALL, CORNER, by_step, grid_statistics


def test_statistics_of_a_hand_made_grid():
    n = 32
    palette = np.array([0.5, 0.4, 0.7, 0.971], dtype=np.float32)  # unknown, free, occupied, occupied
    codes = np.ones((2, n, n, n), dtype=np.uint8)  # all free
    codes[0, 0:CORNER, 0:CORNER, 0:CORNER] = 0  # one corner block unknown: 125 voxels
    codes[0, 10, 10, 10] = 0  # one more unknown voxel, not in a corner
    codes[0, 3, 7, 9] = 2
    codes[0, 20, 7, 30] = 3  # occupied span: x 3..20, y 7..7, z 9..30
    stats = grid_statistics(codes, palette)
    assert stats["occupied"].tolist() == [2, 0]
    assert stats["unknown"].tolist() == [126, 0]
    assert stats["corner_unknown"].tolist() == [125 / (8 * 125), 0.0]
    assert stats["span"].tolist() == [[18, 1, 22], [0, 0, 0]]


def test_by_step_groups_states_and_adds_a_row_over_all(tmp_path, capsys):
    out = tmp_path / "data"
    assert main(["generate", "--out", str(out), "--config", "configs/smoke.yaml", "--workers", "1",
                 "--no-progress"]) == 0
    rows = by_step(sorted(out.glob("*.h5")))
    assert rows[-1].step == ALL and rows[-1].samples == sum(r.samples for r in rows[:-1])
    assert [r.step for r in rows[:-1]] == sorted({r.step for r in rows[:-1]}) and rows[0].step == 1
    assert rows[0].unknown > rows[1].unknown  # a second scan carves more of the cube
    assert main(["inspect", str(out), "--by-step"]) == 0
    text = capsys.readouterr().out
    assert "| 1 | " in text and "1,251 / 10,283 / 0.12" in text and "| all | " in text
