"""A LightGBM model's trees as flat arrays, evaluated by a small compiled loop: the same scores
as ``Booster.predict(raw_score=True)``, bit for bit, in a fraction of its time on a few hundred
rows (a ranker's one decision: 500 views; LightGBM's per-call overhead dominates there).

``compile_trees(model_text)`` reads LightGBM's own text model (what a model file holds, already
checked by ``nbvtrain.ranking._lightgbm.load_booster``): per tree its internal nodes (split feature,
threshold, decision type, children) and its leaf values. ``TreeEnsemble.raw(x)`` walks them as
LightGBM's ``Tree::NumericalDecision`` does: a NaN goes to the default side where the node's
missing type is NaN and counts as 0 otherwise; a zero (|x| <= 1e-35) goes to the default side
where the missing type is Zero; else x <= threshold goes left. The trees' outputs are added in
order in float64, as LightGBM adds them. Categorical splits and linear trees are not read here
(``compile_trees`` returns None for such a model: LightGBM predicts it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

ZERO = 1e-35  # LightGBM's kZeroThreshold


@dataclass(frozen=True)
class TreeEnsemble:
    """Trees as arrays. Node arrays (all trees' internal nodes, tree by tree): ``feature``,
    ``threshold`` (float64), ``left``/``right`` (the child: >= 0 an internal node of the same
    tree, < 0 the leaf ~child), ``default_left``, ``missing`` (0 none, 1 zero, 2 NaN); per tree
    ``nodes`` (T + 1,) offsets into them, ``leaves`` (T + 1,) offsets into ``values`` (float64).
    ``features``: the columns the model reads."""

    feature: np.ndarray
    threshold: np.ndarray
    left: np.ndarray
    right: np.ndarray
    default_left: np.ndarray
    missing: np.ndarray
    nodes: np.ndarray
    leaves: np.ndarray
    values: np.ndarray
    features: int

    def raw(self, x: np.ndarray) -> np.ndarray:
        """(M,) float64 raw scores of (M, features) rows."""
        x = np.ascontiguousarray(x, dtype=np.float32)
        if x.ndim != 2 or x.shape[1] != self.features:
            raise ValueError(f"rows of shape {x.shape}; the trees read {self.features} features")
        out = np.zeros(len(x))
        _predict(x, self.feature, self.threshold, self.left, self.right, self.default_left, self.missing,
                 self.nodes, self.leaves, self.values, out)
        return out


def compile_trees(text: str) -> TreeEnsemble | None:
    """The trees of a LightGBM text model (``Booster.model_to_string()``), or None for one this
    module does not read (more than one output per round, categorical splits, linear trees)."""
    header, _, body = text.partition("\nTree=")
    fields = dict(line.split("=", 1) for line in header.splitlines() if "=" in line)
    if fields.get("num_tree_per_iteration", "1") != "1":
        return None
    features = int(fields["max_feature_idx"]) + 1
    body = "Tree=" + body.split("end of trees", 1)[0]
    columns = {name: [] for name in ("feature", "threshold", "left", "right", "default_left", "missing", "values")}
    nodes, leaves = [0], [0]
    for block in body.split("Tree=")[1:]:
        tree = dict(line.split("=", 1) for line in block.splitlines()[1:] if "=" in line)
        if tree.get("num_cat", "0") != "0" or tree.get("is_linear", "0") != "0":
            return None
        count = int(tree["num_leaves"])
        values = np.array(tree["leaf_value"].split(), dtype=np.float64)
        if count > 1:
            decision = np.array(tree["decision_type"].split(), dtype=np.int64)
            if (decision & 1).any():  # categorical
                return None
            columns["feature"].append(np.array(tree["split_feature"].split(), dtype=np.int32))
            columns["threshold"].append(np.array(tree["threshold"].split(), dtype=np.float64))
            columns["left"].append(np.array(tree["left_child"].split(), dtype=np.int32))
            columns["right"].append(np.array(tree["right_child"].split(), dtype=np.int32))
            columns["default_left"].append((decision & 2) != 0)
            columns["missing"].append(((decision >> 2) & 3).astype(np.uint8))
        columns["values"].append(values)
        nodes.append(nodes[-1] + count - 1)
        leaves.append(leaves[-1] + len(values))

    def joined(name: str, dtype) -> np.ndarray:
        return np.concatenate(columns[name]).astype(dtype) if columns[name] else np.zeros(0, dtype=dtype)

    return TreeEnsemble(joined("feature", np.int32), joined("threshold", np.float64), joined("left", np.int32),
                        joined("right", np.int32), joined("default_left", np.bool_), joined("missing", np.uint8),
                        np.array(nodes, dtype=np.int64), np.array(leaves, dtype=np.int64),
                        joined("values", np.float64), features)


@numba.njit(cache=True)
def _predict(x, feature, threshold, left, right, default_left, missing, nodes, leaves, values, out):
    """Tree by tree (a tree's nodes stay in cache over the rows), each row's total added to in tree
    order: the same sum as LightGBM's, row by row."""
    for row in range(x.shape[0]):
        out[row] = 0.0
    for tree in range(len(nodes) - 1):
        base = nodes[tree]
        if nodes[tree + 1] == base:  # a single leaf
            for row in range(x.shape[0]):
                out[row] += values[leaves[tree]]
            continue
        for row in range(x.shape[0]):
            node = 0
            while node >= 0:
                at = base + node
                value = np.float64(x[row, feature[at]])
                kind = missing[at]
                if np.isnan(value) and kind != 2:
                    value = 0.0
                if (kind == 1 and -ZERO <= value <= ZERO) or (kind == 2 and np.isnan(value)):
                    node = left[at] if default_left[at] else right[at]
                elif value <= threshold[at]:
                    node = left[at]
                else:
                    node = right[at]
            out[row] += values[leaves[tree] + ~node]
