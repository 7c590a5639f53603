"""The numba cache folder per version of the source (lrnbv_drake/numba_cache.py)."""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import lrnbv_drake
from lrnbv_drake.numba_cache import cache_dir, source_hash

PACKAGE = Path(lrnbv_drake.__file__).parent

CALLEE = "import numba\n\n@numba.njit(cache=True)\ndef rule(x):\n    return x + {}\n"
CALLER = textwrap.dedent("""\
    import numba
    from callee import rule

    @numba.njit(cache=True)
    def kernel(x):
        return rule(x) * 10
    """)
RUN = textwrap.dedent("""\
    import os, sys
    from pathlib import Path
    from lrnbv_drake.numba_cache import cache_dir
    os.environ["NUMBA_CACHE_DIR"] = str(cache_dir(Path(sys.argv[1])))
    sys.path.insert(0, sys.argv[1])
    from caller import kernel
    print(kernel(1))
    """)


def _environment() -> dict[str, str]:
    """This process's environment without a chosen numba cache."""
    return {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}


def _kernel_output(folder: Path) -> str:
    env = _environment()
    return subprocess.run([sys.executable, "-c", RUN, str(folder)], capture_output=True,
                          text=True, check=True, env=env).stdout.strip()


def test_a_kernel_sees_an_edit_of_the_kernel_it_calls_in_another_file(tmp_path):
    """numba re-compiles a cached kernel when its own file changes, not when a kernel it calls
    from another file does; with the folder keyed by every file, the edit is seen."""
    (tmp_path / "caller.py").write_text(CALLER)
    (tmp_path / "callee.py").write_text(CALLEE.format(1))
    assert _kernel_output(tmp_path) == "20"  # compiled and cached
    assert _kernel_output(tmp_path) == "20"  # from the cache
    (tmp_path / "callee.py").write_text(CALLEE.format(2))
    assert _kernel_output(tmp_path) == "30"


DEVICE = textwrap.dedent("""\
    import sys
    import numpy as np
    from lrnbv_drake.core.sensing.sensor import NoiseModel, SensorModelParams
    from lrnbv_drake.core.calibration.mixed_zone import edge_scene_depths
    from lrnbv_drake.core.sensing.tof_device import DeviceBehaviour, device_readings
    p = SensorModelParams(noise=NoiseModel(0, 0))
    d = edge_scene_depths(p.geometry, 8, 0.0, 400.0, 700.0)
    for order, merge in [("closest", 0.0), ("strongest", 600.0)][:int(sys.argv[1])]:
        frame = device_readings(d, p, DeviceBehaviour(target_order=order, merge_mm=merge),
                                np.random.default_rng(0))
    print(int(frame.status[0, 0]))
    """)


def test_the_device_kernels_load_in_any_order_without_crashing(tmp_path):
    """The ideal device (`sensor._cluster_kernel`) compiled in one process, the datasheet one
    (`tof_device._targets_kernel`) in a second that loaded the first from the cache: a third
    that loaded both crashed (SIGSEGV) while the latter was cached too. It is not."""
    env = _environment() | {"NUMBA_CACHE_DIR": str(tmp_path)}
    for kernels in (1, 2, 2):
        run = subprocess.run([sys.executable, "-c", DEVICE, str(kernels)], capture_output=True,
                             text=True, env=env)
        assert run.returncode == 0, run.stderr[-2000:]
        assert run.stdout.strip() == "5"


def test_the_hash_follows_every_file_and_only_the_source(tmp_path):
    (tmp_path / "a.py").write_text("x = 1\n")
    first = source_hash(tmp_path)
    (tmp_path / "notes.txt").write_text("not source")
    assert source_hash(tmp_path) == first
    (tmp_path / "a.py").write_text("x = 2\n")
    assert source_hash(tmp_path) != first
    assert cache_dir(tmp_path) == tmp_path / "__pycache__" / f"numba-{source_hash(tmp_path)}"


def test_importing_the_package_chooses_the_folder_unless_one_is_chosen():
    code = "import os, lrnbv_drake; print(os.environ['NUMBA_CACHE_DIR'])"
    env = _environment()
    chosen = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            check=True, env=env).stdout.strip()
    assert chosen == str(cache_dir(PACKAGE))
    kept = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True, env=env | {"NUMBA_CACHE_DIR": "/tmp/mine"}).stdout.strip()
    assert kept == "/tmp/mine"


#: The modules whose kernels an episode's loop runs: the map, the gains, the estimator and
#: the arm's kinematics and collision balls.
LOOP_KERNEL_MODULES = (
    "lrnbv_drake.core.mapping.insert_kernels", "lrnbv_drake.core.mapping.query_kernels",
    "lrnbv_drake.core.planning.utility", "lrnbv_drake.core.planning.box_gain",
    "lrnbv_drake.core.estimation.forward", "lrnbv_drake.core.robot.kinematics",
    "lrnbv_drake.core.robot.poses", "lrnbv_drake.core.robot.sure_collision")
UNCOMPILED = textwrap.dedent("""\
    import importlib, sys
    from numba.core.registry import CPUDispatcher
    from lrnbv_drake.core.kernels import compile_kernels
    compile_kernels()
    kernels = {f"{name}.{key}": value for name in sys.argv[1:]
               for key, value in vars(importlib.import_module(name)).items()
               if isinstance(value, CPUDispatcher) and value.__module__ == name}
    called = {n for k in kernels.values() for n in k.py_func.__code__.co_names}
    for name, kernel in kernels.items():
        if name.rsplit(".", 1)[1] not in called and not kernel.signatures:
            print(name)
    """)


def test_compile_kernels_gives_every_kernel_python_calls_in_the_loop_a_signature():
    # A fresh process, so that no other test has compiled a kernel for it: each kernel the
    # loop's modules define that Python calls has a compiled signature once compile_kernels
    # has run. A kernel only other kernels call is left out: loading its callers from the
    # cache does not load it.
    out = subprocess.run([sys.executable, "-c", UNCOMPILED, *LOOP_KERNEL_MODULES],
                         capture_output=True, text=True, check=True, timeout=600).stdout
    assert out.split() == []


def test_the_tests_compile_into_the_cache_the_package_chooses():
    """conftest imports numba (for xdist's thread counts) after the package, which points
    numba at the versioned cache `make` fills; numba imported first would compile every kernel
    again per worker, into numba's per-file cache that misses an edit of a called kernel."""
    import numba

    assert Path(numba.config.CACHE_DIR) == cache_dir(PACKAGE)
