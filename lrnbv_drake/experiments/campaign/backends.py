"""Where a campaign's episodes run: one after the other in this process, in local processes,
or as Ray tasks. Each backend yields one record per episode as it ends, in any order; an
episode that raises, or whose worker dies, becomes a "failed" record instead of stopping the
campaign.

Ctrl-C reaches this process only (the workers ignore it), and stops the episodes still running
at once, however often it is pressed: their workers are terminated, and the next run of the
command runs those episodes again. SIGTERM (`kill`, a job scheduler's stop) does the same
while local workers run, rather than end this process alone and leave them running.
"""

from __future__ import annotations

import contextlib
import logging
import math
import multiprocessing
import signal
import threading
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numba

from lrnbv_drake.experiments.campaign.plan import BACKENDS, CampaignConfig, CampaignError, Episode
from lrnbv_drake.experiments.episode import make_meshcat, run_episode
from lrnbv_drake.experiments.report import rounded
from lrnbv_drake.station.scenario import Scenario

#: (scenario, planner, run folder, write a replay) -> the episode's report dict.
EpisodeFn = Callable[[Scenario, str, Path, bool], dict[str, Any]]


def simulate(scenario: Scenario, planner: str, out_dir: Path, replay: bool) -> dict[str, Any]:
    """The real episode: `run_episode`, with a Meshcat for the replay only when asked. Drake's
    INFO lines ("Allocating contexts ...") would break the progress bar: only its warnings
    pass, in whichever process the episode runs."""
    logging.getLogger("drake").setLevel(logging.WARNING)
    meshcat = make_meshcat(live=False) if replay else None
    return run_episode(scenario, planner, out_dir, meshcat).report


def execute(episode: Episode, out_dir: Path, episode_fn: EpisodeFn) -> dict[str, Any]:
    """Runs one episode into out_dir/runs/<key> and returns its record; an exception becomes a
    "failed" record with the traceback, so one bad episode never stops the campaign."""
    started = time.perf_counter()
    fields = episode.campaign_fields()
    try:
        report = episode_fn(episode.scenario, episode.planner, out_dir / fields["run_dir"],
                            episode.replay)
    except Exception as e:
        return failed_record(episode, f"{type(e).__name__}: {e}", traceback.format_exc(),
                             time.perf_counter() - started)
    fields |= {"status": "ok", "error": "", "traceback": "",
               "episode_seconds": time.perf_counter() - started}
    # Rounded as report.json is: the record, results.csv and the U tests then hold the same
    # numbers, and float noise (an error of 1e-17 m) is not ranked above an exact 0.
    return {**rounded(report), "campaign": fields}


def failed_record(episode: Episode, error: str, trace: str, seconds: float) -> dict[str, Any]:
    """The record of an episode that did not finish."""
    return {"campaign": episode.campaign_fields() | {
        "status": "failed", "error": error, "traceback": trace, "episode_seconds": seconds}}


#: Ctrl-C and `kill`: what a cleanup must not be cut short by.
INTERRUPTS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def signals_ignored(*signums: int) -> Iterator[None]:
    """`signums` are ignored inside, and by the processes started inside (an ignored signal
    stays ignored across exec, and Python then installs no handler for it). Signals are the
    main thread's: elsewhere this does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {signum: signal.signal(signum, signal.SIG_IGN) for signum in signums}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


@contextlib.contextmanager
def sigterm_interrupts() -> Iterator[None]:
    """SIGTERM raises KeyboardInterrupt inside, as Ctrl-C does (Python's default ends the
    process at once, with no cleanup). Workers spawned inside do not inherit the handler.
    Signals are the main thread's: elsewhere this does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def share_cores(jobs: int) -> None:
    """Gives this worker its share of the CPUs numba may use (those the process may run
    on), so that `jobs` workers side by side do not oversubscribe them."""
    numba.set_num_threads(max(1, numba.config.NUMBA_NUM_THREADS // jobs))


def execute_on_one_thread(episode: Episode, out_dir: Path, episode_fn: EpisodeFn
                          ) -> dict[str, Any]:
    """`execute` with the numba kernels on one thread: a Ray task holds one CPU."""
    numba.set_num_threads(1)
    return execute(episode, out_dir, episode_fn)


def _run_serial(todo: Sequence[Episode], out_dir: Path, episode_fn: EpisodeFn,
                config: CampaignConfig) -> Iterator[dict[str, Any]]:
    for episode in todo:
        yield execute(episode, out_dir, episode_fn)


def _run_processes(todo: Sequence[Episode], out_dir: Path, episode_fn: EpisodeFn,
                   config: CampaignConfig) -> Iterator[dict[str, Any]]:
    # 'spawn': a forked child would inherit Drake's threads and locks mid-state.
    pool = ProcessPoolExecutor(max_workers=config.jobs,
                               mp_context=multiprocessing.get_context("spawn"),
                               initializer=share_cores, initargs=(config.jobs,))
    with sigterm_interrupts():
        try:
            # The workers start on submit: they ignore Ctrl-C, so that only this process
            # hears it (not SIGTERM: that is how they are ended).
            with signals_ignored(signal.SIGINT):
                futures = {pool.submit(execute, ep, out_dir, episode_fn): ep for ep in todo}
            for future in as_completed(futures):
                try:
                    yield future.result()
                except Exception as e:  # the worker died (e.g. a crash in native code)
                    yield failed_record(futures[future], f"{type(e).__name__}: {e}",
                                        traceback.format_exc(), math.nan)
        except BaseException:  # Ctrl-C, SIGTERM, or the consumer stopped: end them now
            with signals_ignored(*INTERRUPTS):
                # Every child, not the pool's list: a worker being started when the
                # interrupt came may not be in it yet (Python 3.14 has terminate_workers()).
                for process in multiprocessing.active_children():
                    process.terminate()
                pool.shutdown(cancel_futures=True)
            raise
    pool.shutdown()


def _run_ray(todo: Sequence[Episode], out_dir: Path, episode_fn: EpisodeFn,
             config: CampaignConfig) -> Iterator[dict[str, Any]]:
    try:
        import ray
    except ImportError:
        raise CampaignError("--backend ray needs Ray: pip install 'lrnbv-drake[ray]' "
                            "(or pip install ray), or use --backend local") from None
    started_here = not ray.is_initialized()
    if started_here:
        if config.ray_address:
            ray.init(address=config.ray_address, logging_level=logging.WARNING)
        else:
            ray.init(num_cpus=config.jobs, logging_level=logging.WARNING)
    pending: dict[Any, Episode] = {}
    try:
        # No Ray retries: a failure is recorded, and the next run of the command retries it.
        task = ray.remote(num_cpus=1, max_retries=0)(execute_on_one_thread)
        pending = {task.remote(ep, out_dir, episode_fn): ep for ep in todo}
        while pending:
            (done,), _ = ray.wait(list(pending), num_returns=1)
            episode = pending.pop(done)
            try:
                yield ray.get(done)
            except Exception as e:  # the worker or the node died
                yield failed_record(episode, f"{type(e).__name__}: {e}", traceback.format_exc(),
                                    math.nan)
    except BaseException:  # Ctrl-C, or the consumer stopped: end the running episodes now
        with signals_ignored(*INTERRUPTS):
            for ref in pending:
                ray.cancel(ref, force=True)
        raise
    finally:
        if started_here:
            ray.shutdown()


#: How a backend runs the episodes still to do: (todo, out_dir, episode_fn, config) -> records.
Backend = Callable[[Sequence[Episode], Path, EpisodeFn, CampaignConfig],
                   Iterator[dict[str, Any]]]


def backend(config: CampaignConfig) -> Backend:
    """The backend `config` asks for: serial for one job, else processes, or Ray."""
    if config.backend == "ray":
        return _run_ray
    if config.backend != "local":
        raise CampaignError(f"unknown backend '{config.backend}': expected one of "
                            f"{', '.join(BACKENDS)}")
    return _run_serial if config.jobs == 1 else _run_processes

