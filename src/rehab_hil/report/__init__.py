"""The session report: one self-contained HTML file (plotly, its JavaScript inlined) from one run's
recording, or the progress across several runs (``rehab-hil report``). ``runs`` reads a run
directory, ``figures`` draws it, ``page`` writes the file, ``browser`` opens a page in headless
Chromium (the tests and the benchmark check every plot is drawn)."""
