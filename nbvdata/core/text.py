"""Wording shared by the messages of ``nbvdata`` and ``nbvtrain``."""

from __future__ import annotations


def plural(count: int, noun: str, many: str | None = None, spec: str = "") -> str:
    """``count`` and ``noun``, the noun in the plural unless ``count`` is 1.

    plural(1, "shard") == "1 shard"; plural(3, "mesh") == "3 meshes"; ``many`` gives other plurals
    (plural(2, "batch", "batches")); ``spec`` formats the number: plural(12000, "sample", spec=",")
    == "12,000 samples".
    """
    if many is None:
        many = noun + ("es" if noun.endswith(("s", "sh", "x", "z")) else "s")
    return f"{count:{spec}} {noun if count == 1 else many}"


def some_names(names: list[str], shown: int = 3) -> str:
    """The first ``shown`` names and how many more: one line however many."""
    more = f" and {len(names) - shown} more" if len(names) > shown else ""
    return ", ".join(names[:shown]) + more
