"""``nifo fleet``'s shell: manifest, cache, Dask orchestration, tables, page, Rerun.

The pure parts (tree reduction, strut health) live in :mod:`nifo_core.fleet`;
the per-bag spectral work is :class:`nifo_core.nifo.identify.StreamingNifo`, as in
``nifo identify``. Modules: :mod:`.manifest` (what to process), :mod:`.cache`
(partials by content hash), :mod:`.tasks` (what runs on a worker),
:mod:`.cluster` (the Dask client, the workers' fork server), :mod:`.preload` (what
warms a worker, once), :mod:`.worker_plugin` (the same on any cluster), :mod:`.runner` (the graph), :mod:`.outputs`
(Parquet/CSV/JSON), :mod:`.page` (HTML and figures), :mod:`.rerun_fleet`.
"""
