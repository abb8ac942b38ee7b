"""Studies over many runs (issue 15): a grid of cells x experiments x sensors x variants x
seeds (:mod:`.grid`), run resumably on a local process pool or a Dask cluster
(:mod:`.engine`), summed up as tables and plots (:mod:`.summary`); ``cellsight sweep``
(:mod:`.command`). The package imports nothing itself (a fast command line)."""
