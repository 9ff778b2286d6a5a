#!/usr/bin/env bash
# The test command behind `make test` and `make test-fast`: ruff check, ruff format --check,
# pyright (standard mode over feed_twin/, tests/, benchmarks/, tools/; [tool.pyright] in
# pyproject.toml) and pytest, all four run even when an earlier one fails (so pytest's summary
# line is always printed); the exit status is non-zero when any failed. Arguments go to pytest.
# pytest's exit status 5 (no tests collected) counts as success.

set -o nounset

here="${BASH_SOURCE[0]%/*}"
[[ "$here" == "${BASH_SOURCE[0]}" ]] && here="."
cd "$here/.." || exit 1
bin="${FEED_TWIN_VENV:-.venv}/bin"

failed=()

echo "== ruff check"
"$bin/ruff" check . || failed+=("ruff check")
echo "== ruff format --check"
"$bin/ruff" format --check . || failed+=("ruff format")
echo "== pyright"
# the pinned wheel's own pyright and Node.js: no look-up of a newer version on the network;
# --project: this checkout's pyproject.toml, never a pyrightconfig.json in a folder above it
# (a stray /tmp/pyrightconfig.json once made a clone in /tmp check nothing, with 0 errors)
PYRIGHT_PYTHON_IGNORE_WARNINGS=1 "$bin/pyright" --project pyproject.toml --pythonpath "$bin/python" \
    || failed+=("pyright")
echo "== pytest $*"
# OpenBLAS's own threads spin against the engine's and the nodes' on a small machine (a diagnose
# of the same record took 0.9-21 s); one thread unless the caller chose
export OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}"
"$bin/pytest" "$@"
status=$?
if [[ $status -eq 5 ]]; then
    echo "run_tests: pytest collected no tests"
elif [[ $status -ne 0 ]]; then
    failed+=("pytest (exit $status)")
fi

# On success pytest's summary stays the last line of the output, where CI looks for it.
if [[ ${#failed[@]} -gt 0 ]]; then
    summary="$(printf '%s, ' "${failed[@]}")"
    echo "run_tests: FAILED: ${summary%, }"
    exit 1
fi
