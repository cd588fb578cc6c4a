#!/usr/bin/env bash
# The Python package's tests: builds it into .venv (made by `bash .ci/setup.sh --python`) with
# maturin, then runs pytest. Expects the CLI built by `cargo test --release --features train` (the
# tests compare the package with it); torch-only tests skip unless torch is installed in .venv.
set -euo pipefail
cd "$(dirname "$0")/.."
export VIRTUAL_ENV="$PWD/.venv" PATH="$PWD/.venv/bin:$PATH"
# The CLI the tests compare with: PIPELINE_BIN, else the release build under CARGO_TARGET_DIR
# (or target/).
bin="${PIPELINE_BIN:-${CARGO_TARGET_DIR:-target}/release/pipeline}"
[ -x "$bin" ] || cargo build --release --features train
bin="$(cd "$(dirname "$bin")" && pwd)/$(basename "$bin")"
# Cargo's own progress lines show (the first build compiles PyO3 and reuses the rest).
echo "python-tests: building the package into .venv with maturin (reuses cargo's build of the CLI)" >&2
# With the test build's features, so maturin reuses every crate it compiled (the package itself
# needs only the default features, which a plain `pip install ./python` builds).
maturin develop --release --features pipeline/train 2>&1 | grep -v "^📦\\|^🔗\\|^🐍\\|^📡" >&2 || true
python -c "import pipeline._native" || { echo "python-tests: maturin develop did not install the package" >&2; exit 1; }
PIPELINE_BIN="$bin" python -m pytest -q python/tests "$@"
