"""nbvdata: simulated reconstructions labelled with the ground-truth next-best-view.

Data flows one way: mesh -> views -> sensor -> grid -> coverage (-> oracle -> episode -> shards).
"""

__version__ = "0.1.0"
