"""The one kind of error a user can fix, and what each command line does with it.

``UserError`` is anything the user gave - a setting, an argument, a file - that cannot be used.
Its message is one line naming the value or file and the fix; both command lines print it and
exit with status 2 (``nbvdata.commandline.run_command``), never a traceback. Each topic's error
is one of them, by what it is about:

- ``nbvdata.core.config.ConfigError``: a setting or a command-line value (``nbvdata.simulation.policy.PolicyError``
  a policy to follow, ``nbvtrain.networks.trained_scene.SceneMismatch`` a network trained in another scene);
- ``nbvdata.simulation.mesh.MeshError``: a mesh file;
- ``nbvdata.schema.shards.ShardError``: a shard file (``nbvdata.schema.manifest.ManifestError`` a published version);
- ``nbvdata.datasets.authors.AuthorsDataError``: the authors' published files;
- ``nbvdata.core.userarrays.NpyError`` and ``GridError``: a user's arrays;
- ``nbvtrain.networks.checkpoint.CheckpointError``: a checkpoint file; ``nbvtrain.release.NoReleasedModel``:
  no released model installed;
- ``nbvtrain.robot.sensordata.SensorDataError`` and ``nbvtrain.robot.plan.PlanError``: a robot's data;
- ``nbvtrain.networks.train.TrainingDiverged``: a run whose loss stopped being finite.

They stay ``ValueError`` too, as they were.
"""

from __future__ import annotations


class UserError(ValueError):
    """An input the user can fix; the one-line message names it and the fix (module docstring)."""
