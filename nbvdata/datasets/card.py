"""The dataset card of a published version: ``NAME-X.Y.Z.md`` and ``.png`` beside its manifest.

The card opens with the YAML front matter the Hugging Face Hub reads (``front_matter``: license,
tags, the splits of the folder ``nbvdata share`` writes). It says what the data is and how it was
made, how it splits, the shard schema (read from the docstring of ``nbvdata.schema.shards``, its
one description), the statistics ``nbvdata inspect`` prints (samples per mesh, coverage reached,
label spread), the meshes' licenses as recorded, and five lines of plain h5py that load a sample.
The PNG shows how the NBV labels spread over the candidate views. Both are written before the
manifest, each under a temporary name first.
"""

from __future__ import annotations

import json
import os
import re
from collections import Counter
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import yaml  # noqa: E402

from nbvdata.core.config import OracleConfig, SimConfig, from_dict  # noqa: E402
from nbvdata.core.files import write_atomic  # noqa: E402
from nbvdata.core.text import plural  # noqa: E402
from nbvdata.datasets.about import About  # noqa: E402
from nbvdata.schema import shards as shard_schema  # noqa: E402
from nbvdata.schema.shards import COVER, GENERATED, Shard  # noqa: E402
from nbvdata.schema.summary import Summary, format_summary, summarise  # noqa: E402
from nbvdata.simulation.shapes import BUILTIN_SHAPES  # noqa: E402


def write_card(content: dict, manifest_path: Path, shard_paths: list[Path], about: About) -> Path:
    """Write the card and its label-spread PNG for the manifest ``content`` about to be written
    at ``manifest_path``; returns the card's path."""
    summary = summarise(shard_paths)
    with Shard(shard_paths[0]) as first:
        views = first["view_positions"]
        present = set(first.file)
    png = manifest_path.with_suffix(".png")
    plot_label_spread(views, summary.nbv_counts, png, f"{content['name']} {content['version']}: "
                      f"NBV labels of {plural(summary.samples, 'sample', spec=',')} over "
                      f"{plural(len(views), 'candidate view')}")
    card = manifest_path.with_suffix(".md")
    write_atomic(card, front_matter(content, about) + card_text(content, summary, present, manifest_path))
    return card


HUB_SPLITS = {"train": "train", "val": "validation", "test": "test"}  # the manifest's part -> the Hub's split
SIZES = ((1_000, "n<1K"), (10_000, "1K<n<10K"), (100_000, "10K<n<100K"), (1_000_000, "100K<n<1M"),
         (10_000_000, "1M<n<10M"))


def hub_split(content: dict) -> tuple[str, dict[str, str]]:
    """The split a shared folder is laid out by - the mesh split where the version has one, else
    the random one - and {the manifest's part: the Hub's split name}."""
    kind = "random" if "unavailable" in content["splits"].get("mesh", {"unavailable": ""}) else "mesh"
    return kind, {part: HUB_SPLITS[part] for part in HUB_SPLITS if part in content["splits"][kind]}


def front_matter(content: dict, about: About) -> str:
    """The YAML front matter the Hugging Face Hub reads from a dataset card: license, name,
    tags, task and size categories, and ``configs`` whose ``data_files`` are the splits of the
    folder ``nbvdata share`` writes (``data/<split>/*.h5``, one file per shard and split, every
    dataset in it per sample: what the ``hdf5`` builder of ``datasets`` requires)."""
    _, parts = hub_split(content)
    size = next((label for bound, label in SIZES if content["totals"]["samples"] < bound), "n>10M")
    matter = {"license": "other" if about.license == "other" else about.license.lower()}
    if about.license == "other":
        matter |= {"license_name": "nbv-mesh-licenses", "license_link": "LICENSE"}
    matter |= {"pretty_name": f"{content['name']} {content['version']}", "tags": list(about.keywords),
               "task_categories": ["robotics"], "size_categories": [size],
               "configs": [{"config_name": "default",
                            "data_files": [{"split": split, "path": f"data/{split}/*.h5"} for split in parts.values()]}]}
    return "---\n" + yaml.safe_dump(matter, sort_keys=False, width=100) + "---\n\n"


def with_front_matter(card: str, matter: str) -> str:
    """``card`` with ``matter`` in place of the front matter it has, or before its text."""
    if card.startswith("---\n"):
        end = card.find("\n---\n", 4)
        if end >= 0:
            card = card[end + 5:].lstrip("\n")
    return matter + card


def plot_label_spread(views: np.ndarray, counts: Counter, out: Path, title: str) -> None:
    """Left: every candidate view by azimuth and elevation, coloured and sized by how many samples
    it labels. Right: the share of samples labelled by the k most frequent views, against uniform.

    views : (V, 3) float positions; counts : view index -> samples whose NBV it is
    """
    unit = np.asarray(views, dtype=np.float64)
    unit = unit / np.linalg.norm(unit, axis=1, keepdims=True)
    azimuth = np.degrees(np.arctan2(unit[:, 1], unit[:, 0]))
    elevation = np.degrees(np.arcsin(np.clip(unit[:, 2], -1, 1)))
    count = np.zeros(len(unit))
    for view, samples in counts.items():
        count[view] = samples
    used = count > 0

    fig, (sky, ranked) = plt.subplots(1, 2, figsize=(12, 4.4), gridspec_kw={"width_ratios": [1.7, 1]})
    sky.scatter(azimuth[~used], elevation[~used], s=5, c="0.8", label="never the NBV")
    points = sky.scatter(azimuth[used], elevation[used], s=10 + 70 * count[used] / max(count.max(), 1),
                         c=count[used], cmap="viridis")
    fig.colorbar(points, ax=sky, label="samples with this NBV")
    sky.set_xlim(-180, 180)
    sky.set_xlabel("azimuth (deg)")
    sky.set_ylabel("elevation (deg)")
    sky.legend(loc="lower left", fontsize=8)
    share = np.cumsum(np.sort(count)[::-1]) / max(count.sum(), 1)
    ranks = np.arange(1, len(count) + 1)
    ranked.plot(ranks, share, label="labels")
    ranked.plot(ranks, ranks / len(count), linestyle="--", color="0.5", label="uniform over the views")
    ranked.set_xlabel("candidate views, most frequent NBV first")
    ranked.set_ylabel("share of samples (cumulative)")
    ranked.legend(loc="lower right", fontsize=8)
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    partial = out.with_name(out.name + ".partial")
    fig.savefig(partial, dpi=90, format="png")
    plt.close(fig)
    os.replace(partial, out)


def card_text(content: dict, summary: Summary, present: set[str], manifest_path: Path) -> str:
    """The card as Markdown; ``present``: the datasets the shards hold."""
    name, version, totals = content["name"], content["version"], content["totals"]
    manifest = f"{manifest_path.parent.name}/{manifest_path.name}"
    lines = [f"# {name} {version}", ""]
    if content["notes"]:
        lines += [f"> {content['notes']}", ""]
    lines += [_what(content, summary.view_count), "",
              f"- Manifest `{manifest_path.name}`: every shard with its path, sha256, size and sample "
              "count; the meshes; the settings; the splits. Published versions never change.",
              f"- Check a copy: `nbvdata verify {manifest} [--root SHARDS_DIR]`",
              f"- Train on it: `nbvtrain fit {manifest}"
              f"{'' if 'unavailable' in content['splits']['mesh'] else ' [--split mesh]'}`", "",
              "## How it was made", "", *_made(content, summary.policies), "",
              f"## Splits (seed {content['splits']['seed']})", "", *_splits(content["splits"]), "",
              f"## Schema (version {content['schema_version']})", "",
              "The samples of the shards, N per shard, V candidate views, n = grid size "
              "(the description in `nbvdata/schema/shards.py`):", "",
              "| dataset | shape | dtype | content |", "|---|---|---|---|"]
    for dataset, shape, dtype, meaning in schema_rows():
        if dataset in COVER and dataset not in present:
            continue  # set-cover labels: listed only in versions that hold them (oracle.cover)
        absent = "" if dataset in present else " *(absent in this version)*"
        lines.append(f"| `{dataset}` | {shape} | {dtype} | {meaning.replace('|', '/')}{absent} |")
    lines += ["", "## Statistics", "", *_coverage(summary), "", "As `nbvdata inspect` prints them:", "",
              "```text", format_summary(summary), "```", "",
              f"![How the NBV labels spread over the candidate views]({manifest_path.with_suffix('.png').name})",
              "", "## Meshes and licenses", "", "Licenses as recorded when the version was published.", "",
              "| mesh | sha256 | runs | samples | license |", "|---|---|---|---|---|"]
    for mesh in content["meshes"]:
        digest = f"`{mesh['sha256'][:12]}`" if mesh["sha256"] else "-"
        lines.append(f"| {mesh['source']} | {digest} | {mesh['runs']} | {mesh['samples']} | {mesh['license']} |")
    lines += ["", "## Loading a sample with h5py", "",
              "From the folder that holds `manifests/`, with nothing but h5py:", "",
              "```python", *_snippet(manifest), "```", "",
              f"`grid` is sample 0's {content['config'].get('grid', {}).get('size', 32)}^3 occupancy "
              "probabilities (float32, 0.5 = unknown), `nbv` the unit vector from the object's centre to "
              f"its next-best-view. The version's {plural(totals['samples'], 'sample', spec=',')} are the shards' "
              "rows in manifest order; the split ranges index them in that order."]
    return "\n".join(lines) + "\n"


def schema_rows() -> list[list[str]]:
    """[dataset, shape, dtype, content] rows, read from the ``Datasets::`` block of the docstring
    of ``nbvdata.schema.shards``."""
    block = shard_schema.__doc__.split("Datasets::", 1)[1].splitlines()
    rows: list[list[str]] = []
    for line in block[1:]:
        if not line.strip():
            if rows:
                break
            continue
        match = re.fullmatch(r" {4}(\w+)\s+(\([^)]*\))\s+(\S+)\s+(.*)", line)
        if match:
            rows.append(list(match.groups()))
        else:
            rows[-1][3] += " " + line.strip()
    return rows


def _what(content: dict, view_count: int) -> str:
    totals, megabytes = content["totals"], content["totals"]["bytes"] / 2 ** 20
    files = f"{plural(totals['shards'], 'HDF5 shard')} ({megabytes:.1f} MB)"
    if content["source"] != GENERATED:
        return (f"Reconstruction states imported by `nbvdata import-legacy` from {content['source']}: "
                f"{plural(totals['samples'], 'sample', spec=',')} ({plural(totals['runs'], 'run', spec=',')}, "
                f"derived from the row order) in {files}, each an occupancy grid labelled with its next-best-view, "
                f"one of {plural(view_count, 'view')}.")
    return (f"Reconstruction states of {plural(totals['meshes'], 'object')}, each labelled with its ground-truth "
            f"next-best-view (NBV): {plural(totals['samples'], 'sample', spec=',')} from "
            f"{plural(totals['runs'], 'simulated reconstruction', spec=',')}, in {files}. A sample is the "
            "probabilistic occupancy grid of a partly scanned object and the one of "
            f"{plural(view_count, 'candidate view')} that an exhaustive search finds best: the view that adds the "
            "most surface while overlapping enough of what is already seen.")


def _made(content: dict, policies: set[str] = frozenset()) -> list[str]:
    config = content["config"]
    commit = content["git_commit"]
    at = f" at commit `{commit[:12]}`{' with uncommitted changes' if content['git_dirty'] else ''}" if commit else ""
    published = f"- Published on {content['created']} by nbvdata {content['package_version']}{at}."
    if content["source"] != GENERATED:
        return [f"- {config.get('note', content['source'])}", published]
    views, sensor = config["views"], config["sensor"]
    episode, oracle = config["episode"], config["oracle"]
    layout = LAYOUT_WORDS.get(views["layout"], f"the {views['layout']}")
    lines = [f"- Simulated by `nbvdata generate`: {plural(views['count'], 'candidate view')} on "
             f"{layout} of radius {views['radius']} m; a {sensor['width']}x{sensor['height']} range "
             f"sensor (noise {sensor['noise_std']} m); {_grid_words(config)} "
             f"with OctoMap's update rule; {plural(episode['runs_per_mesh'], 'run')} per mesh from seeded random "
             f"start views, at most {plural(episode['max_scans'], 'scan')}, stopping when no view adds "
             f"{100 * episode['min_gain']:g} % of the observable surface; every state labelled by exhaustive "
             f"search over the views that overlap at least {100 * oracle['min_overlap']:g} % of what is already "
             f"covered; global seed {episode['seed']}.",
             *_moves(episode, oracle, policies), *_clouds(config),
             *([f"- Set-cover labels (`oracle.cover`, docs/setcover.md): every state also holds the fewest candidate "
                f"views whose scans cover all the observable surface it has not covered (`cover`, SCVP's label), solved "
                f"by HiGHS within {_cover_limit(oracle)} per state; `cover_bound` == `cover_size` marks the labels "
                "proved optimal."]
               if oracle.get("cover") else []),
             "- Every setting is in the manifest's `config` and in each shard's `config` attribute."]
    command = _reproduce(content, policies)
    lines.append(f"- Reproduce the shards: `{command}`; `nbvdata verify` with `--root` then tells whether your "
                 "bytes are the published ones (everything is seeded, independent of the number of workers and "
                 "of the CPU's instruction set), and `--content` whether the arrays are, when other library "
                 "versions wrote the files differently."
                 + (" A policy's moves come from its network's floating-point arithmetic, which other torch "
                    "builds or CPUs may round differently: there, expect other runs." if policies else "")
                 if command else
                 "- Made with the `nbvdata.datasets.generate` API from the meshes listed below and these settings.")
    return lines + [published]


def _grid_words(config: dict) -> str:
    """"a 32^3 occupancy grid of 0.32 m" (a fixed cube), or the cube fitted to the object with its
    side (``SimConfig.scene_grid``): every mesh is scaled to the same largest side, so one size."""
    grid = config["grid"]
    if grid["extent"] is not None:
        return f"a {grid['size']}^3 occupancy grid of {grid['extent']} m"
    side = from_dict(SimConfig, config).scene_grid.extent
    return (f"a {grid['size']}^3 occupancy grid fitted to the object (cube = largest side + half a voxel: "
            f"{side:.4g} m, the same for every object, each scaled to a largest side of "
            f"{config['mesh']['object_size']} m)")


# How the card names a views.layout (any other: "the <layout>").
LAYOUT_WORDS = {"pc-nbv-33": "PC-NBV's 33-view layout (`pc-nbv-33`, their y-up directions turned to z-up)",
                "scvp-32": "SCVP's 32-view layout (`scvp-32`, their directions)"}


def _cover_limit(oracle: dict) -> str:
    """How a card's set-cover labels were bounded: the node count, or (datasets made before it) seconds."""
    if "cover_time_limit" in oracle:
        return f"{oracle['cover_time_limit']:g} s of wall time (labels not proved optimal depend on the machine)"
    return f"{oracle.get('cover_node_limit', OracleConfig.cover_node_limit):,} branch-and-bound nodes (the same labels on every machine)"


def _clouds(config: dict) -> list[str]:
    """The states' point clouds, when the shards hold them (nothing otherwise)."""
    points = config.get("state", {}).get("points", 0)
    if not points:
        return []
    return [f"- Point clouds (`state.points` {points}): every state holds the points its run had scanned "
            f"(`points`, object frame), reduced to {points} by farthest-point sampling from the first point "
            "(fewer: repeated), how many there were (`points_count`), and each shard the mesh's reference "
            "points (`reference_points`); `nbvdata export --format pc-nbv` writes them in PC-NBV's layout."]


def _moves(episode: dict, oracle: dict, policies: set[str]) -> list[str]:
    """How the runs left the oracle's path (exploration, a policy), or nothing when they did not."""
    lines = []
    explore, mix = episode.get("explore", 0.0), episode.get("oracle_mix", 0.0)
    if explore:
        lines.append(f"- Exploration: at each move, with probability {explore:g} the run moved to a uniformly random "
                     f"view overlapping at least {100 * oracle['min_overlap']:g} % of what was covered instead of "
                     "the NBV (`episode.explore`); every state is still labelled exactly, and the shards record "
                     "each move (`move`, `next_view`, `next_pose`).")
    for text in sorted(policies):
        policy = json.loads(text)
        mixed = f", mixed with the oracle's moves with probability {mix:g} (`episode.oracle_mix`)" if mix else ""
        lines.append(f"- A learned-policy rollout (a DAgger round): the runs moved where the trained planner "
                     f"{policy.get('network') or 'of the checkpoint'} (sha256 `{policy['sha256']}`) chose{mixed}, its "
                     "continuous poses scanned as they are; every state is labelled exactly.")
    return lines


def _reproduce(content: dict, policies: set[str] = frozenset()) -> str | None:
    """The ``nbvdata generate`` command that makes these shards again, or None if the CLI cannot."""
    sources = {mesh["source"] for mesh in content["meshes"]}
    builtin = {f"builtin:{name}" for name in BUILTIN_SHAPES}
    if sources == builtin:
        meshes = ""
    elif not sources & builtin:
        meshes = " --meshes MESH_DIR"  # the folder holding the files listed under Meshes
    else:
        return None
    defaults = SimConfig().dataset_dict()
    changed = [f" --set {section}.{key}={value if isinstance(value, str) else json.dumps(value, allow_nan=False)}"
               for section, values in content["config"].items() for key, value in values.items()
               if defaults.get(section, {}).get(key) != value]
    per_shard = max(stop - start for start, stop in (shard["runs"] for shard in content["shards"]))
    if per_shard < content["config"]["episode"]["runs_per_mesh"]:  # the shard files' names depend on it
        changed.append(f" --set generate.runs_per_shard={per_shard}")
    policy = " --policy CHECKPOINT" if policies else ""  # the checkpoint of the sha256 above
    return f"nbvdata generate{meshes} --out {Path(content['root']).name}{policy}{''.join(changed)}"


def _splits(splits: dict) -> list[str]:
    lines = ["Stored in the manifest as mesh ids and [start, stop) ranges of sample indices.", "",
             "| split | part | meshes | samples |", "|---|---|---|---|"]
    for kind in ("random", "mesh"):
        split = splits[kind]
        if "unavailable" in split:
            lines.append(f"| {kind} | - | unavailable: {split['unavailable']} | - |")
            continue
        for part in ("train", "val", "test"):
            if part in split:
                meshes = len(split[part]["meshes"]) if "meshes" in split[part] else "all"
                lines.append(f"| {kind} | {part} | {meshes} | {split[part]['samples']:,} |")
    return lines + ["", "`random` is the paper's per-sample split (train/val; the paper tests in closed loop "
                    "on other objects). `mesh` holds whole objects out: `nbvtrain fit --split mesh` trains on "
                    "train, validates on val, and never sees test."]


def _coverage(summary: Summary) -> list[str]:
    final = [value for entry in summary.meshes.values() for value in entry.final_coverage]
    if not final:
        return ["Coverage was not recorded in these shards."]
    final = 100 * np.array(final)
    return [f"Observable surface covered at the end of a run: mean {final.mean():.1f} %, median "
            f"{np.median(final):.1f} %, range {final.min():.1f}-{final.max():.1f} % over {plural(len(final), 'run')}."]


def _snippet(manifest: str) -> list[str]:
    """Five lines of plain h5py that load sample 0 of the version."""
    return ["import h5py, json, pathlib",
            f'manifest = pathlib.Path("{manifest}")',
            "m = json.loads(manifest.read_text())",
            'with h5py.File(manifest.parent / m["root"] / m["shards"][0]["path"]) as f:',
            '    grid, nbv = f["grid_palette"][()][f["grids"][0]], f["nbv_position"][0]']
