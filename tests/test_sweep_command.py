"""`tpo sweep`: LAR's exact curve, the learned runs on the local backend and on a real
Ray cluster (two nodes of one CPU on this machine, loopback only), and a Ray worker
killed mid-unit."""

import contextlib
import csv
import os
import shutil
import signal
import subprocess
import sys
import textwrap
from types import SimpleNamespace

import pytest

from tpo.algo import TPOConfig
from tpo.cli.main import main
from tpo.envs import grid_model, load_map
from tpo.experiments.engine import RayBackend
from tpo.experiments.runspec import DEFAULT_STEPS
from tpo.experiments.slack_sweep import SweepSpec, sweep
from tpo.graph import ObjectiveGraph
from tpo.tabular import Judge, solve_lar

# Small and quick: 4 chunks of 32 updates (of 8 envs x 32 steps) per run.
LEARNED = ["--map", "small", "--dag", "A>G", "--slack", "0,5", "--seeds", "2",
           "--steps", str(4 * 32 * 8 * 32), "--num-envs", "8", "--num-steps", "32"]
SPEC = SweepSpec(map="small", dag="A>G", xs=(0.0, 5.0), seeds=2, steps=4 * 32 * 8 * 32,
                 config=TPOConfig(num_envs=8, num_steps=32))


def rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_the_exact_curve_is_lars_at_every_slack(tmp_path, capsys):
    out = tmp_path / "sweep"
    args = ["sweep", "--exact-only", "--map", "small", "--dag", "A>M>G", "--slack", "0,5,100",
            "--edge-slack", "0,x", "--out", str(out)]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert printed.splitlines()[0].split()[:2] == ["slack", "V*_goal"]
    assert sorted(p.name for p in out.iterdir()) == [".tpo.lock", "exact.csv", "exact.json",
                                                     "exact.png", "settings.json"]
    model = grid_model(load_map("small"), gamma=0.99).model
    table = rows(out / "exact.csv")
    assert len(table) == 3 * 3
    for x in (0.0, 5.0, 100.0):
        sol = solve_lar(model, ObjectiveGraph.parse("A>M>G", [0.0, x], objectives=model.objectives),
                        relax=True)
        floors = Judge(sol).floors
        for row in (r for r in table if float(r["x"]) == x):
            name = row["objective"]
            assert row["slack"] == f"0/{x:g}"
            assert float(row["v_star"]) == pytest.approx(sol.start_values()[name], abs=1e-6)
            assert float(row["lar"]) == pytest.approx(sol.start_policy_values()[name], abs=1e-6)
            assert row["floor"] == ("" if name not in floors else f"{floors[name] + 0.0:.6f}")
            assert row["lar_feasible"] == str(sol.feasible)
    # Again on the same directory: the same curve; another problem there is refused.
    before = (out / "exact.csv").read_text()
    assert main(args) == 0 and (out / "exact.csv").read_text() == before
    capsys.readouterr()
    assert main([*args[:7], "0,1", *args[8:]]) == 2
    assert capsys.readouterr().err.strip() == (
        f"tpo: error: {out} holds a sweep with other settings (in xs: see its settings.json); "
        "choose another --out")


@pytest.mark.parametrize(("extra", "message"), [
    (["--slack", "5,1"], "--slack needs increasing finite values >= 0, e.g. 0,1,2,5,10,100"),
    (["--slack", "0,1", "--dag", "A>M>G", "--edge-slack", "x"],
     "--edge-slack has 1 entry; the DAG 'A>M>G' has 2 edges (avoid>monitor, monitor>goal)"),
    (["--slack", "0,1", "--dag", "A>M>G", "--edge-slack", "0,y"],
     "--edge-slack: give per edge 'x' (the swept value) or a finite number, with at least one "
     "'x'; got '0,y'"),
    (["--slack", "0,1", "--exact-only", "--seeds", "3"], "--exact-only trains nothing: drop "
                                                        "--seeds"),
    (["--slack", "0,1", "--exact-only", "--profile", "paper"],
     "--exact-only trains nothing: drop --profile"),
    (["--slack", "0,1", "--profile", "paper,fast"],
     "unknown profile 'fast': choose from grid, continuous, penalty, restriction, paper"),
    (["--slack", "0,1", "--address", "auto"], "--address and --storage are options of "
                                              "--backend ray"),
    (["--slack", "0,1", "--seeds", "0"], "--seeds must be from 1 to 1000, got 0"),
    (["--slack", "0,1", "--slacks-per-unit", "3"],
     "--slacks-per-unit must be from 1 to the number of slack values (2), got 3"),
    (["--slack", "0,1e31", "--exact-only"], "--slack values above 1e+30 are not supported "
     "(training is in float32; a slack that large is no constraint)"),
    (["--slack", "0,1", "--dag", "M", "--exact-only"], "the DAG 'M' has no edges: no slack "
                                                        "to sweep"),
])
def test_bad_sweeps_are_one_line_and_make_nothing(tmp_path, capsys, extra, message):
    out = tmp_path / "never"
    assert main(["sweep", "--out", str(out), *extra]) == 2
    assert capsys.readouterr().err.strip() == f"tpo: error: {message}"
    assert not out.exists()


def test_an_exact_curve_takes_gamma_and_a_damaged_settings_file_is_refused(tmp_path, capsys):
    out = tmp_path / "sweep"
    assert main(["sweep", "--exact-only", "--map", "small", "--slack", "0", "--gamma", "0.9",
                 "--out", str(out)]) == 0
    assert '"gamma": 0.9' in (out / "settings.json").read_text()
    (out / "settings.json").write_text('{"kind": "tpo sweep", "problem": [1]}')
    capsys.readouterr()
    assert main(["sweep", "--exact-only", "--map", "small", "--slack", "0", "--out",
                 str(out)]) == 2
    assert capsys.readouterr().err.strip() == (
        f"tpo: error: {out / 'settings.json'} is damaged; choose another --out")


def test_a_folder_of_the_users_is_not_a_sweep(tmp_path, capsys):
    (tmp_path / "results.csv").write_text("mine")
    assert main(["sweep", "--exact-only", "--slack", "0", "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip() == (
        f"tpo: error: {tmp_path} is not empty and holds no tpo sweep; choose another --out")
    assert (tmp_path / "results.csv").read_text() == "mine"


def test_a_continuous_sweep_takes_the_continuous_budget_unless_told(tmp_path, monkeypatch):
    """... and a run's observation: on the paper's map the cell tents (continuous) and
    the cell's one-hot (grid)."""
    import tpo.cli.main as cli

    seen = []
    monkeypatch.setattr(cli, "_learned_sweep", lambda args, out, spec, engine: seen.append(
        (spec.steps, spec.env().observation)) or SimpleNamespace(summary=str))
    for i, extra in enumerate((["--dynamics", "continuous"],
                               ["--dynamics", "continuous", "--steps", "50000"], [])):
        assert main(["sweep", "--slack", "0", *extra, "--out", str(tmp_path / str(i))]) == 0
    assert [s for s, _ in seen] == [DEFAULT_STEPS["continuous"], 50000, DEFAULT_STEPS["grid"]] \
        == [8_000_000, 50000, 1_000_000]
    assert [o for _, o in seen] == ["factored+onehot"] * 3


@pytest.fixture(scope="module")
def local_sweep(tmp_path_factory):
    """The small sweep on the local backend, through the command line."""
    out = tmp_path_factory.mktemp("local") / "sweep"
    assert main(["sweep", *LEARNED, "--out", str(out), "--quiet"]) == 0
    return out


@pytest.mark.slow
def test_a_learned_sweep_writes_results_figure_and_report_and_resumes(local_sweep, capsys):
    out = local_sweep
    table = rows(out / "results.csv")
    assert len(table) == 2 * 2 * 3  # slacks x seeds x objectives
    assert list(table[0])[:5] == ["dag", "x", "slack", "seed", "objective"]
    exact = {(r["x"], r["objective"]): r["lar"] for r in rows(out / "exact.csv")}
    for row in table:  # LAR's column is the exact curve's
        assert row["lar"] == exact[(row["x"], row["objective"])]
        assert row["lar_correct"] in ("True", "False")
        if row["strict"] == "True":
            assert row["lar_correct"] == "True"
    report = (out / "report.md").read_text()
    correct = sum(r["lar_correct"] == "True" for r in table) // 3
    assert f"LAR-correct {correct}/4" in report
    assert (out / "sweep.png").read_bytes()[:4] == b"\x89PNG"
    units = sorted((out / "units").iterdir())
    assert [p.name for p in units] == ["unit-000.json", "unit-001.json"]  # no checkpoint left
    before = {p.name: p.stat().st_mtime_ns for p in units}
    csv_before = (out / "results.csv").read_text()
    capsys.readouterr()
    assert main(["sweep", *LEARNED, "--out", str(out), "--quiet"]) == 0
    assert {p.name: p.stat().st_mtime_ns for p in (out / "units").iterdir()} == before
    assert (out / "results.csv").read_text() == csv_before
    assert main(["sweep", *LEARNED[:-1], "16", "--out", str(out), "--quiet"]) == 2
    assert "holds a sweep with other settings (in config" in capsys.readouterr().err
    # A unit's record that is not this sweep's (here: two swapped) is named, not used.
    copy = out.parent / "copy"
    shutil.copytree(out, copy)
    (copy / ".tpo.lock").unlink(missing_ok=True)
    first, second = (copy / "units" / f"unit-00{i}.json" for i in (0, 1))
    text = first.read_text()
    first.write_text(second.read_text())
    second.write_text(text)
    assert main(["sweep", *LEARNED, "--out", str(copy), "--quiet"]) == 2
    assert capsys.readouterr().err.strip().endswith(
        "unit-000.json is not this sweep's unit of slacks 0; delete it to run the unit again")


CLUSTER = textwrap.dedent("""
    import sys
    from ray.cluster_utils import Cluster
    cluster = Cluster(initialize_head=True, head_node_args={
        "num_cpus": 1, "include_dashboard": False, "object_store_memory": 100 * 2**20})
    cluster.add_node(num_cpus=1, object_store_memory=100 * 2**20)
    cluster.wait_for_nodes()
    print(cluster.address, flush=True)
    sys.stdin.read()  # until the test closes it
    cluster.shutdown()
""")


@pytest.fixture
def ray_cluster(monkeypatch):
    """Two Ray nodes of one CPU each on 127.0.0.1, in their own process group.

    Not ``ray start``: a node joining with ``ray start --address 127.0.0.1:PORT``
    takes the host's address instead and listens on every interface
    (ray-project/ray#59110); Ray's own multi-node test cluster keeps every node and
    server on the loopback address when Ray is told the cluster is local only."""
    import ray._private.ray_constants as constants

    env = {**os.environ, "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0"}  # local only: 127.0.0.1
    monkeypatch.setattr(constants, "ENABLE_RAY_CLUSTER", False)  # the driver's side of it
    proc = subprocess.Popen([sys.executable, "-c", CLUSTER], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, env=env, text=True, start_new_session=True)
    try:
        address = proc.stdout.readline().strip()
        assert address.startswith("127.0.0.1:"), address
        yield address
    finally:
        proc.stdin.close()
        try:
            proc.wait(timeout=60)
        finally:
            with contextlib.suppress(ProcessLookupError):  # anything of the cluster still there
                os.killpg(proc.pid, signal.SIGKILL)


@pytest.mark.slow
def test_a_sweep_on_a_ray_cluster_survives_a_killed_worker_to_the_same_results(
        local_sweep, ray_cluster, tmp_path):
    """SIGKILL of the Ray worker running a unit, after its first checkpoint: Ray runs
    the unit again, it resumes from that checkpoint, and the results are the local
    backend's, byte for byte; the other unit ran once."""
    victim, killed = "unit-001", []

    def kill_after_first_checkpoint(tracker):
        attempts = tracker.attempts.get(victim, [])
        if not killed and len(attempts) == 1 and 0 < tracker.fractions[victim] < 1:
            os.kill(attempts[0][0], signal.SIGKILL)
            killed.append(tracker.fractions[victim])

    out = tmp_path / "ray"
    attempts = {}

    def watch(tracker):
        kill_after_first_checkpoint(tracker)
        attempts.update({k: [list(a) for a in v] for k, v in tracker.attempts.items()})

    sweep(out, SPEC, RayBackend(ray_cluster, every=0.0), progress=watch)
    assert killed, "the victim finished before it could be killed"
    assert len(attempts[victim]) == 2 and len(attempts["unit-000"]) == 1
    first, second = attempts[victim]
    assert first[0] != second[0]  # another worker process
    # Resumed from the checkpoint of the chunks done (the victim may have finished one
    # more between the report the kill followed and the kill), not from the start.
    assert killed[0] <= second[1] < 1
    assert (out / "results.csv").read_text() == (local_sweep / "results.csv").read_text()
    assert sorted(p.name for p in (out / "units").iterdir()) == ["unit-000.json",
                                                                 "unit-001.json"]
