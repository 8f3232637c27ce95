"""Count nouns in messages: "1 shard", "3 meshes"."""

import pytest

from nbvdata.core.text import plural


@pytest.mark.parametrize("count, noun, expected", [
    (0, "shard", "0 shards"), (1, "shard", "1 shard"), (2, "epoch", "2 epochs"),
    (1, "mesh", "1 mesh"), (6, "mesh", "6 meshes"), (3, "candidate view", "3 candidate views"),
    (2, "process", "2 processes"), (1, "box", "1 box"), (4, "box", "4 boxes"), (1, "epoch", "1 epoch"),
])
def test_plural(count, noun, expected):
    assert plural(count, noun) == expected


def test_plural_irregular_and_formatted():
    assert plural(2, "child", "children") == "2 children" and plural(1, "child", "children") == "1 child"
    assert plural(12000, "sample", spec=",") == "12,000 samples"
