"""Fleet calibration (layer 7): every vehicle of a fleet as one job, resumable, failures isolated.

Modules, named for what they hold:

- ``jobs``: ``Job`` (plain data: paths, names, dicts; it crosses process and machine boundaries),
  ``discover_jobs`` (one job per vehicle across every root, or a ``FLEET.json``), ``calibrate_job``
  (THE one call into the per-vehicle calibration) and ``run_job`` (its outcome as plain data).
- ``manifest``: ``Manifest``, the job list and each job's state in ``OUT/manifest.json`` (atomic).
- ``engines``: ``local`` (in-process), ``process`` (spawned process pool), ``ray`` (a Ray cluster or
  a local one), one interface: ``run_engine(engine, jobs, on_outcome, ...)``.
- ``prior``: the fleet's random-effects model (mean mount and spread, outliers named) and the
  prior it gives each vehicle (``calib.schedule.GaussianPrior``).
- ``summary``: the fleet view (``OUT/summary.json``, ``summary.md``, ``fleet_prior.json``).
- ``driver``: ``run_fleet``, the chain: discover -> manifest -> engine -> summary.
"""
