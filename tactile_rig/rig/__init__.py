"""The bench and its sessions: ``bench.toml`` and connecting (:mod:`.bench`), MCAP recordings
(:mod:`.recording`, :mod:`.replay`), reports (:mod:`.reports`), progress (:mod:`.progress`),
sweeps (:mod:`.sweep`), learning sessions (:mod:`.learning`), scene runs and jig accuracy runs.

Submodules are imported on demand; optional extras (mcap, matplotlib, scikit-learn, Dask) only
inside the functions that need them. See ``docs/rig.md``.
"""
