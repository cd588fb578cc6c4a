#!/usr/bin/env bash
# The Python package's tests: builds it into .venv (made by `bash .ci/setup.sh --python`) with
# maturin, then runs pytest. Expects the CLI built by `cargo test --release` (the tests compare
# the package with it); torch-only tests skip unless torch is installed in .venv.
set -euo pipefail
cd "$(dirname "$0")/.."
export VIRTUAL_ENV="$PWD/.venv" PATH="$PWD/.venv/bin:$PATH"
[ -x target/release/pipeline ] || cargo build --release
maturin develop --release --quiet 2>&1 | grep -v "^📦\\|^🔗\\|^🐍\\|^📡" >&2 || true
python -c "import pipeline._native" || { echo "python-tests: maturin develop did not install the package" >&2; exit 1; }
PIPELINE_BIN="$PWD/target/release/pipeline" python -m pytest -q python/tests "$@"
