"""SCVP's 32 candidate views (Pan et al., RA-L 2022), the layout ``views.layout: scvp-32``.

The positions are their ``sc-net/view_space.txt`` (repository psc0628/SCVP-Simulation, MIT
licence): metres on their view sphere around the object, the upper hemisphere, z up as here.
Their network's outputs index these rows, so the order is theirs. The layout keeps their
directions and puts the views at ``views.radius``.
"""

from __future__ import annotations

import numpy as np

SCVP_VIEW_SPACE_32 = np.array([  # (32, 3) x, y, z in metres, their file's rows in order
    (-0.0181873, -0.164359, 0.250311),
    (0.0841047, 0.185797, 0.220013),
    (-0.175144, -0.227254, 0.087638),
    (0.190745, -0.231528, 0.00334377),
    (0.052354, -0.0534508, 0.29052),
    (-0.244266, 0.0796451, 0.15489),
    (-0.204274, -0.0364497, 0.216665),
    (0.0846345, 0.279202, 0.0698819),
    (0.196407, -0.0447294, 0.222314),
    (0.268875, 0.121518, 0.0542185),
    (-0.0412795, 0.269933, 0.124226),
    (0.276878, -0.0269452, 0.112306),
    (-0.0848467, -0.048845, 0.283576),
    (0.273605, -0.122317, 0.013377),
    (-0.143702, 0.0824778, 0.250094),
    (0.122697, -0.245074, 0.122001),
    (-0.270158, -0.0790121, 0.103788),
    (-0.295669, 0.0370648, 0.0347312),
    (-0.1677, 0.193795, 0.15595),
    (0.122488, 0.0623324, 0.266667),
    (-0.0109508, -0.259038, 0.150928),
    (-0.0125056, 0.0677291, 0.291987),
    (-0.067782, -0.290714, 0.029848),
    (0.0674563, -0.292269, 0.0053191),
    (0.220694, -0.149896, 0.137205),
    (-0.147971, -0.161313, 0.205141),
    (0.226376, 0.0821916, 0.178881),
    (-0.246274, 0.164751, 0.0469716),
    (0.183136, 0.201465, 0.125988),
    (0.117121, -0.1569, 0.227299),
    (-0.0529044, 0.184057, 0.23092),
    (-0.146779, 0.259041, 0.0367914),
])


def scvp_32() -> np.ndarray:
    """(32, 3) float64 unit directions of SCVP's views, in their order (the norm in a fixed order
    of operations, so the bytes are the same on every CPU); ``nbvdata.core.views.FIXED_LAYOUTS``."""
    x, y, z = SCVP_VIEW_SPACE_32.T
    return SCVP_VIEW_SPACE_32 / np.sqrt(x * x + y * y + z * z)[:, None]
