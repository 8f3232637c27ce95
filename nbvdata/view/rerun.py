"""Rerun recordings of reconstructions: scrub through every scan of a run in 3D (``--rerun``).

A ``Recording`` is one ``.rrd`` file; each run in it is an entity tree of its own (a
``RunLog``), so several runs (``nbvdata generate --rerun-runs``) or planners (``nbvtrain
evaluate --rerun``) sit side by side. Everything a run logs is on the timeline ``scan``: the
state after that many scans. Under a run's root:

    mesh                the object (static)
    scans/NN            scan NN's surface points, one colour per scan (logged at scan NN, so
                        every earlier scan stays in view)
    grid/occupied       occupied voxels (p > 0.5) as boxes, darker when more certain
    grid/unknown        never-observed voxels (p = 0.5) as faint points; toggle it off in the
                        viewer's entity tree to see through
    views/candidates    the candidate views as points coloured by the oracle's gain at this
                        state (dark purple to yellow = least to most new surface; grey: below
                        the overlap rule or adding nothing)
    views/sensor        the pose of the latest scan, drawn as the sensor's frustum
    views/path          the poses scanned so far, joined in order
    views/chosen        arrow: the view the run moves to next (cleared at its last state)
    views/nbv           arrow: the oracle's next-best view at this state (cleared when none)
    coverage            observable surface covered, in %, a line plot over the scans

The points of a scan are cast again, noise-free, from its pose (``MeshScanner.scan`` without a
generator): the run's own scan for a noise-free sensor (the default), its noise-free twin
otherwise. Recording is a pure observer: it reads states and draws from no random stream, so a
run's results and every shard are the same with or without it.

Needs the ``viz`` extra (``rerun-sdk``); importing this module without it raises ImportError
with the install command. Open a recording with ``rerun FILE.rrd`` (docs/rerun.md).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

try:
    import rerun as rr
    import rerun.blueprint as rrb
except ImportError:
    raise ImportError("nbvdata.view.rerun needs rerun-sdk, which is not installed: "
                      'pip install -e ".[viz]" (in a checkout) or pip install "rerun-sdk>=0.41"') from None

import numpy as np

from nbvdata.core.files import TEMPORARY_SUFFIX, process_tag
from nbvdata.core.logodds import probability
from nbvdata.core.views import Pose
from nbvdata.simulation.episode import NO_MOVE, LabelledRun
from nbvdata.simulation.scene import Scene

TIMELINE = "scan"
# One colour per scan (tab10), repeated after ten.
SCAN_COLOURS = np.array([[31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189],
                         [140, 86, 75], [227, 119, 194], [127, 127, 127], [188, 189, 34], [23, 190, 207]],
                        dtype=np.uint8)
# viridis at 0, 1/4, 1/2, 3/4 and 1: the candidate views' gain, least to most.
GAIN_RAMP = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], dtype=np.float64)
NO_GAIN = (90, 90, 90, 160)
OCCUPIED_LOW, OCCUPIED_HIGH = np.array([150, 190, 240.0]), np.array([20, 60, 160.0])  # p just over 0.5 -> 1
UNKNOWN = (230, 190, 30, 50)
MESH = (200, 200, 200, 255)
CHOSEN, NBV = (30, 200, 60), (230, 30, 30)
EYE = np.array([1.1, -1.1, 0.95])  # where each 3D view looks from, in view-sphere radii: just outside it


def gain_colours(gains: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(V,) gains and (V,) bool valid views -> (V, 4) uint8 RGBA: ``GAIN_RAMP`` over the valid
    views' gains relative to the largest, ``NO_GAIN`` for the others."""
    gains = np.asarray(gains, dtype=np.float64)
    valid = np.asarray(valid, dtype=bool) & (gains > 0)
    top = gains[valid].max() if valid.any() else 1.0
    where = np.clip(gains / top, 0.0, 1.0) * (len(GAIN_RAMP) - 1)
    rgb = np.stack([np.interp(where, np.arange(len(GAIN_RAMP)), GAIN_RAMP[:, c]) for c in range(3)], axis=1)
    colours = np.empty((len(gains), 4), dtype=np.uint8)
    colours[:, :3] = np.round(rgb)
    colours[:, 3] = 255
    colours[~valid] = NO_GAIN
    return colours


class Recording:
    """One ``.rrd`` file of one or more runs. Written under a temporary name and renamed by
    ``close`` (``with Recording(...) as recording:`` closes it), so a killed job leaves no
    cut-off recording under the final name (its ``.NAME.rrd.HOST-PID.tmp`` is swept by the next
    job, ``nbvdata.datasets.claims.sweep_temporaries``); the viewer's layout shows each run's 3D view side by
    side above the coverage plot."""

    def __init__(self, path: str | Path, name: str):
        """``name``: the recording's name in the viewer (a mesh, say)."""
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._partial = self.path.with_name(f".{self.path.name}.{process_tag()}{TEMPORARY_SUFFIX}")
        self.stream = rr.RecordingStream("nbvdata")
        self.stream.set_log_time_enabled(False)  # one timeline: scan
        self.stream.set_log_tick_enabled(False)
        self.stream.save(self._partial)
        self.stream.send_recording_name(name)
        self.roots: list[str] = []
        self.radius = 0.0  # of the largest view sphere of the runs

    def run(self, parts: Sequence[str], scene: Scene) -> "RunLog":
        """A new run under the entity path of ``parts`` (each escaped: ("regression", "start_0")
        -> regression/start_0); logs the scene's mesh there."""
        root = "/".join(rr.escape_entity_path_part(part) for part in parts)
        self.roots.append(root)
        self.radius = max(self.radius, scene.config.views.radius)
        return RunLog(self.stream, root, scene)

    def close(self) -> Path:
        """Send the layout, finish the file and give it its name; returns the path."""
        eye = rrb.archetypes.EyeControls3D(kind="Orbital", position=self.radius * EYE, look_target=[0, 0, 0],
                                           eye_up=[0, 0, 1])
        views = [rrb.Spatial3DView(origin=root, name=root, eye_controls=eye) for root in self.roots]
        plot = rrb.TimeSeriesView(origin="/", contents=[f"+ /{root}/coverage" for root in self.roots],
                                  name="observable coverage (%)")
        self.stream.send_blueprint(rrb.Blueprint(rrb.Vertical(rrb.Grid(*views), plot, row_shares=[3, 1]),
                                                 collapse_panels=True))
        self.stream.flush()
        self.stream.disconnect()
        os.replace(self._partial, self.path)
        return self.path

    def discard(self) -> None:
        """Stop without a file (the run failed)."""
        self.stream.disconnect()
        self._partial.unlink(missing_ok=True)

    def __enter__(self) -> "Recording":
        return self

    def __exit__(self, kind, error, traceback) -> None:
        if kind is None:
            self.close()
        else:
            self.discard()


class RunLog:
    """The entity tree of one run in a ``Recording``: ``step`` logs each state."""

    def __init__(self, stream: rr.RecordingStream, root: str, scene: Scene):
        self.stream, self.root, self.scene = stream, root, scene
        self.grid = scene.config.scene_grid
        self.centres = scene.new_grid().voxel_centres()  # (n, n, n, 3) metres
        self.path: list[np.ndarray] = []  # the scanned positions, (3,) each
        mesh = scene.object.mesh
        stream.log(root, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        stream.log(f"{root}/mesh", rr.Mesh3D(vertex_positions=np.asarray(mesh.vertices, dtype=np.float32),
                                             triangle_indices=np.asarray(mesh.faces, dtype=np.uint32),
                                             vertex_normals=np.asarray(mesh.vertex_normals, dtype=np.float32),
                                             albedo_factor=MESH), static=True)
        stream.log(f"{root}/coverage", rr.SeriesLines(names=root, widths=2), static=True)

    def step(self, scan: int, probabilities: np.ndarray, sensor: Pose, coverage: float,
             gains: np.ndarray | None = None, overlaps: np.ndarray | None = None,
             nbv: int | None = None, chosen: Pose | None = None) -> None:
        """Log the state after ``scan`` scans, the last one taken from ``sensor``.

        probabilities : (n, n, n) float32 occupancy, exactly 0.5 where unknown
        coverage : observable coverage in [0, 1]
        gains, overlaps : (V,) the oracle's scores of every candidate view (None: unknown)
        nbv : the oracle's next-best view (None: no valid view adds surface)
        chosen : the pose of the next scan (None at the run's last state)
        """
        stream, root = self.stream, self.root
        stream.set_time(TIMELINE, sequence=scan)
        hits = self.scene.scanner.scan(sensor, cloud=False).hit_points  # noise-free: draws nothing
        stream.log(f"{root}/scans/{scan:02d}", rr.Points3D(hits, colors=SCAN_COLOURS[(scan - 1) % len(SCAN_COLOURS)],
                                                          radii=0.4 * self.grid.resolution / 2))
        self._log_grid(np.asarray(probabilities))
        views = self.scene.views
        if gains is None:
            colours = np.tile(np.array(NO_GAIN, dtype=np.uint8), (len(views), 1))
        else:
            colours = gain_colours(gains, np.asarray(overlaps) >= self.scene.config.oracle.min_overlap)
        stream.log(f"{root}/views/candidates", rr.Points3D(views.positions, colors=colours, radii=-3.0))  # UI points
        sensor_config = self.scene.config.sensor
        stream.log(f"{root}/views/sensor", rr.Transform3D(translation=sensor.position, mat3x3=sensor.rotation.T),
                   rr.Pinhole(fov_y=sensor_config.vfov, aspect_ratio=sensor_config.width / sensor_config.height,
                              image_plane_distance=0.05, camera_xyz=rr.ViewCoordinates.RDF))
        self.path.append(np.asarray(sensor.position, dtype=np.float64))
        stream.log(f"{root}/views/path", rr.LineStrips3D([np.stack(self.path)], colors=CHOSEN, radii=0.001))
        self._log_arrow("chosen", chosen, CHOSEN)
        self._log_arrow("nbv", views[nbv] if nbv is not None else None, NBV)
        stream.log(f"{root}/coverage", rr.Scalars(100.0 * coverage))

    def scored_step(self, scan: int, probabilities: np.ndarray, sensor: Pose, covered: np.ndarray,
                    chosen: Pose | None = None) -> None:
        """``step`` with the scene oracle's scores and coverage of the state whose scans covered
        ``covered`` ((W,) packed reference points)."""
        oracle = self.scene.oracle
        scores = oracle.score(covered)
        self.step(scan, probabilities, sensor, oracle.observable_coverage(covered), scores.gains, scores.overlaps,
                  scores.best(self.scene.config.oracle.min_overlap), chosen)

    def _log_grid(self, probabilities: np.ndarray) -> None:
        """Occupied voxels as boxes, unknown ones as points, at the voxel centres."""
        resolution = self.grid.resolution
        occupied = probabilities > 0.5
        certainty = ((probabilities[occupied] - 0.5) / 0.5)[:, None]
        colours = np.round(OCCUPIED_LOW + certainty * (OCCUPIED_HIGH - OCCUPIED_LOW)).astype(np.uint8)
        self.stream.log(f"{self.root}/grid/occupied",
                        rr.Boxes3D(centers=self.centres[occupied], half_sizes=[[resolution / 2] * 3],
                                   colors=colours, fill_mode="TransparentFillMajorWireframe"))
        self.stream.log(f"{self.root}/grid/unknown", rr.Points3D(self.centres[probabilities == 0.5],
                                                                 colors=UNKNOWN, radii=resolution / 6))

    def _log_arrow(self, name: str, pose: Pose | None, colour: tuple[int, int, int]) -> None:
        """An arrow along ``pose``'s optical axis, a quarter of its distance to the object centre long,
        or a clear."""
        path = f"{self.root}/views/{name}"
        if pose is None:
            self.stream.log(path, rr.Clear(recursive=False))
            return
        position = np.asarray(pose.position, dtype=np.float64)
        length = 0.25 * np.linalg.norm(position)
        self.stream.log(path, rr.Arrows3D(origins=[position], vectors=[length * pose.direction], colors=colour,
                                          radii=0.002, labels=[name], show_labels=False))


def log_record(run: RunLog, record: LabelledRun) -> None:
    """Log every state of a generated run (``nbvdata.simulation.episode.run_reconstruction``'s record):
    its grid, oracle scores, NBV and next move."""
    views = run.scene.views
    for i in range(len(record)):
        last = record.last_view[i]  # -1: a policy's pose, no candidate view
        sensor = views[last] if last >= 0 else Pose.from_xyzypr(record.next_pose[i - 1])
        chosen = None
        if record.move[i] != NO_MOVE:
            following = record.next_view[i]
            chosen = views[following] if following >= 0 else Pose.from_xyzypr(record.next_pose[i])
        run.step(i + 1, probability(record.log_odds[i]), sensor, record.coverage[i][0], record.gains[i],
                 record.overlaps[i], record.nbv_index[i], chosen)
