"""nbvdata: simulated reconstructions labelled with the ground-truth next-best-view.

Data flows one way, stage by stage (base, schema, simulation, datasets): docs/design.md states
the stages once, and tests/test_layout.py holds the imports to them.
"""

__version__ = "0.1.0"
