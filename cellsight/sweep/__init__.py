"""Studies over many runs (issue 15): a grid of cells x experiments x sensors x variants x
seeds (:mod:`.grid`), run resumably on a local process pool or a Dask cluster
(:mod:`.engine`), summed up as tables and plots (:mod:`.summary`); ``cellsight sweep``
(:mod:`.command`)."""

from cellsight.sweep.engine import map_jobs
from cellsight.sweep.grid import VARIANTS, RunSpec, run_spec, sweep_grid

__all__ = ["VARIANTS", "RunSpec", "map_jobs", "run_spec", "sweep_grid"]
