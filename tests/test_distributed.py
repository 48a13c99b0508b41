"""Monte Carlo walks on Dask: the same table as in this process, failures named and re-runnable alone.

The clusters here run their workers as threads of the test process
(``processes=False``): starting worker processes costs seconds per worker on a
loaded 2-core machine, and the result of a walk does not depend on the process
it runs in (``tests/test_cli.py`` runs the command line on worker processes).
"""

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from dtmbnav.evaluation import evaluate as ev
from dtmbnav.cli import EXIT_NO_RESULT, EXIT_OK, main
from dtmbnav.evaluation.distributed import IN_PROCESS, ClusterConfig, Task, run_tasks
from fusion.run import FusionConfig

TINY = str(Path(__file__).parent / "data" / "tiny-walk.toml")
THREADS_2 = ClusterConfig(workers=2, processes=False)
R0 = ev.REPORTING_SEEDS.start  # the first reporting index: a walk of the tiny scenario (seed 7) runs 7000 + R0


def square_or_fail(x: int) -> int:
    if x == 3:
        raise ValueError(f"cannot take {x}")
    return x * x


@pytest.mark.parametrize("cluster", [IN_PROCESS, THREADS_2], ids=["in-process", "2 dask workers"])
def test_results_in_task_order_and_failures_named(cluster):
    tasks = [Task(f"x={x}", square_or_fail, (x,)) for x in range(6)]
    outcome = run_tasks(tasks, cluster, progress=False)
    assert outcome.results == [0, 1, 4, None, 16, 25]
    assert [(f.index, f.label) for f in outcome.failures] == [(3, "x=3")]
    assert outcome.failures[0].error == "ValueError: cannot take 3"


def blas_threads() -> list[int]:
    return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]


def blas_product(seed: int) -> tuple[str, list[int]]:
    """A complex64 matrix product's bytes (OpenBLAS rounds it differently for one and two threads), and the BLAS
    thread counts it ran with."""
    rng = np.random.default_rng(seed)
    a, b = ((rng.standard_normal(shape) + 1j * rng.standard_normal(shape)).astype(np.complex64)
            for shape in ((64, 600), (600, 420)))
    return hashlib.sha256((a @ b).tobytes()).hexdigest(), blas_threads()


@pytest.mark.parametrize("cluster", [IN_PROCESS, THREADS_2], ids=["in-process", "2 dask workers"])
def test_every_task_runs_with_one_blas_thread_and_this_process_keeps_its_own(cluster):
    before = blas_threads()
    digest, threads = run_tasks([Task("blas", blas_product, (0,))], cluster, progress=False).results[0]
    assert threads and set(threads) == {1}
    with threadpool_limits(limits=1):
        assert digest == blas_product(0)[0]
    assert blas_threads() == before


def test_two_seed_evaluate_on_a_two_worker_local_cluster_matches_in_process():
    kwargs = {"seeds": 2, "filters": ("pf", "ukf"), "config": FusionConfig(n_particles=300)}
    here = ev.evaluate_many([TINY], **kwargs)
    dask = ev.evaluate_many([TINY], cluster=THREADS_2, **kwargs)
    assert not here.failures and not dask.failures
    assert dask.rows == here.rows  # every number bit for bit
    assert ev.format_table(dask.rows) == ev.format_table(here.rows)


def test_a_walk_depends_on_its_seed_only():
    kwargs = {"filters": ("ukf",), "config": FusionConfig(n_particles=300)}
    both = ev.run_seeds(TINY, seeds=2, **kwargs)[1]
    second = ev.run_seeds(TINY, seeds=1, first_seed=ev.REPORTING_SEEDS.start + 1, **kwargs)[1]
    assert second[0].errors_m["ukf"].tolist() == both[1].errors_m["ukf"].tolist()


def test_a_failed_walk_is_reported_with_its_seed_and_the_command_that_reruns_it(tmp_path, capsys):
    # A custom clock without its offset and drift loads, but every walk of it fails when the clock is drawn.
    bad = tmp_path / "bad.toml"
    bad.write_text(Path(TINY).read_text().replace('sample_format = "ci8"', 'sample_format = "ci8"\n'
                                                   'clock = { preset = "custom" }'))
    argv = ["-q", "evaluate", str(bad), "--seeds", "1", "--filters", "ukf", "--no-vary-geometry", "--workers", "0"]
    assert main(argv) == EXIT_NO_RESULT
    err = capsys.readouterr().err
    assert f"tiny-walk walk k=0 (seed {7000 + R0}) failed: ValueError: scenario receiver.clock: preset 'custom'" in err
    rerun = err.split("re-run it alone: ")[1].splitlines()[0]
    assert rerun.startswith(f"dtmbnav evaluate {bad} --seeds 1 --first-seed {R0} ")
    assert main(["-q", *rerun.split()[1:]]) == EXIT_NO_RESULT
    assert f"(seed {7000 + R0}) failed:" in capsys.readouterr().err


def test_evaluate_command_on_worker_processes(tmp_path, capsys):
    argv = ["-q", "evaluate", TINY, "--seeds", "2", "--filters", "ukf", "--workers"]
    assert main([*argv, "2", "--walks", str(tmp_path / "workers.jsonl")]) == EXIT_OK
    on_workers = capsys.readouterr().out
    assert main([*argv, "0", "--walks", str(tmp_path / "here.jsonl"), "--json", str(tmp_path / "table.json")]) \
        == EXIT_OK
    assert capsys.readouterr().out == on_workers
    assert f"Monte Carlo indices {R0}-{R0 + 1} (reporting range" in on_workers
    # --walks: a line per walk as it finishes (workers finish in any order), the walks the table averages.
    walks = {name: sorted((json.loads(line) for line in (tmp_path / name).read_text().splitlines()),
                          key=lambda r: r["k"]) for name in ("workers.jsonl", "here.jsonl")}
    assert walks["workers.jsonl"] == walks["here.jsonl"]
    here = walks["here.jsonl"]
    assert [(r["k"], r["seed"], r["first_seed"], r["level"]) for r in here] == [(0, 7000 + R0, R0, "obs"),
                                                                              (1, 7001 + R0, R0, "obs")]
    table = {r["filter"]: r for r in json.loads((tmp_path / "table.json").read_text())}
    for name in ("pdr", "pdr@fix", "ukf"):
        assert table[name]["p95_m"] == pytest.approx(sum(r["p95_m"][name] for r in here) / 2, rel=1e-12)
    assert table["ukf"]["worst_vs_fix"] == pytest.approx(
        max(r["p95_m"]["ukf"] / r["p95_m"]["pdr@fix"] for r in here) - 1.0, rel=1e-12)


def test_run_over_several_capture_sets(tmp_path, capsys):
    sets = []
    for seed in (1, 2):
        folder = tmp_path / f"set{seed}"
        assert main(["-q", "simulate", TINY, "--seconds", "0.4", "--seed", str(seed), "-o", str(folder)]) == EXIT_OK
        sets.append(folder)
    empty = tmp_path / "empty"
    empty.mkdir()
    out = tmp_path / "out"
    assert main(["-q", "run", *map(str, sets), str(empty), "-o", str(out), "--workers", "0"]) == EXIT_NO_RESULT
    captured = capsys.readouterr()
    assert captured.out.count("capture  ") == 2
    for folder in sets:
        assert (out / folder.name / "receiver.h5").is_file()
    assert f"dtmbnav run: {empty} failed: ValueError: {empty}: expected exactly one capture" in captured.err
    assert f"re-run it alone: dtmbnav run {empty} -o {out / 'empty'}" in captured.err
