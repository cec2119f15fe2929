"""The ground floor: what every layer uses and nothing domain-level.

Errors and warnings (:mod:`.errors`), the shared names of the wrench and the regimes
(:mod:`.names`), pure numpy helpers on sampled signals (:mod:`.timeseries`), compiled small dense
linear algebra (:mod:`.linalg`), the declarative schemas of every file a user hands in
(:mod:`.schema`), atomic output and the output guard (:mod:`.files`), arrays spilled to disk past
a memory budget (:mod:`.spill`), many independent tasks on Dask (:mod:`.tasks`), process-wide
settings of the command line (:mod:`.runtime`) and the version (:mod:`.version`).

Nothing here imports another folder of ditherlab.
"""
