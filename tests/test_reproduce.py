"""`tpo reproduce`: the sweep runner, its resume, and the quick end-to-end run."""

import json
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import pytest
from flax import serialization

from tpo.algo import TPOConfig
from tpo.cli.main import main
from tpo.envs import ContinuousNav, grid_model, load_map
from tpo.envs.continuous_model import continuous_model
from tpo.envs.grid import GridNav
from tpo.errors import TPOError
from tpo.experiments.engine import Backend, FileLink
from tpo.experiments.paper import (
    CONTINUOUS_PANELS,
    CONTINUOUS_SHARES,
    FIGURE3,
    FORMS,
    PANELS,
    Settings,
    direction,
)
from tpo.experiments.report import budget_text, merge_records, pick_runs, results_csv, verdict_table
from tpo.experiments.reproduce import check_settings, learner, reproduce, saved_settings
from tpo.experiments.sweep import run_sweep
from tpo.graph import ObjectiveGraph
from tpo.tabular import solve_lar

TINY = TPOConfig(num_envs=8, num_steps=32)


def test_the_reproduction_runs_the_default_learner_and_can_run_every_form():
    assert Settings().forms == Settings.quick().forms == ("penalty",)
    settings = Settings()
    assert learner("penalty", settings) == TPOConfig()  # the grid's default learner
    assert {f: learner(f, settings).constraint for f in FORMS} == {
        "penalty": "penalty", "restriction": "restriction", "paper": "penalty"}
    # The paper's TPO as printed: Eq. 10's penalized advantage on every constraint
    # rectified, no margin, no tie-break, the leaf's policy the answer; the rest the
    # default learner's.
    paper = learner("paper", settings)
    assert (paper.advantage, paper.telescope, paper.margin, paper.tie_break,
            paper.select) == ("penalized", "off", 0.0, 0.0, False)
    assert replace(paper, advantage="traced", telescope="roots", margin=0.15,
                   tie_break=0.1, select=True) == TPOConfig()
    assert learner("paper", replace(settings, completion=True)).completion


def test_each_panel_trains_its_share_of_the_budget():
    settings = Settings()
    steps = {p.name: settings.steps_of(p) for p, _ in settings.panels()}
    assert steps == {"a": 500_000, "b": 1_000_000, "c": 750_000, "d": 500_000,
                     "fig3": 750_000}
    assert budget_text(settings) == "1,000,000 in (b), 750,000 in (c) (fig3), 500,000 in (a) (d)"
    even = replace(settings, steps=900, shares={})
    assert budget_text(even) == "900" and {even.steps_of(p) for p, _ in even.panels()} == {900}
    # The continuous robot's panels: every DAG and Figure 3 at slack 0 and 100, on their
    # own budget, in the penalty form, named apart from the grid's.
    assert settings.continuous_panels() == []  # tpo reproduce --continuous ACTION adds them
    settings = replace(settings, continuous=CONTINUOUS_PANELS)
    cont = settings.continuous_panels()
    assert [(p.key, xs) for p, xs in cont] == [
        (f"{n}-velocity", [0.0, 100.0]) for n in ("a", "b", "c", "d", "fig3")]
    assert {p.name: settings.steps_of(p) for p, _ in cont} == {
        "a": 1_000_000, "b": 2_000_000, "c": 1_250_000, "d": 375_000, "fig3": 1_000_000}
    assert budget_text(settings, continuous=True) == \
        "2,000,000 in (b), 1,250,000 in (c), 1,000,000 in (a) (fig3), 375,000 in (d)"
    assert Settings.quick().steps_of(cont[1][0]) == 600_000  # (b): the whole of --quick's
    assert [name for name, *_ in settings.jobs()][-5:] == [
        f"penalty-{n}-velocity" for n in ("a", "b", "c", "d", "fig3")]
    assert [p.key for p, _ in replace(settings, action="heading",
                                      continuous=("fig3",)).continuous_panels()] == [
        "fig3-heading"]
    assert [p.key for p, _ in Settings.quick().continuous_panels()] == ["a-velocity"]


def test_a_reproduction_without_continuous_panels_resumes_whatever_its_continuous_shares(
        tmp_path):
    # The committed run's settings, as written before the field or with another
    # version's shares: no continuous panels, so today's shares change nothing and it
    # resumes; with continuous panels its units trained on its own shares (the whole
    # --continuous-steps before the field), which keep it apart.
    saved = json.loads((Path(__file__).parent.parent / "docs" / "reproduce"
                        / "settings.json").read_text())
    assert saved["continuous_shares"] == CONTINUOUS_SHARES
    old = {k: v for k, v in saved.items() if k != "continuous_shares"}
    other = {**saved, "continuous_shares": {**CONTINUOUS_SHARES, "c": 1.0}}
    for written in (old, other):
        (tmp_path / "settings.json").write_text(json.dumps(written))
        assert saved_settings(tmp_path / "settings.json") == saved
    (tmp_path / "settings.json").write_text(json.dumps({**old, "continuous": ["a"]}))
    assert "continuous_shares" not in saved_settings(tmp_path / "settings.json")
    (tmp_path / "settings.json").write_text(json.dumps({**other, "continuous": ["a"]}))
    assert saved_settings(tmp_path / "settings.json")["continuous_shares"]["c"] == 1.0


def test_units_train_every_run_once_cut_evenly_costliest_first():
    settings = Settings()
    units = settings.units()
    cost = [len(runs) * settings.steps_of(runs[0][0]) for *_, runs in units]
    assert cost == sorted(cost, reverse=True)
    assert [u[0] for u in units[:2]] == ["penalty-b.1", "penalty-b.2"]
    assert {name for name, *_ in units} == {
        *(f"penalty-{p}.{i}" for p in "abcd" for i in (1, 2)), "penalty-fig3"}
    # Figure 3 trains longer than panel (a): its slack (0, 0) is its own run.
    assert [[x for _, x in runs] for name, *_, runs in units if name == "penalty-fig3"] == [
        [0.0, 100.0]]
    sources = settings.sources()
    assert sources["penalty-fig3"] == [("penalty-fig3", [0, 1], True)]
    assert sources["penalty-b"] == [("penalty-b.1", [0, 1, 2, 3], True),
                                    ("penalty-b.2", [0, 1, 2, 3], True)]
    for job, form, panel, xs in settings.jobs():  # every run of a job, in order, is trained
        found = {name: runs for name, *_, runs in units}
        assert [found[u][i] for u, ids, _ in sources[job] for i in ids] == [(panel, x) for x in xs]
        assert {settings.run(form, panel, x) for x in xs} <= {
            settings.run(f, p, x) for _, f, runs in units for p, x in runs}
    # Two workers taking units in this order end within half a unit of each other.
    loads = [0.0, 0.0]
    for c in cost:
        loads[loads.index(min(loads))] += c
    assert max(loads) - min(loads) <= max(cost) / 2
    # The same budget for (a) and Figure 3: Figure 3's slack (0, 0) is panel (a)'s first
    # run, trained once, by (a)'s unit, and its (100, 0) trains in (a)'s program, after
    # (a)'s eight.
    shared = replace(settings, shares={**settings.shares, "fig3": settings.shares["a"]})
    assert "penalty-fig3" not in {name for name, *_ in shared.units()}
    assert [[(p.name, x) for p, x in runs] for name, _, runs in shared.units()
            if name == "penalty-a.3"] == [[("fig3", 100.0)]]
    assert shared.sources()["penalty-fig3"] == [("penalty-a.1", [0], False),
                                                ("penalty-a.3", [0], False)]
    # So with the continuous robot's panels: Figure 3's (100, 0) beside panel (a)'s.
    robot = replace(settings, continuous=CONTINUOUS_PANELS)
    assert [[(p.key, x) for p, x in runs] for name, _, runs in robot.units()
            if name == "penalty-a-velocity"] == [
        [("a-velocity", 0.0), ("a-velocity", 100.0), ("fig3-velocity", 100.0)]]
    assert robot.sources()["penalty-fig3-velocity"] == [("penalty-a-velocity", [0, 2], False)]
    assert len(robot.units()) == len(units) + 4


def test_a_panels_record_is_its_runs_along_the_slack_axis_wherever_they_trained():
    first = {"x": [0.0, 1.0], "lar_correct": [[True], [False]], "paths": [[[1]], [[2]]],
             "objectives": ["goal"], "seconds": 2.0, "runs": 2}
    second = {**first, "x": [5.0], "lar_correct": [[False]], "paths": [[[3]]],
              "seconds": 3.0, "runs": 1}
    assert merge_records([first, second]) == {
        "x": [0.0, 1.0, 5.0], "lar_correct": [[True], [False], [False]],
        "paths": [[[1]], [[2]], [[3]]], "objectives": ["goal"], "seconds": 5.0, "runs": 3}
    # A run borrowed from another panel's unit costs this panel nothing.
    assert pick_runs(first, [1], own=False) == {
        "x": [1.0], "lar_correct": [[False]], "paths": [[[2]]], "objectives": ["goal"],
        "seconds": 0, "runs": 0}
    assert pick_runs(first, [0, 1], own=True) == first


def test_panels_sweep_the_edges_the_paper_names():
    slack = {p.name: p.slack(7.0) for p in PANELS}
    assert slack == {"a": [7.0, 7.0], "b": [0.0, 7.0], "c": [7.0, 0.0], "d": [7.0, 7.0]}
    assert [p.dag for p in PANELS] == ["M>A>G", "A>M>G", "G>M>A", "A>G, M>G"]


def test_direction_is_flat_within_one_percent_of_the_scale():
    assert direction(-100.0, -7.7, 100.0) == "up"
    assert direction(88.6, 0.0, 88.6) == "down"
    assert direction(-100.0, -99.2, 100.0) == "flat"
    assert direction(0.0, 0.4, 1.0) == "flat"


def _record(dag, correct, feasible):
    """A panel record of 2 slacks x 2 seeds whose verdicts are ``correct`` (also strict;
    same values on seed 0 only)."""
    return {"panel": {"dag": dag}, "x": [0.0, 5.0], "slacks": [[0.0], [5.0]], "seeds": [0, 1],
            "objectives": ["goal"], "exact": [[[-1.0], [-2.0]], [[-3.0], [-4.0]]],
            "mc": [[[0.0], [0.0]], [[0.0], [0.0]]], "lar": [[-1.0], [-3.0]],
            "feasible": feasible, "lar_correct": correct, "strict": correct,
            "same_values": [[True, False], [True, False]]}


def test_verdict_table_and_csv_count_each_form_over_its_feasible_runs():
    records = {"penalty": {"a": _record("A>G", [[True, True], [True, False]], [True, True]),
                           "b": _record("G>A", [[False, False], [True, True]], [False, True])},
               "restriction": {"a": _record("A>G", [[False, True], [False, False]],
                                            [True, True]),
                               "b": _record("G>A", [[True, True], [False, False]],
                                            [False, True])}}
    rows = verdict_table(records).splitlines()
    assert rows[2:] == ["| (a) A>G | 3/4 / 3/4 / 2/4 | 1/4 / 1/4 / 2/4 |",
                        "| (b) G>A | 2/2 / 2/2 / 1/2 | 0/2 / 0/2 / 1/2 |",
                        "| **all feasible runs** | 5/6 / 5/6 / 3/6 | 1/6 / 1/6 / 3/6 |"]
    continuous = {"c-velocity": _record("G>A", [[True, False], [True, True]], [True, True])}
    csv_rows = results_csv(records, continuous).splitlines()
    assert len(csv_rows) == 1 + 2 * 2 * 2 * 2 + 2 * 2  # forms x panels x slacks x seeds
    assert csv_rows[1] == ("penalty,a,A>G,0.0,0,0,goal,-1.000000,0.000000,-1.000000,"
                           "True,True,True,True")
    assert csv_rows[-5].startswith("restriction,b,G>A,5.0,5,1,goal,-4.000000,")
    assert csv_rows[-1].startswith("penalty,c-velocity,G>A,5.0,5,1,goal,-4.000000,")
    assert verdict_table({"penalty": continuous}).splitlines()[2:] == [
        "| (c-velocity) G>A | 3/4 / 3/4 / 2/4 |", "| **all feasible runs** | 3/4 / 3/4 / 2/4 |"]


@pytest.mark.parametrize(("change", "message"), [
    ({"continuous": ("e",)}, r"continuous must name panels from a, b, c, d, fig3, got \('e',\)"),
    ({"continuous": "a"}, r"continuous must name panels from a, b, c, d, fig3, got 'a'"),
    ({"action": "jump"}, r"action must be one of velocity, heading, got 'jump'"),
    ({"continuous_steps": 10}, r"panel \(a-velocity\) trains 5 steps per run \(its share "
                               r"of 10, --continuous-steps\): total_timesteps must be an "
                               r"integer")])
def test_bad_continuous_settings_are_one_line(change, message):
    with pytest.raises(TPOError, match=f"^{message}"):
        check_settings(replace(Settings.quick(), **change))


@pytest.mark.parametrize("forms", [(), ("penalty", "penalty"), ("bogus",), "penalty"])
def test_bad_forms_are_one_line(forms):
    with pytest.raises(TPOError, match=r"^forms must be distinct names from "
                                       r"penalty, restriction, paper, got .*$"):
        check_settings(Settings(forms=forms))


@pytest.mark.parametrize(("flag", "forms"), [
    ([], ("penalty",)), (["--constraint", "paper"], ("paper",)),
    (["--constraint", "both"], ("penalty", "restriction")),
    (["--constraint", "all"], ("penalty", "restriction", "paper"))])
def test_the_constraint_flag_picks_the_forms(tmp_path, monkeypatch, flag, forms):
    ran = []

    class Done:
        def summary(self):
            return "done"

    monkeypatch.setattr("tpo.experiments.reproduce.reproduce",
                        lambda out, settings, *a: ran.append(settings.forms) or Done())
    assert main(["reproduce", "--quick", *flag, "--out", str(tmp_path / "r"),
                 "--quiet"]) == 0
    assert ran == [forms]


def test_a_half_finished_reproduction_runs_only_what_is_missing(tmp_path):
    """Finished panels are found by form and panel; the rest is queued, and the
    progress starts where the directory is (Figure 3 on panel (a)'s budget: sharing
    its first run)."""
    quick = Settings.quick()
    settings = replace(quick, forms=FORMS, shares={**quick.shares, "fig3": quick.shares["a"]})
    out = tmp_path / "repro"
    queued, seen = [], []

    class Fake(Backend):
        def run(self, units, tracker, done, folder):
            for u in units:
                queued.append(u.name)
                done(u.name, {"x": [x for _, x in u.args[1]], "unit": u.name})

    (out / "panels").mkdir(parents=True)
    (out / "panels" / "restriction-b.json").write_text(json.dumps({"x": [0, 100],
                                                                     "mine": True}))
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr("tpo.experiments.reproduce.write_outputs", lambda *a: None)
        result = reproduce(out, settings, seen.append, Fake())
    assert sorted(queued) == sorted(
        [f"{f}-{p}" for f in FORMS for p in ("a", "b", "c", "d")
         if (f, p) != ("restriction", "b")] + ["penalty-a-velocity"])
    assert queued == [name for name, *_ in settings.units() if name != "restriction-b"]
    assert seen[0] == {name: float(name == "restriction-b") for name, *_ in settings.units()}
    assert seen[-1] == dict.fromkeys(seen[0], 1.0)
    assert list(result.records) == list(FORMS)
    assert result.records["restriction"]["b"] == {"form": "restriction",
                                                  "panel": asdict(PANELS[1]),
                                                  "x": [0, 100], "mine": True}
    # Figure 3's slack 0 is panel (a)'s run, and its (100, 0) trains in (a)'s program:
    # its record takes both from (a)'s unit.
    assert result.records["penalty"]["fig3"] == {"form": "penalty", "panel": asdict(FIGURE3),
                                                 "x": [0.0, 100.0], "unit": "penalty-a"}
    assert result.continuous["a-velocity"]["x"] == [0.0, 100.0]
    assert result.continuous["a-velocity"]["panel"]["action"] == "velocity"
    assert json.loads((out / "panels" / "penalty-a.json").read_text()) == {
        "x": [0.0, 100.0, 100.0], "unit": "penalty-a"}  # written by the driver as it finished


def test_a_unit_record_of_other_runs_is_refused_before_anything_trains(tmp_path):
    """A finished unit's record holding other runs than today's unit of that name (a
    version of tpo that cut the units otherwise) is refused, and kept."""
    settings = replace(Settings.quick(), continuous=("a", "fig3"))
    assert [[(p.key, x) for p, x in runs] for name, _, runs in settings.units()
            if name == "penalty-a-velocity"] == [
        [("a-velocity", 0.0), ("a-velocity", 100.0), ("fig3-velocity", 100.0)]]
    out = tmp_path / "repro"
    (out / "panels").mkdir(parents=True)
    old = json.dumps({"x": [0.0, 100.0], "slacks": [[0.0, 0.0], [100.0, 100.0]]})
    (out / "panels" / "penalty-a-velocity.json").write_text(old)

    class Refused(Backend):
        def run(self, units, tracker, done, folder):
            raise AssertionError("nothing trains")

    with pytest.raises(TPOError, match=r"penalty-a-velocity.json holds other runs than this "
                       r"unit's \(slacks \[\[0.0, 0.0\], \[100.0, 100.0\]\], not "
                       r"\[\[0.0, 0.0\], \[100.0, 100.0\], \[100.0, 0.0\]\]\)"):
        reproduce(out, settings, backend=Refused())
    assert (out / "panels" / "penalty-a-velocity.json").read_text() == old


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
    link = FileLink("sweep", 0.0, ckpt)
    with pytest.raises(Interrupt):
        run_sweep(*args, chunk_updates=2, checkpoint=link, progress=stop_after_two_chunks)
    seen = []
    resumed = run_sweep(*args, chunk_updates=2, checkpoint=FileLink("sweep", 60.0, ckpt),
                        progress=lambda done, total: seen.append(done))
    assert seen == [4, 6, 8]  # started after update 4
    np.testing.assert_array_equal(resumed.exact, whole.exact)
    np.testing.assert_array_equal(resumed.policies, whole.policies)
    # A checkpoint of another version (tpo 0.1's had no format) is named, not misread.
    ckpt.write_bytes(serialization.msgpack_serialize({"done": 4, "states": {}}))
    with pytest.raises(TPOError, match=r"written by another version of tpo \(format None; "
                                       r"this version reads \d+ to \d+\); delete it"):
        run_sweep(*args, chunk_updates=2, checkpoint=link)


@pytest.mark.slow
def test_quick_reproduction_writes_figures_tables_and_report_and_resumes(tmp_path, capsys):
    out = tmp_path / "repro"
    both = ["--constraint", "both"]
    assert main(["reproduce", "--quick", *both, "--out", str(out), "--quiet"]) == 0
    names = {p.name for p in out.iterdir()}
    pngs = {f"figure{n}-{form}.png" for n in (2, 3) for form in ("penalty", "restriction")}
    pngs.add("figure2-continuous-velocity.png")  # one continuous panel: no Figure 3 of it
    assert pngs | {"results.csv", "results.json", "report.md", "settings.json",
                   "panels"} <= names and "figure3-continuous-velocity.png" not in names
    for png in pngs:
        assert (out / png).read_bytes()[:4] == b"\x89PNG"
    rows = [r.split(",") for r in (out / "results.csv").read_text().strip().splitlines()]
    # 2 forms x (4 panels + figure 3) x 2 slacks x 2 seeds x 3 objectives, and the
    # continuous panel (a): 2 slacks x 2 seeds x 3 objectives
    assert len(rows) == 1 + 2 * 5 * 2 * 2 * 3 + 2 * 2 * 3
    assert rows[0][:2] == ["form", "panel"]
    assert rows[0][-4:] == ["lar_feasible", "lar_correct", "strict", "same_values"]
    assert {tuple(r[:3]) for r in rows if r[1] == "a-velocity"} == {
        ("penalty", "a-velocity", "M>A>G")}
    # The forms ran on the same seeds, slacks and objectives, row for row.
    penalty = [r[1:7] for r in rows[1:] if r[0] == "penalty" and r[1] != "a-velocity"]
    assert penalty == [r[1:7] for r in rows[1:] if r[0] == "restriction"]
    report = (out / "report.md").read_text()
    # The verdicts side by side: one row per panel (and the total), one column per form.
    header = ("| panel | penalty: LAR-correct / strict / same values | "
              "restriction: LAR-correct / strict / same values |")
    table = report[report.index(header):].split("\n\n")[0].splitlines()
    assert [row.split(" | ")[0] for row in table[2:]] == [
        "| (a) M>A>G", "| (b) A>M>G", "| (c) G>M>A", "| (d) A>G, M>G", "| (fig3) M>A>G",
        "| **all feasible runs**"]
    assert report.count("| (a) M>A>G | avoid |") == 1  # directions: both forms in a row
    assert report.count("| (a) M>A>G | ") == 1 + 3
    assert report.count(": restriction form") == report.count(": penalty form") == 4
    # LAR's line in the results is the exact solver's, e.g. panel (b) at slack (0, 100).
    results = json.loads((out / "results.json").read_text())["forms"]
    assert {(form, name, rec["form"], rec["panel"]["name"]) for form, panels in results.items()
            for name, rec in panels.items()} == {
        (form, name, form, name) for form in ("penalty", "restriction")
        for name in ("a", "b", "c", "d", "fig3")}
    record = results["penalty"]["b"]
    assert results["restriction"]["b"]["lar"] == record["lar"]
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
    # The continuous panel is judged against the env's finite reference, solved alone.
    assert "## The continuous robot, velocity actions" in report
    assert "| (a-velocity) M>A>G | " in report
    cont = json.loads((out / "results.json").read_text())["continuous"]["a-velocity"]
    ref = continuous_model(ContinuousNav(load_map("small"), action="velocity"), 0.99)
    graph = ObjectiveGraph.parse("M>A>G", [100, 100], objectives=ref.model.objectives)
    lar = solve_lar(ref.model, graph, relax=True).start_policy_values()
    assert cont["lar"][1] == pytest.approx([lar[n] for n in cont["objectives"]])
    assert np.shape(cont["exact"]) == (2, 2, 3) and np.shape(cont["lar_correct"]) == (2, 2)
    # A second run skips every finished panel; other settings are refused.
    before = {p.name: p.stat().st_mtime_ns for p in (out / "panels").iterdir()}
    assert main(["reproduce", "--quick", *both, "--out", str(out), "--quiet"]) == 0
    assert {p.name: p.stat().st_mtime_ns for p in (out / "panels").iterdir()} == before
    capsys.readouterr()
    assert main(["reproduce", "--quick", *both, "--seeds", "3", "--out", str(out),
                 "--quiet"]) == 2
    assert "holds a reproduction with other settings" in capsys.readouterr().err
    # one form alone (the default) is another reproduction, in its own directory
    assert main(["reproduce", "--quick", "--out", str(out), "--quiet"]) == 2
    assert "other settings (in forms, learners: see its settings.json)" in \
        capsys.readouterr().err
    assert json.loads((out / "settings.json").read_text())["forms"] == ["penalty",
                                                                         "restriction"]
