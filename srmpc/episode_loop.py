"""Closed-loop evaluation: run a controller for episodes of the scenario, collect the metrics.

Episode i of an evaluation with seed s is ``env.reset(seed=s + i)`` after ``controller.reset()``, so it is
the same episode whichever process runs it: :func:`evaluate` runs the episodes in this process,
:func:`evaluate_in_workers` shards them over worker processes and hands them back in episode order.
"""

from __future__ import annotations

import contextlib
import itertools
import multiprocessing
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field

import gymnasium

from srmpc.controllers import Controller
from srmpc.metrics import EpisodeMetrics, episode_metrics


@dataclass(frozen=True)
class EpisodeRecord:
    """One evaluated episode."""

    episode: int
    seed: int
    metrics: EpisodeMetrics
    termination: str
    """"collision", "offroad" or "truncated"."""
    outcomes: dict[str, int] = field(default_factory=dict)
    """Steps per controller outcome (e.g. a planner's solved / fallback counts)."""


def run_episode(env: gymnasium.Env, controller: Controller, seed: int) -> tuple[EpisodeMetrics, str, dict[str, int]]:
    """One episode from ``env.reset(seed=seed)`` until termination or truncation."""
    observation, _ = env.reset(seed=seed)
    controller.reset()
    scenario = env.unwrapped
    reward_primes, event_costs, vxs, si_costs = [], [], [], []
    while True:
        observation, _, terminated, truncated, info = env.step(controller.act(observation, scenario.measurement))
        reward_primes.append(info["reward_prime"])
        event_costs.append(info["event_cost"])
        vxs.append(info["vx"])
        si_costs.append(info["cost"])
        if terminated or truncated:
            reason = info["termination"] if terminated else "truncated"
            metrics = episode_metrics(reward_primes, event_costs, vxs, si_costs)
            return metrics, reason, controller.episode_outcomes()


def evaluate_episode(env: gymnasium.Env, controller: Controller, episode: int, seed: int) -> EpisodeRecord:
    """Episode ``episode`` of an evaluation seeded ``seed``: from ``env.reset(seed=seed + episode)``."""
    metrics, reason, outcomes = run_episode(env, controller, seed + episode)
    return EpisodeRecord(episode, seed + episode, metrics, reason, outcomes)


def evaluate(
    env: gymnasium.Env,
    controller: Controller,
    episodes: int,
    seed: int,
    on_episode: Callable[[EpisodeRecord], None] | None = None,
    first_episode: int = 0,
) -> list[EpisodeRecord]:
    """Episodes ``first_episode .. episodes-1``, episode i seeded with ``seed + i``."""
    records = []
    for episode in range(first_episode, episodes):
        record = evaluate_episode(env, controller, episode, seed)
        records.append(record)
        if on_episode is not None:
            on_episode(record)
    return records


# ------------------------------------------------------------------------------------------ workers
WORKER_START_METHOD = "spawn"
"""Workers start as fresh interpreters: forking a process that holds numba's or torch's thread pools
can deadlock."""
SINGLE_THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")
"""Set to 1 in the workers' environment: the workers are the parallelism, one core each."""

IN_FLIGHT_PER_WORKER = 2
"""Episodes handed to the pool per worker at a time (one running, one queued), so a worker never waits
for the next and an interrupted run has little to cancel."""

SIGNAL_POLL_S = 0.2
"""Longest wait for a finished episode before a held-back signal is acted on [s]."""

_worker: tuple[gymnasium.Env, Controller] | None = None
"""The worker process's own scenario and controller, built once by :func:`_start_worker`."""


def _start_worker(setup: Callable[[], tuple[gymnasium.Env, Controller]]) -> None:
    global _worker
    # The parent stops the workers (terminate) on Ctrl-C, SIGTERM or a submitit preemption signal (USR2);
    # a worker that caught the terminal's SIGINT or SLURM's USR2 itself would die mid-episode first.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGUSR2, signal.SIG_IGN)
    _worker = setup()
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(1)


def _worker_episode(episode: int, seed: int) -> EpisodeRecord:
    assert _worker is not None, "worker not started"
    env, controller = _worker
    return evaluate_episode(env, controller, episode, seed)


@contextlib.contextmanager
def _single_threaded_children() -> Iterator[None]:
    saved = {name: os.environ.get(name) for name in SINGLE_THREAD_VARIABLES}
    os.environ.update({name: "1" for name in SINGLE_THREAD_VARIABLES})
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


@contextlib.contextmanager
def _signals_at_safe_points() -> Iterator[Callable[[], None]]:
    """Hold SIGINT, SIGTERM and SIGUSR2 back until the yielded ``deliver()`` is called (and at exit).

    Their handlers raise (KeyboardInterrupt; SystemExit from ``python -m srmpc``'s SIGTERM handler or
    submitit's preemption handler). Raised at an arbitrary point of ``concurrent.futures``, that can
    leave a future's lock held and deadlock the pool's shutdown; ``deliver()`` runs the handler where
    no lock is held. A signal whose action is the default (terminate) raises SystemExit(128 + signal);
    an ignored one stays ignored."""
    caught: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield lambda: None
        return
    previous = {number: signal.getsignal(number) for number in (signal.SIGINT, signal.SIGTERM, signal.SIGUSR2)}

    def deliver() -> None:
        if caught:
            number = caught.pop(0)
            handler = previous[number]
            if not callable(handler):  # SIG_DFL: the process would have ended
                raise SystemExit(128 + number)
            handler(number, None)

    for number, handler in previous.items():
        if handler not in (signal.SIG_IGN, None):
            signal.signal(number, lambda number, frame: caught.append(number))
    try:
        yield deliver
    finally:
        for number, handler in previous.items():
            if handler not in (signal.SIG_IGN, None):
                signal.signal(number, handler)
    deliver()


def _stop_workers(executor: ProcessPoolExecutor) -> None:
    """End every worker now, mid-episode included (``ProcessPoolExecutor.shutdown`` would wait for them)."""
    for process in list((getattr(executor, "_processes", None) or {}).values()):
        if process.is_alive():
            process.terminate()
    executor.shutdown(wait=True, cancel_futures=True)


def evaluate_in_workers(
    setup: Callable[[], tuple[gymnasium.Env, Controller]],
    episodes: int,
    seed: int,
    workers: int,
    on_episode: Callable[[EpisodeRecord], None] | None = None,
    first_episode: int = 0,
) -> list[EpisodeRecord]:
    """:func:`evaluate`'s episodes, run by ``workers`` processes; the same records, in the same order.

    Each worker calls the picklable ``setup()`` once for its own scenario and controller, then runs the
    episodes it is handed (in episode order, as workers free up) with :func:`evaluate_episode`. Episodes
    that finish ahead of an earlier one wait in this process, so ``on_episode`` sees episode
    ``first_episode``, then ``first_episode + 1``, ...: whatever it wrote is always the contiguous prefix
    of finished episodes. An exception in an episode, or any exception here (SystemExit from a SIGTERM
    handler included), terminates the workers; the episodes already handed to ``on_episode`` stay done.
    """
    records: list[EpisodeRecord] = []
    ahead: dict[int, EpisodeRecord] = {}
    next_episode = first_episode
    context = multiprocessing.get_context(WORKER_START_METHOD)
    with _signals_at_safe_points() as deliver_signals, _single_threaded_children():
        executor = ProcessPoolExecutor(workers, mp_context=context, initializer=_start_worker, initargs=(setup,))
        try:
            queue = iter(range(first_episode, episodes))
            pending: set[Future] = set()
            while True:
                for episode in itertools.islice(queue, IN_FLIGHT_PER_WORKER * workers - len(pending)):
                    pending.add(executor.submit(_worker_episode, episode, seed))
                if not pending:
                    break
                done, pending = wait(pending, timeout=SIGNAL_POLL_S, return_when=FIRST_COMPLETED)
                for future in done:
                    record = future.result()
                    ahead[record.episode] = record
                while next_episode in ahead:
                    record = ahead.pop(next_episode)
                    records.append(record)
                    if on_episode is not None:
                        on_episode(record)
                    next_episode += 1
                deliver_signals()
        except BaseException:
            _stop_workers(executor)
            raise
        executor.shutdown(wait=True)
    return records
