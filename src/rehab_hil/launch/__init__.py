"""Start the project's own Python child processes (simulated devices, loop processes) by forking a warm
interpreter, the zygote, that has already imported them: a child then starts in milliseconds instead of
importing numpy, numba and the package again (about 1.5 s of CPU each; a session starts two).

``popen(argv, ...)`` takes what ``subprocess.Popen`` takes for ``[sys.executable, "-c"|"-m", ...]`` and
returns a ``subprocess.Popen`` or a ``ForkedChild`` with the same methods. Anything else (another program,
interpreter flags, an environment whose numba/BLAS/Python settings differ from the zygote's, or
``REHAB_HIL_ZYGOTE=0``) is an ordinary ``subprocess.Popen``.
"""

from rehab_hil.launch.client import ForkedChild, popen, warm

__all__ = ["ForkedChild", "popen", "warm"]
