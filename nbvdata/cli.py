"""The ``nbvdata`` command line: its commands' options, and the dispatch to their handlers
(``nbvdata.commands``).

Each subcommand is a plain function of parsed arguments returning an exit status; expected
user errors (a bad config key, a broken mesh, a missing file) print one line naming the fix
and exit with status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from nbvdata import __version__
from nbvdata.commandline import (Parser, exit_quietly_when_stdout_closes, fraction, non_negative_int, positive_int,
                                 run_command)
from nbvdata.commands import (cmd_demo, cmd_export, cmd_generate, cmd_import_legacy, cmd_inspect, cmd_publish,
                              cmd_share, cmd_show, cmd_verify)
from nbvdata.simulation.shapes import BUILTIN_SHAPES

DESCRIPTION = """\
nbvdata makes datasets for learned next-best-view (NBV) planning: a simulated range sensor
scans a mesh from candidate views on a sphere, each partial reconstruction (an occupancy grid,
32^3 by default) is labelled with the view an exhaustive search finds best, and the labelled
states are written to HDF5 shards.

The usual workflow: generate -> inspect -> publish -> verify, then `nbvtrain fit` trains on the
published version."""

EPILOG = """\
example (the 6 built-in shapes, 20 runs each, into 6 shards):
  nbvdata generate --out nbv_dataset
  nbvdata inspect nbv_dataset
  nbvdata publish nbv_dataset --name my-shapes --version 1.0.0 --license CC-BY-4.0 \\
      --creator "Lovelace, Ada" --url https://huggingface.co/datasets/ada/my-shapes
  nbvdata verify manifests/my-shapes-1.0.0.json
  nbvdata share manifests/my-shapes-1.0.0.json --out share/my-shapes   # for the Hub, Zenodo
  nbvtrain fit manifests/my-shapes-1.0.0.json --split mesh --epochs 2

Your meshes: nbvdata generate --meshes DIR (obj, ply, off, stl, glb, gltf; searched recursively).
'nbvdata COMMAND --help' lists a command's options."""


def _add_config_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", type=Path, help="YAML file with settings (see configs/default.yaml)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="override one setting, e.g. --set views.count=1000 (repeatable)")


def _add_object_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--mesh", type=Path, help="mesh file (obj, ply, off, stl, glb, gltf)")
    parser.add_argument("--shape", default="mug", choices=sorted(BUILTIN_SHAPES),
                        help="built-in shape used when no --mesh is given (default: mug)")


def build_parser() -> Parser:
    parser = Parser(prog="nbvdata", description=DESCRIPTION, epilog=EPILOG,
                    formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"nbvdata {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    sub = parser.add_subparsers(dest="command", required=True, title="commands", metavar="COMMAND")
    _add_generate(sub)
    _add_inspect(sub)
    _add_publish(sub)
    _add_verify(sub)
    _add_export(sub)
    _add_share(sub)
    _add_show(sub)
    _add_demo(sub)
    _add_import_legacy(sub)
    return parser


def _add_generate(sub) -> None:
    """``generate``: its options."""
    gen = sub.add_parser("generate", help="simulate labelled reconstructions of meshes into HDF5 shards")
    gen.add_argument("--meshes", type=Path, help="folder of mesh files (searched recursively), one mesh "
                     "file, or a .txt list of files; with --manifest, the folder its meshes lie in or below; default: "
                     "the built-in shapes")
    gen.add_argument("--manifest", type=Path, help="a published version (manifests/NAME-X.Y.Z.json): generate from "
                     "exactly the meshes of --part of its mesh split, found under --meshes by name and sha256 (a "
                     "DAgger round on its training meshes: --part train)")
    gen.add_argument("--part", help="with --manifest: train, val or test")
    gen.add_argument("--out", type=Path, default=Path("nbv_dataset"), help="output folder (default nbv_dataset)")
    _add_config_options(gen)
    gen.add_argument("--workers", type=non_negative_int, help="parallel workers, 0 = one per core (generate.workers)")
    gen.add_argument("--runs-per-mesh", type=positive_int, help="runs per mesh (episode.runs_per_mesh)")
    gen.add_argument("--seed", type=non_negative_int, help="global seed (episode.seed)")
    gen.add_argument("--explore", type=fraction, metavar="EPSILON", help="probability that a move goes to a random "
                     "valid view instead of the NBV; every state is still labelled exactly (episode.explore, "
                     "default 0)")
    gen.add_argument("--policy", type=Path, metavar="CHECKPOINT", help="runs move where this trained planner "
                     "(nbvtrain fit's best.pt) would, every state labelled exactly: a DAgger round; needs torch")
    gen.add_argument("--policy-provider", metavar="NAME", help="with --policy: what makes a policy of that file, "
                     "a name registered in the nbvdata.policies entry-point group by an installed package "
                     "(default checkpoint: nbvtrain's trained networks)")
    gen.add_argument("--oracle-mix", type=fraction, metavar="BETA", help="with --policy: probability that a move "
                     "follows the oracle instead (episode.oracle_mix, default 0)")
    gen.add_argument("--backend", choices=["loky", "threading", "dask"],
                     help="joblib backend (generate.backend)")
    gen.add_argument("--scheduler", help="Dask scheduler address for --backend dask (generate.scheduler)")
    gen.add_argument("--rerun-runs", type=positive_int, metavar="K", help="also write Rerun recordings of the "
                     "first K runs of each mesh, one per shard in OUT/rerun/ (open one with: rerun FILE.rrd; needs "
                     "the viz extra; the shards stay the same bytes; docs/rerun.md)")
    gen.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                     help="show a progress bar (default: on a terminal)")
    gen.set_defaults(func=cmd_generate)

def _add_inspect(sub) -> None:
    """``inspect``: its options."""
    inspect = sub.add_parser("inspect", help="summarise shards: samples per mesh, coverage, label spread (reads "
                             "the labels, not the grids: nbvdata verify reads every shard whole)")
    inspect.add_argument("shards", type=Path, nargs="+", help="shard files or folders of shards")
    inspect.add_argument("--top", type=non_negative_int, default=10, help="most frequent NBVs to list")
    inspect.add_argument("--by-step", action="store_true",
                         help="also the grids' occupied, unknown and corner-unknown voxels and the occupied span "
                         "per reconstruction step, beside the authors' published grids (reads every grid)")
    inspect.set_defaults(func=cmd_inspect)

def _add_publish(sub) -> None:
    """``publish``: its options."""
    pub = sub.add_parser("publish", help="write a manifest, dataset card, Croissant, sample index and citation "
                         "files for a folder of shards: a dataset version others can cite, check and train on")
    pub.add_argument("shards_dir", type=Path, help="folder of shards (searched recursively), e.g. nbv_dataset; or a "
                     "published version's manifest (manifests/NAME-X.Y.Z.json): write its card's front matter, "
                     "Croissant, index and citation files from its shards (--root), the manifest unchanged")
    pub.add_argument("--name", help="dataset name, e.g. builtin-shapes (with a folder of shards: required)")
    pub.add_argument("--version", help="X.Y.Z: new shard schema = major, new meshes or runs = "
                     "minor, metadata only = patch (with a folder of shards: required)")
    pub.add_argument("--license", help="SPDX identifier of the data's license, e.g. CC-BY-4.0 (or license: in "
                     "--about; required)")
    pub.add_argument("--creator", action="append", metavar="NAME", help="a creator, \"Family, Given\" for a person "
                     "or an organisation's name; repeat for several (or creators: in --about; required)")
    pub.add_argument("--url", help="where the version is shared, e.g. its Hugging Face Hub repository (or url: in "
                     "--about; required)")
    pub.add_argument("--about", type=Path, metavar="FILE", help="YAML of license, license_text, creators, url, "
                     "keywords (docs/publishing.md); the flags override it")
    pub.add_argument("--root", type=Path, help="with a manifest: the folder holding its shards (default: the one it "
                     "records); shards of another version of the same states serve where the manifest's content "
                     "digests show the index's arrays equal")
    pub.add_argument("--notes", default="", help="release notes")
    pub.add_argument("--manifests", type=Path, default=Path("manifests"),
                     help="folder of manifests and cards (default manifests)")
    pub.add_argument("--meshes", type=Path, help="folder the mesh files came from: every MESHES.tsv in it "
                     "(columns file, license_or_origin) gives their licenses")
    pub.add_argument("--seed", type=non_negative_int, default=0, help="seed of both splits (default 0)")
    pub.add_argument("--val-fraction", type=fraction, default=0.2,
                     help="share of samples (random split) and of meshes (mesh split) for validation (default 0.2)")
    pub.add_argument("--test-fraction", type=fraction, default=0.2,
                     help="share of meshes held out for test in the mesh split (default 0.2)")
    pub.set_defaults(func=cmd_publish)

def _add_verify(sub) -> None:
    """``verify``: its options."""
    ver = sub.add_parser("verify", help="check shards against a manifest (missing, changed or extra files), or "
                         "read a folder of shards whole (damaged ones)")
    ver.add_argument("manifest", type=Path, help="a manifest, e.g. manifests/builtin-shapes-1.3.0.json; or a "
                     "folder of shards, or one shard: each read whole, every checksum and value range checked")
    ver.add_argument("--root", type=Path, help="folder holding the shards (default: the one the manifest records, "
                     "relative to the manifest)")
    ver.add_argument("--content", action="store_true",
                     help="accept a shard whose file bytes differ when every array and attribute equals the "
                     "published one (a regeneration written by another HDF5 library, say)")
    ver.set_defaults(func=cmd_verify)

def _add_export(sub) -> None:
    """``export``: its options."""
    export = sub.add_parser("export", help="write shards in another project's file layout (PC-NBV's, SCVP's)")
    export.add_argument("shards", type=Path, nargs="+", help="shard files or folders, or one published version's "
                        "manifest (manifests/NAME-X.Y.Z.json: verified first)")
    export.add_argument("--format", required=True, help="pc-nbv: PC-NBV's per-state viewstate/acc_pc/target_value "
                        ".npy files, gt.xyz and viewspace.txt (needs shards made with --set state.points=N; "
                        "docs/pointclouds.md); scvp: SCVP's folders of grid.txt and view_ids.txt (needs "
                        "--set oracle.cover=true --set views.layout=scvp-32 --set views.count=32; docs/setcover.md)")
    export.add_argument("--out", type=Path, required=True, help="a new folder to write")
    export.add_argument("--root", type=Path, help="with a manifest: the folder holding its shards (default: the "
                        "one it records)")
    export.set_defaults(func=cmd_export)

def _add_share(sub) -> None:
    """``share``: its options."""
    share = sub.add_parser("share", help="a published version as a folder to upload whole: Hugging Face Hub card and "
                           "splits that datasets.load_dataset reads, Croissant, CITATION.cff, .zenodo.json, the shards")
    share.add_argument("manifest", type=Path, help="a published version, e.g. manifests/builtin-shapes-1.3.0.json "
                       "(with its Croissant and citation files: nbvdata publish MANIFEST --about FILE writes them)")
    share.add_argument("--out", type=Path, required=True, help="a new folder to write")
    share.add_argument("--root", type=Path, help="the folder holding its shards (default: the one it records)")
    share.set_defaults(func=cmd_share)


def _add_show(sub) -> None:
    """``show``: its options."""
    show = sub.add_parser("show", help="render a shard sample or a grid with the candidate views to PNG")
    show.add_argument("grid", type=Path, nargs="?",
                      help="a shard (.h5; pick the sample with --index) or a .npy of one (n, n, n) grid or of "
                      "(B, n, n, n) grids (pick one with --index), float probabilities in [0, 1], 0.5 = unknown "
                      "(the authors' encoding); n = grid.size, 32 by default")
    show.add_argument("--index", type=non_negative_int, default=0,
                      help="sample of the shard, or grid of a (B, n, n, n) .npy, to render (default 0)")
    show.add_argument("--top", type=non_negative_int, default=5, help="runner-up candidate views to draw (orange)")
    _add_object_options(show)
    _add_config_options(show)
    show.add_argument("--views", default="0", help="without a grid file: views to scan from, e.g. 0,120,340")
    show.add_argument("--highlight", type=non_negative_int, help="index of the view to draw as a red arrow")
    show.add_argument("--seed", type=non_negative_int, default=0, help="seed for sensor noise")
    show.add_argument("--out", type=Path, default=Path("nbv_show.png"), help="PNG to write")
    show.set_defaults(func=cmd_show)

def _add_demo(sub) -> None:
    """``demo``: its options."""
    demo = sub.add_parser("demo", help="scan an object from a few random views and render the grid to PNG")
    _add_object_options(demo)
    _add_config_options(demo)
    demo.add_argument("--scans", type=positive_int, default=4, help="number of scans (default 4)")
    demo.add_argument("--seed", type=non_negative_int, default=0, help="seed for the views, noise and reference points")
    demo.add_argument("--out", type=Path, default=Path("nbv_demo.png"), help="PNG to write")
    demo.add_argument("--rerun", type=Path, metavar="FILE.rrd", help="also write a Rerun recording of every scan "
                      "(open it with: rerun FILE.rrd; needs the viz extra; docs/rerun.md)")
    demo.set_defaults(func=cmd_demo)

def _add_import_legacy(sub) -> None:
    """``import-legacy``: its options."""
    legacy = sub.add_parser("import-legacy", help="convert the authors' published dataset into shards")
    legacy.add_argument("--volumes", type=Path, required=True,
                        help="dataset_volumes_regression.zip or .npy (N grids of 32^3 probabilities)")
    legacy.add_argument("--poses", type=Path, required=True, help="dataset_pose.zip or .npy (N NBV poses)")
    legacy.add_argument("--out", type=Path, required=True, help="output folder")
    legacy.add_argument("--rows-per-shard", type=positive_int, default=2048, help="rows per shard (default 2048)")
    legacy.add_argument("--limit", type=positive_int, help="import only the first N rows (for tests and tries)")
    legacy.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                        help="show a progress bar (default: on a terminal)")
    legacy.set_defaults(func=cmd_import_legacy)


@exit_quietly_when_stdout_closes
def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    return run_command("nbvdata", args)


if __name__ == "__main__":
    sys.exit(main())
