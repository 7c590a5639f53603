"""Tests run as CI does: offline (Drake may open Meshcat on localhost, never download)."""

import os

import pytest

# First: the package points numba at the kernels `make` compiled (lrnbv_drake/numba_cache.py),
# which it can only do before numba is imported (pytest_configure below imports it).
import lrnbv_drake  # noqa: F401

os.environ["DRAKE_ALLOW_NETWORK"] = "meshcat"
os.environ.setdefault("MPLBACKEND", "Agg")
# `make test` runs two pytest-xdist workers on CI's two cores: each takes its share of the
# cores for numba's and BLAS's threads, which would otherwise spin against each other.
WORKERS = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
if WORKERS > 1:
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(name, str(max(1, (os.cpu_count() or 1) // WORKERS)))


def pytest_configure(config):
    if WORKERS > 1:
        import numba

        numba.set_num_threads(max(1, numba.config.NUMBA_NUM_THREADS // WORKERS))


@pytest.fixture(scope="session")
def heu_run(tmp_path_factory):
    """A whole simulated HEU episode written by `lrnbv run` (horizontal box, seed 3): read by
    every test that takes it, changed by none."""
    from lrnbv_drake.cli.main import main

    out = tmp_path_factory.mktemp("heu")
    assert main(["run", "--planner", "heu", "--object", "horizontal_box", "--seed", "3",
                 "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="session")
def compiled_kernels():
    """The numba kernels `make` compiles after installing, loaded (or compiled, on a cache an
    edit made cold) in this process: a test that bounds a session's wall time bounds the
    session, not numba's first compile of the report's fit (about 5 s) or the IK."""
    from lrnbv_drake.core.kernels import compile_kernels

    compile_kernels()
