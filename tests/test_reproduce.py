"""`tpo reproduce`: the sweep runner, its resume, and the quick end-to-end run."""

import json

import numpy as np
import pytest
from flax import serialization

from tpo.algo import TPOConfig
from tpo.cli.main import main
from tpo.envs import grid_model, load_map
from tpo.envs.grid import GridNav
from tpo.errors import TPOError
from tpo.experiments.paper import PANELS, direction
from tpo.experiments.sweep import run_sweep
from tpo.graph import ObjectiveGraph
from tpo.tabular import solve_lar

TINY = TPOConfig(num_envs=8, num_steps=32)


def test_panels_sweep_the_edges_the_paper_names():
    slack = {p.name: p.slack(7.0, 2) for p in PANELS}
    assert slack == {"a": [7.0, 7.0], "b": [0.0, 7.0], "c": [7.0, 0.0], "d": [7.0, 7.0]}
    assert [p.dag for p in PANELS] == ["M>A>G", "A>M>G", "G>M>A", "A>G, M>G"]


def test_direction_is_flat_within_one_percent_of_the_scale():
    assert direction(-100.0, -7.7, 100.0) == "up"
    assert direction(88.6, 0.0, 88.6) == "down"
    assert direction(-100.0, -99.2, 100.0) == "flat"
    assert direction(0.0, 0.4, 1.0) == "flat"


class Interrupt(Exception):
    pass


def test_a_killed_sweep_resumes_from_its_checkpoint_to_the_same_result(tmp_path):
    env = GridNav(load_map("small"), random_start=True)
    args = (env, "A>G", [[0.0], [5.0]], [0, 1], TINY, 8 * 32 * 8)
    whole = run_sweep(*args, chunk_updates=2)

    def stop_after_two_chunks(done, total):
        if done == 4:
            raise Interrupt

    ckpt = tmp_path / "sweep.ckpt"
    with pytest.raises(Interrupt):
        run_sweep(*args, chunk_updates=2, checkpoint=ckpt, checkpoint_seconds=0.0,
                  progress=stop_after_two_chunks)
    seen = []
    resumed = run_sweep(*args, chunk_updates=2, checkpoint=ckpt,
                        progress=lambda done, total: seen.append(done))
    assert seen == [6, 8]  # started after update 4
    np.testing.assert_array_equal(resumed.exact, whole.exact)
    np.testing.assert_array_equal(resumed.policies, whole.policies)
    # A checkpoint of another version (tpo 0.1's had no format) is named, not misread.
    ckpt.write_bytes(serialization.msgpack_serialize({"done": 4, "states": {}}))
    with pytest.raises(TPOError, match=r"written by another version of tpo \(format None; "
                                       r"this version reads \d+\); delete it"):
        run_sweep(*args, chunk_updates=2, checkpoint=ckpt)


@pytest.mark.slow
def test_quick_reproduction_writes_figures_tables_and_report_and_resumes(tmp_path, capsys):
    out = tmp_path / "repro"
    assert main(["reproduce", "--quick", "--out", str(out), "--quiet"]) == 0
    names = {p.name for p in out.iterdir()}
    assert {"figure2.png", "figure3.png", "results.csv", "results.json", "report.md",
            "settings.json", "panels"} <= names
    for png in ("figure2.png", "figure3.png"):
        assert (out / png).read_bytes()[:4] == b"\x89PNG"
    rows = (out / "results.csv").read_text().strip().splitlines()
    assert len(rows) == 1 + 5 * 2 * 2 * 3  # (4 panels + figure 3) x 2 slacks x 2 seeds x 3
    assert rows[0].endswith(",lar_feasible,lar_correct,strict,same_values")
    report = (out / "report.md").read_text()
    assert report.count("| (a) M>A>G |") == 3 and report.count("| (d) A>G, M>G |") == 3
    # LAR's line in the results is the exact solver's, e.g. panel (b) at slack (0, 100).
    record = json.loads((out / "results.json").read_text())["panels"]["b"]
    grid = grid_model(load_map("small"), gamma=0.99)
    lar = solve_lar(grid.model, ObjectiveGraph.parse("A>M>G", [0, 100],
                                                     objectives=grid.model.objectives),
                    relax=True).start_policy_values()
    assert record["lar"][1] == pytest.approx([lar[n] for n in record["objectives"]])
    # Every learned value is an exact value of some policy: within the objectives' range.
    exact = np.array(record["exact"])
    assert exact.shape == (2, 2, 3) and (exact <= 100).all() and (exact >= -200).all()
    # A strict run is LAR-correct (strict adds a condition).
    correct, strict = np.array(record["lar_correct"]), np.array(record["strict"])
    assert correct.shape == strict.shape == (2, 2) and not (strict & ~correct).any()
    # A second run skips every finished panel; other settings are refused.
    before = {p.name: p.stat().st_mtime_ns for p in (out / "panels").iterdir()}
    assert main(["reproduce", "--quick", "--out", str(out), "--quiet"]) == 0
    assert {p.name: p.stat().st_mtime_ns for p in (out / "panels").iterdir()} == before
    capsys.readouterr()
    assert main(["reproduce", "--quick", "--seeds", "3", "--out", str(out), "--quiet"]) == 2
    assert "holds a reproduction with other settings" in capsys.readouterr().err
    # the other form of the constraint is another reproduction, in its own directory
    assert main(["reproduce", "--quick", "--constraint", "restriction", "--out", str(out),
                 "--quiet"]) == 2
    assert "'constraint': 'penalty'" in capsys.readouterr().err
    assert json.loads((out / "settings.json").read_text())["constraint"] == "penalty"
