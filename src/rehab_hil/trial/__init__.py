"""The in-silico trial: a controller run over a virtual cohort of simulated patients (``cohort.py``),
each patient's sessions on the in-process rig, on a local process pool or a Dask cluster
(``run.py``), written to ``trial.json`` and ``trial.html`` (``report.py``). docs/patient.md."""
