"""The ``tpo`` command line as a user runs it."""

import json
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from tpo.cli.main import main


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tpo.cli.main", *args],
                          capture_output=True, text=True, timeout=120)


def test_solve_json_is_one_object_with_the_documented_keys():
    out = run("solve", "--map", "home", "--dag", "M>A>G", "--slack", "100,0", "--json")
    assert out.returncode == 0, out.stderr
    data = json.loads(out.stdout)
    assert data["order"] == ["monitor", "avoid", "goal"]
    assert data["feasible"] is True
    assert set(data["values"]) == {"monitor", "avoid", "goal"}
    assert set(data["policy_values"]) == {"goal", "avoid", "monitor"}
    # The hallway detour: 28 steps, never in the living room, monitor unvisited.
    assert data["path_length"] == 28 and data["reached_goal"]
    assert data["policy_values"]["avoid"] == pytest.approx(0.0)
    assert data["policy_values"]["goal"] == pytest.approx(-(1 - 0.99**28) / 0.01)


def test_solve_prints_a_table(capsys):
    assert main(["solve", "--dag", "M>A>G", "--slack", "0"]) == 0
    out = capsys.readouterr().out
    assert "monitor>avoid>goal (slack 0, 0)" in out
    assert "does not reach the goal" in out


def test_infeasible_problem_exits_nonzero_unless_relaxed():
    out = run("solve", "--dag", "A>G, M>G", "--slack", "0")
    assert out.returncode == 2
    assert out.stderr.startswith("tpo: error: infeasible: objective 'goal'")
    assert "Traceback" not in out.stderr
    out = run("solve", "--dag", "A>G, M>G", "--slack", "0", "--relax", "--json")
    assert out.returncode == 0
    assert json.loads(out.stdout)["feasible"] is False


def test_plot_writes_a_png_and_refuses_to_overwrite(tmp_path, capsys):
    target = tmp_path / "path.png"
    assert main(["solve", "--slack", "100,0", "--plot", str(target)]) == 0
    assert target.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    before = target.stat().st_mtime_ns
    assert main(["solve", "--plot", str(target)]) == 2
    assert "exists; pass --force" in capsys.readouterr().err
    assert target.stat().st_mtime_ns == before
    assert main(["solve", "--plot", str(target), "--force"]) == 0


def test_map_file_path(tmp_path, capsys):
    from tpo.envs import load_map

    path = tmp_path / "copy.toml"
    path.write_text(load_map("home").to_toml())
    assert main(["solve", "--map", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["map"] == "home"


def test_maps_lists_the_bundled_maps(capsys):
    assert main(["maps"]) == 0
    out = capsys.readouterr().out
    assert "home" in out and "11x30" in out


def test_train_writes_a_run_directory_and_eval_reads_it(tmp_path, capsys):
    out = tmp_path / "run"
    args = ["train", "--map", "small", "--dag", "M>A>G", "--slack", "100,0", "--steps",
            str(3 * 2048 * 2), "--out", str(out), "--episodes", "4", "--quiet"]
    assert main(args) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[0].split() == ["objective", "learned", "LAR", "V*", "floor"]
    assert printed[3].startswith("monitor") and printed[5].startswith("LAR-correct: ")
    assert sorted(p.name for p in out.iterdir()) == [".tpo.lock", ".tpo.run", "checkpoints",
                                                      "config.toml", "eval.json", "metrics.csv",
                                                      "model", "tb"]
    assert [p.name for p in (out / "checkpoints").iterdir()] == ["update-000006"]
    assert any(p.name.startswith("events.out.tfevents") for p in (out / "tb").iterdir())
    result = json.loads((out / "eval.json").read_text())
    assert set(result) == {"mc", "exact", "lar", "lar_correct", "strict", "same_values", "outside"}
    assert set(result["mc"]["greedy"]["undiscounted"]) == {"goal", "avoid", "monitor"}
    assert result["lar"]["policy_values"]["avoid"] == 0.0
    lines = (out / "metrics.csv").read_text().strip().splitlines()
    assert lines[0].startswith("update,timesteps,phase,return_goal")
    assert len(lines) == 1 + 6 and lines[-1].split(",")[2] == "goal"  # last phase
    capsys.readouterr()
    assert main(["eval", str(out), "--episodes", "4"]) == 0
    assert json.loads(capsys.readouterr().out)["exact"] == result["exact"]
    # The resolved config trains the same problem again.
    again = tmp_path / "again"
    assert main(["train", "--config", str(out / "config.toml"), "--out", str(again),
                 "--episodes", "4", "--quiet"]) == 0
    assert json.loads((again / "eval.json").read_text())["exact"] == result["exact"]


def test_train_resume_finishes_a_run_from_its_last_checkpoint(tmp_path, capsys):
    out = tmp_path / "run"
    args = ["train", "--map", "small", "--dag", "A>G", "--slack", "0", "--steps",
            str(2 * 2048 * 12), "--out", str(out), "--episodes", "4", "--quiet"]
    assert main(args) == 0
    done = json.loads((out / "eval.json").read_text())
    metrics = (out / "metrics.csv").read_text()
    # Pretend the run was killed after update 16's checkpoint, mid-way through a chunk.
    for p in [out / "model", *sorted((out / "checkpoints").iterdir())[1:]]:
        shutil.rmtree(p)
    (out / "eval.json").unlink()
    (out / "metrics.csv").write_text(metrics[: len(metrics) * 3 // 4])  # a cut-off line
    assert main(["train", "--resume", str(out), "--quiet", "--episodes", "4"]) == 0
    assert json.loads((out / "eval.json").read_text()) == done
    assert (out / "metrics.csv").read_text() == metrics
    assert main(["train", "--resume", str(out), "--map", "home"]) == 2
    assert "drop --out, --config and the run options" in capsys.readouterr().err


def test_a_run_of_tpo_0_2_resumes_without_the_margin_it_never_had(tmp_path):
    """A run written before ``margin`` and ``tie_break`` existed (no keys in its
    config.toml or its checkpoints, config format 7) resumes as it was trained, with
    both 0, to the same result."""
    out = tmp_path / "run"
    assert main(["train", "--map", "small", "--dag", "A>G", "--slack", "1", "--margin", "0",
                 "--tie-break", "0", "--steps", str(2 * 2048 * 8), "--out", str(out),
                 "--episodes", "4", "--quiet"]) == 0
    done = json.loads((out / "eval.json").read_text())
    metrics = (out / "metrics.csv").read_text()  # the penalties of every update
    for p in [out / "model", *sorted((out / "checkpoints").iterdir())[1:]]:
        shutil.rmtree(p)
    (out / "eval.json").unlink()
    for config in [out / "config.toml", *out.glob("checkpoints/*/model.json")]:
        text = config.read_text()
        assert "margin" in text and "tie_break" in text and "format" in text
        config.write_text("\n".join(
            line.replace('"format": 8', '"format": 7') for line in text.splitlines()
            if "margin" not in line and "tie_break" not in line
            and not line.startswith("format = ")))
    assert main(["train", "--resume", str(out), "--quiet", "--episodes", "4"]) == 0
    assert json.loads((out / "eval.json").read_text()) == done
    assert (out / "metrics.csv").read_text() == metrics
    saved = json.loads((out / "model" / "model.json").read_text())["config"]
    assert (saved["margin"], saved["tie_break"]) == (0.0, 0.0)


def test_train_refuses_to_replace_a_run_and_rejects_bad_config(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    assert main(["train", "--map", "small", "--steps", "20000", "--out", str(out)]) == 2
    assert "exists; pass --force to replace it or --resume" in capsys.readouterr().err
    assert (out / "keep.txt").read_text() == "mine"
    assert [p.name for p in out.iterdir()] == ["keep.txt"]  # no lock file left behind
    bad = tmp_path / "bad.toml"
    bad.write_text("learning_rate = -1\n")
    assert main(["train", "--config", str(bad), "--out", str(tmp_path / "x")]) == 2
    assert "learning_rate must be a finite number > 0" in capsys.readouterr().err
    assert main(["train", "--config", str(tmp_path / "none.toml"), "--out", "y"]) == 2
    assert "cannot read --config" in capsys.readouterr().err
    assert main(["eval", str(tmp_path / "nothing")]) == 2
    assert "is not a saved tpo model" in capsys.readouterr().err


def test_every_run_field_and_hyperparameter_is_a_documented_train_flag():
    from dataclasses import fields

    from tpo.algo import TPOConfig
    from tpo.experiments import RunSpec

    text = run("train", "--help").stdout
    names = [f.name for f in fields(TPOConfig)] + [f.name for f in fields(RunSpec)
                                                   if f.name != "config"]
    for name in names:
        assert f"--{name.replace('_', '-')} " in text, name
    assert "Adam's step size" in text and "--no-anneal-lr" in text


def test_train_flags_reach_the_run_config_and_bad_values_are_one_line(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["train", "--map", "small", "--dag", "A>G", "--steps", "1024", "--num-envs",
                 "4", "--num-steps", "32", "--num-minibatches", "2", "--hidden", "16,16",
                 "--no-anneal-lr", "--beta", "auto", "--phase-fractions", "1,3", "--out",
                 str(out), "--quiet", "--episodes", "2", "--profile", "paper",
                 "--tie-break", "0.05"]) == 0
    config = (out / "config.toml").read_text()
    for line in ("num_envs = 4", "num_steps = 32", "hidden = [\n    16,\n    16,\n]",
                 "anneal_lr = false", 'beta = "auto"', "phase_fractions = [\n    1.0,\n",
                 'profile = "paper"', "select = false", 'telescope = "off"',
                 "tie_break = 0.05", "format = 8"):
        assert line in config, (line, config)
    capsys.readouterr()
    for args, message in [(["--num-envs", "many"], "bad --num-envs 'many': expected int"),
                          (["--hidden", "64,x"], "bad --hidden '64,x': expected int,..."),
                          (["--gamma", "1"], "gamma must be in [0, 1), got 1.0"),
                          (["--slack", "0,,1"], "bad --slack '0,,1': expected number,..."),
                          (["--observation", "grid"],
                           "bad --observation 'grid': choose one of auto, factored, onehot, "
                           "coords, factored+onehot"),
                          (["--beta", "AUTO"], 'beta must be a finite number >= 0 or "auto"'),
                          (["--env", " "], "bad --env ' ': expected text"),
                          (["--profile", "grid,fast"], "unknown profile 'fast': choose from")]:
        assert main(["train", "--map", "small", "--out", str(tmp_path / "x"), *args]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err


def test_solve_continuous_gives_the_reference_and_its_discretisation_error():
    out = run("solve", "--dynamics", "continuous", "--action", "heading", "--dag", "M>A>G",
              "--slack", "100,0", "--json")
    assert out.returncode == 0, out.stderr
    data = json.loads(out.stdout)
    assert (data["dynamics"], data["action"], data["resolution"]) == ("continuous", "heading", 8)
    assert data["path"] == {"reaches_goal": True, "enters_avoid": False,
                            "ends_in_monitor": False}
    # The hallway detour at half a cell per step, twice as long as the grid's 28 moves
    # (diagonals shorten it): about -39.6, within 0.11 of the finer lattice's (a tenth of
    # the verdict's 5 % tolerance, 2.0).
    assert -41 < data["policy_values"]["goal"] < -38
    assert max(data["discretisation_error"].values()) < 0.2
    assert data["unresolved"] == []


def test_solve_continuous_names_what_its_lattice_does_not_resolve():
    """hall's M>A>G at slack 0 at 4 points a cell: avoid -8.83 against -7.27 at 8, more
    than a continuous verdict's 0.5 (tests/test_continuous_model.py)."""
    hall = str(Path(__file__).parents[1] / "benchmarks/maps/hall.toml")
    args = ("solve", "--map", hall, "--dynamics", "continuous", "--dag", "M>A>G", "--slack",
            "0", "--resolution", "4")
    out = run(*args, "--json")
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["unresolved"] == ["avoid"]
    text = run(*args).stdout.splitlines()
    assert text[-1].startswith("not resolved: avoid differs by more than") and \
        text[-1].endswith("solve at --resolution 8")


@pytest.mark.parametrize("args, message", [
    (["solve", "--action", "heading"], "--action and --resolution are options of continuous"),
    (["solve", "--dynamics", "continuous", "--resolution", "5"], "--resolution must be an even"),
    (["train", "--dynamics", "continuous", "--slip", "0.1", "--out", "x"],
     "slip is not an option of continuous dynamics"),
    (["train", "--noise", "0.1", "--out", "x"], "noise is not an option of grid dynamics"),
    (["train", "--dynamics", "continuous", "--noise", "-1", "--out", "x"],
     "noise must be a finite number >= 0")])
def test_dynamics_options_are_checked_in_one_line(args, message, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("tpo: error: ") and message in err and err.count("\n") == 1
    assert not (tmp_path / "x").exists()


def test_train_continuous_writes_a_run_judged_against_the_reference(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["train", "--map", "small", "--dynamics", "continuous", "--action", "heading",
                 "--dag", "A>G", "--slack", "100", "--steps", str(4 * 2048),
                 "--episodes", "4", "--quiet", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "LAR-correct at value level (5 %)" in printed and "reference" in printed
    config = (out / "config.toml").read_text()
    assert 'dynamics = "continuous"' in config and 'action = "heading"' in config
    assert "slip" not in config and "population = 2" in config
    result = json.loads((out / "eval.json").read_text())
    assert set(result) >= {"mc", "mc_noise_free", "reference", "lar_correct", "path",
                           "path_matches"}
    assert result["reference"]["path"]["reaches_goal"]
    assert set(result["reference"]["floors"]) == {"avoid"}
    assert main(["eval", str(out), "--episodes", "2"]) == 0
    assert json.loads(capsys.readouterr().out)["reference"] == result["reference"]


def test_a_continuous_run_takes_the_continuous_budget_unless_told():
    from tpo.experiments.runspec import DEFAULT_STEPS, RunSpec

    assert DEFAULT_STEPS == {"grid": 1_000_000, "continuous": 8_000_000}
    assert RunSpec.from_settings({"dynamics": "continuous"}).steps == 8_000_000
    assert RunSpec.from_settings({"dynamics": "continuous", "steps": 5000}).steps == 5000
    assert RunSpec.from_settings({}).steps == RunSpec().steps == 1_000_000


def test_a_map_run_trains_a_population_unless_told_and_old_runs_keep_one(tmp_path, capsys):
    from tpo.experiments.runspec import RunSpec

    assert RunSpec.from_settings({}).population == RunSpec().population == 4
    assert RunSpec.from_settings({"dynamics": "continuous"}).population == 2
    assert RunSpec.from_settings({"dynamics": "continuous"}, saved=True).population == 1
    assert RunSpec.from_settings({"env": "mo-gymnasium:deep-sea-treasure-v0",
                                  "objectives": "treasure,time"}).population == 1
    assert RunSpec.from_settings({}, saved=True).population == 1  # a run written before
    assert "population = 2" in RunSpec.from_settings({"population": 2}).to_toml()
    for args, message in [
            (["--map", "small", "--population", "0"], "population must be from 1 to 64, got 0"),
            (["--map", "small", "--population", "x"], "bad --population 'x': expected int")]:
        assert main(["train", *args, "--out", str(tmp_path / "x")]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "x").exists()


def test_a_velocity_robot_starts_from_the_discretized_defaults_and_flags_win():
    """Velocity actions take a factorised categorical of 5 values per dimension with a
    categorical's other defaults unless told otherwise; heading actions keep the
    categorical defaults; both take the continuous state's telescoping penalty and GAE's
    lambda, the grid not; a Gaussian keeps its own; a saved run keeps its own config."""
    from tpo.algo import TPO, TPOConfig
    from tpo.algo.config import POLICY_DEFAULTS
    from tpo.envs import ContinuousNav, load_map
    from tpo.experiments.runspec import RunSpec

    binned = TPOConfig(action_bins=5)
    assert TPOConfig.from_profile("grid", "discretized") == binned
    gaussian = TPOConfig.from_profile("grid", "gaussian")
    assert gaussian == TPOConfig(**POLICY_DEFAULTS["gaussian"])
    assert (gaussian.ent_coef, gaussian.ent_coef_end, gaussian.learning_rate) == (0, 0, 3e-4)
    continuous = {"telescope": "all", "advantage": "immediate", "tie_critic": "leaf",
                  "dead_zone": 0.4, "gae_lambda": 0.98}
    robot = TPOConfig(action_bins=5, **continuous)
    assert RunSpec.from_settings({"dynamics": "continuous"}).config == robot
    assert RunSpec.from_settings({"dynamics": "continuous", "action": "heading"}).config \
        == TPOConfig(**continuous)
    assert RunSpec.from_settings({}).config == TPOConfig()
    mine = RunSpec.from_settings({"dynamics": "continuous", "action_bins": 3}).config
    assert (mine.action_bins, mine.ent_coef) == (3, TPOConfig().ent_coef)
    saved = RunSpec.from_settings({"dynamics": "continuous", "format": 8,
                                   **TPOConfig().to_dict()}, saved=True)
    assert saved.config == TPOConfig() and saved.profile == "continuous"
    # A run's config.toml of format 7 (no format key) from before telescope meant the
    # paper's penalty and advantage, in any space.
    old_robot = RunSpec.from_settings({"dynamics": "continuous"}, saved=True).config
    assert (old_robot.telescope, old_robot.advantage, old_robot.tie_critic,
            old_robot.dead_zone) == ("off", "penalized", "ancestors", 0.0)
    # ... and a telescope of true or false, written when it was a flag.
    assert TPOConfig.from_saved({"telescope": True}, 7).telescope == "all"
    assert TPOConfig.from_saved({"telescope": False}, 7).telescope == "off"
    # A saved config from before action_bins meant a Gaussian.
    old = {k: v for k, v in binned.to_dict().items() if k != "action_bins"}
    assert TPOConfig.from_saved(old, 7).action_bins == 0
    # A run names its profile(s); a saved run's config.toml keeps them.
    paper = RunSpec.from_settings({"profile": "grid,paper"})
    assert (paper.profile, paper.config.select) == ("grid,paper", False)
    assert "profile = \"grid,paper\"" in paper.to_toml()
    again = RunSpec.from_settings(tomllib.loads(paper.to_toml()), saved=True)
    assert (again.config, again.profile) == (paper.config, paper.profile)
    navmap = load_map("small")
    assert TPO(ContinuousNav(navmap), "goal").config == robot
    assert TPO(ContinuousNav(navmap, action="heading"), "goal").config \
        == TPOConfig(**continuous)
    assert TPO(ContinuousNav(navmap), "goal", config=TPOConfig()).config == TPOConfig()
