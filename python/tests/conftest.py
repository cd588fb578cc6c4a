import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
FIXTURE = ROOT / "fixtures" / "mandelbrot-pan-240fps.mp4"


@pytest.fixture(scope="session")
def cli():
    """Runs the `pipeline` command line (the binary `cargo test --release` built, or PIPELINE_BIN)."""
    exe = os.environ.get("PIPELINE_BIN", str(ROOT / "target" / "release" / "pipeline"))
    if not Path(exe).exists():
        pytest.fail(f"{exe} not found: build the CLI (cargo build --release) or set PIPELINE_BIN")

    def run(*args, cwd=ROOT):
        r = subprocess.run([exe, *map(str, args)], cwd=cwd, capture_output=True, text=True)
        assert r.returncode == 0, f"pipeline {' '.join(map(str, args))}: exit {r.returncode}\n{r.stderr}"
        return r

    return run


@pytest.fixture(scope="session")
def clips(tmp_path_factory):
    """Four copies of the fixture under their own names: four inputs, each with its own samples."""
    d = tmp_path_factory.mktemp("clips")
    for name in "abcd":
        shutil.copy(FIXTURE, d / f"{name}.mp4")
    return d
