#!/bin/sh
# install_python.sh VENV: install the project (editable) and its test extras into the venv VENV.
# uv (from PyPI, into the venv) installs them where it can be had, else pip (as before). Then the
# packages' modules are byte-compiled, tests folders left out: this machine's environment
# (PYTHONDONTWRITEBYTECODE) keeps Python from writing bytecode itself, and every process a session
# starts imports numpy, scipy and numba. Measured on 2 cores with warm caches (issue 49): 30 s, against
# 72 s for pip, which compiled every file one at a time.
set -eu

venv="$1"
py="$venv/bin/python"

if "$py" -m pip install --quiet --disable-pip-version-check uv >/dev/null 2>&1; then
    "$venv/bin/uv" pip install --quiet --python "$py" --upgrade-package pip pip -e ".[test]"
else
    echo "install_python.sh: uv could not be installed from PyPI; installing with pip" >&2
    "$py" -m pip install --quiet --upgrade pip
    "$py" -m pip install --quiet --no-compile -e ".[test]"
fi
site=$("$py" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
"$py" -m compileall -q -j 0 -x '/tests?/' "$site" >/dev/null || echo "install_python.sh: some modules could not be byte-compiled (they compile when imported)" >&2
