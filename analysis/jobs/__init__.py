"""What sweeps and tunings share as resumable jobs: the key checker (``keys``), the JSON-lines logs with
their lock and checksums (``files``), Dask clusters (``cluster``) and the outputs' figures (``figures``).
"""
