"""Issue 7's catalogue of bad inputs: every one ends in one line `tpo: error: ...`
naming the problem and exit code 2 — never a traceback (from JAX or anywhere)."""

import pytest

from tpo.cli.main import main

GOOD_MAP = """grid = \"\"\"
#####
#S.G#
#####
\"\"\"
"""
FILES = {
    "ragged.toml": 'grid = """\n#####\n#S.G#\n###\n"""\n',
    "walled.toml": 'grid = """\n#####\n#S#G#\n#####\n"""\n',
    "nostart.toml": 'grid = """\n#####\n#..G#\n#####\n"""\n',
    "char.toml": 'grid = """\n#####\n#SxG#\n#####\n"""\n',
    "steps.toml": GOOD_MAP + "max_steps = 0\n",
    "bigsteps.toml": GOOD_MAP + "max_steps = 100000000000000000000\n",
    "rect.toml": GOOD_MAP + "avoid = [[1, 3, 1, 1]]\n",
    "notoml.toml": "grid = [unclosed\n",
    "lr.toml": "learning_rate = -1\n",
    "unknown.toml": "learning_rat = 0.001\n",
    "minibatch.toml": "num_envs = 3\nnum_steps = 3\nnum_minibatches = 2\n",
    "advantage.toml": 'advantage = "clipped"\n',
    "beta.toml": 'beta = "big"\n',
    "fractions.toml": "phase_fractions = [1.0]\n",
    "badconfig.toml": "num_envs = [\n",
    "slackconf.toml": 'slack = "lots"\n',
    "tiny.toml": "num_envs = 2\nnum_steps = 8\nnum_minibatches = 1\nupdate_epochs = 1\n",
}

CASES = [
    # DAG specs
    (["solve", "--dag", "M>A>X"], "unknown objective 'X'"),
    (["solve", "--dag", "M>A>M"], "cycle"),
    (["solve", "--dag", ""], "empty"),
    (["solve", "--dag", "M>>G"], "empty objective name"),
    (["solve", "--dag", "A>G, M>A, M>G, G>M"], "cycle"),
    (["solve", "--dag", "A>G, M>A, A>G"], "duplicate edge"),
    (["solve", "--dag", "A>G, A>M"], "exactly one sink (leaf), found 2"),
    # slack values
    (["solve", "--slack", "abc"], "bad --slack 'abc'"),
    (["solve", "--slack", "1,2,3"], "got 3 slack values for 2 edge(s)"),
    (["solve", "--slack", "-1"], "slack must be >= 0"),
    (["solve", "--slack", "nan"], "bad --slack 'nan': give a finite number"),
    (["solve", "--slack", "inf"], "bad --slack 'inf': give a finite number"),
    (["solve", "--dag", "A>G, M>G", "--slack", "0"], "infeasible: objective 'goal'"),
    # maps and models
    (["solve", "--map", "nowhere"], "no bundled map or file named 'nowhere'"),
    (["solve", "--map", "{tmp}/ragged.toml"], "ragged"),
    (["solve", "--map", "{tmp}/walled.toml"], "unreachable"),
    (["solve", "--map", "{tmp}/nostart.toml"], "needs exactly one 'S' (start)"),
    (["solve", "--map", "{tmp}/char.toml"], "unknown character(s) 'x' in grid row 1"),
    (["solve", "--map", "{tmp}/steps.toml"], "max_steps must be an integer from 1 to"),
    (["solve", "--map", "{tmp}/bigsteps.toml"], "max_steps must be an integer from 1 to"),
    (["solve", "--map", "{tmp}/rect.toml"], "avoid rectangle"),
    (["solve", "--map", "{tmp}/notoml.toml"], "bad TOML"),
    (["solve", "--gamma", "1.5"], "gamma must be a number in [0, 1)"),
    (["solve", "--slip", "2"], "slip must be a probability"),
    # config files
    (["train", "--config", "{tmp}/lr.toml", "--out", "{tmp}/r"],
     "learning_rate must be a finite number > 0"),
    (["train", "--config", "{tmp}/unknown.toml", "--out", "{tmp}/r"], "learning_rat"),
    (["train", "--config", "{tmp}/minibatch.toml", "--out", "{tmp}/r"],
     "num_minibatches (2) must divide num_envs * num_steps (9)"),
    (["train", "--config", "{tmp}/advantage.toml", "--out", "{tmp}/r"], "advantage"),
    (["train", "--config", "{tmp}/beta.toml", "--out", "{tmp}/r"], "beta"),
    (["train", "--config", "{tmp}/fractions.toml", "--out", "{tmp}/r", "--map", "small",
      "--steps", "20000"], "phase_fractions has 1 values for 3 phase(s)"),
    (["train", "--config", "{tmp}/badconfig.toml", "--out", "{tmp}/r"], "cannot read --config"),
    (["train", "--config", "{tmp}/none.toml", "--out", "{tmp}/r"], "cannot read --config"),
    (["train", "--config", "{tmp}/slackconf.toml", "--out", "{tmp}/r"],
     "slack must be a number or a list of numbers"),
    # CLI arguments
    (["train", "--map", "small", "--steps", "100", "--out", "{tmp}/r"],
     "total_timesteps must be an integer from 6144"),
    (["train", "--map", "small", "--steps", "100000000000000000000", "--out", "{tmp}/r"],
     "to 4.4e+12 (the update counter is int32)"),
    (["train", "--map", "small", "--seed", "99999999999999999999", "--out", "{tmp}/r"],
     "seed must be an integer from 0 to 2**32 - 1"),
    (["train", "--map", "small", "--seed", "-1", "--out", "{tmp}/r"],
     "seed must be an integer from 0 to 2**32 - 1"),
    (["train", "--map", "small", "--episodes", "0", "--out", "{tmp}/r"],
     "argument --episodes: must be from 1 to 1000000, got 0"),
    (["eval", "{tmp}", "--episodes", "-3"], "argument --episodes: must be from 1 to 1000000"),
    (["eval", "{tmp}", "--episodes", "2147483648"], "argument --episodes: must be from 1 to"),
    (["train", "--map", "small", "--hidden", "3000000000", "--out", "{tmp}/r"],
     "hidden must be 1 to 16 layer widths from 1 to 4096"),
    (["reproduce", "--out", "{tmp}/x", "--quick", "--slacks", "nan,1"], "bad --slacks 'nan,1'"),
    (["reproduce", "--out", "{tmp}/x", "--quick", "--seeds", "99999999999999999999"],
     "--seeds must be from 1 to 1000"),
    (["train", "--config", "{tmp}", "--out", "{tmp}/r"], "not a regular file"),
    (["solve", "--map", "{tmp}"], "is not a regular file"),
    (["reproduce", "--out", "", "--quick"], "--out must name a directory"),
    (["solve", "--plot", "{tmp}/figure.xyz"], "give a file ending in one of"),
    (["train", "--map", "small", "--out", "{tmp}/lr.toml"], "is a file, not a directory"),
    (["train", "--map", "small"], "give --out RUN_DIR (or --resume RUN_DIR)"),
    (["train", "--resume", "{tmp}"], "is not a run directory (no config.toml)"),
    (["train", "--resume", "{tmp}", "--map", "home"], "drop --out, --config and the run"),
    (["eval", "{tmp}"], "is not a saved tpo model"),
    (["reproduce", "--out", "{tmp}/x", "--slacks", "5,1"], "at least two increasing values"),
    (["reproduce", "--out", "{tmp}/x", "--seeds", "0"], "--seeds must be from 1 to 1000"),
    (["reproduce", "--out", "{tmp}/x", "--map", "nowhere"], "no bundled map or file"),
    # argparse's own errors, on one line too
    (["reproduce", "--out", "{tmp}/x", "--constraint", "bogus"], "invalid choice: 'bogus'"),
    (["reproduce", "--out", "{tmp}/x", "--seeds", "abc"], "invalid int value: 'abc'"),
    (["train", "--map", "small", "--bogus"], "unrecognized arguments: --bogus"),
    # user environments
    (["train", "--env", "gym:CartPole-v1", "--objectives", "a", "--dag", "a",
      "--out", "{tmp}/r"], "has a scalar reward"),
    (["train", "--env", "mo-gymnasium:deep-sea-treasure-v0", "--objectives", "a,b,c",
      "--dag", "a", "--out", "{tmp}/r"], "returns 2 reward components but 3 objectives"),
    (["train", "--env", "mo-gymnasium:deep-sea-treasure-v0", "--dag", "a", "--out",
      "{tmp}/r"], "name the reward components"),
    (["train", "--env", "deep-sea-treasure", "--objectives", "a", "--dag", "a", "--out",
      "{tmp}/r"], "a Gymnasium env is named PACKAGE:ENV_ID"),
    (["train", "--env", "mo-gymnasium:no-such-env-v0", "--objectives", "a", "--dag", "a",
      "--out", "{tmp}/r"], "unknown env id 'no-such-env-v0'"),
    *[(["train", "--env", f"badenvs:{name}-v0", "--objectives", "a,b", "--dag", "a>b",
        "--steps", "64", "--config", "{tmp}/tiny.toml", "--out", "{tmp}/r", "--quiet"], message)
      for name, message in (
          ("NanReward", "NanReward-v0 returned a non-finite reward nan for objective 'b' "
                        "at update 1, step 3 of its rollout, in copy 0"),
          ("WideReward", "WideReward-v0 returned a reward of shape (3,) for 2 objectives"),
          ("GrowingObservation", "GrowingObservation-v0's observation shape changed from "
                                 "(2,) to (3,)"),
          ("SequenceObservation", "TPO supports Box, Discrete and what gymnasium"),
          ("MultiDiscreteAction", "TPO supports Discrete and 1-D Box actions"))],
]


@pytest.mark.parametrize(("args", "message"), CASES,
                         ids=[" ".join(a)[:60] for a, _ in CASES])
def test_bad_input_gives_one_line_and_exit_2(args, message, tmp_path, capsys):
    for name, text in FILES.items():
        (tmp_path / name).write_text(text)
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("tpo: error: ") and err.count("\n") == 1, err
    assert message in err, err
    assert "Traceback" not in err


def test_failed_settings_are_never_saved(tmp_path, capsys):
    """A reproduction refused for its settings leaves nothing that would refuse the
    corrected command on the same --out (issue 15, item 4)."""
    out = tmp_path / "repro"
    assert main(["reproduce", "--quick", "--steps", "0", "--out", str(out)]) == 2
    assert "total_timesteps must be an integer from 6144" in capsys.readouterr().err
    assert not out.exists()
    out.mkdir()
    assert main(["reproduce", "--quick", "--steps", "0", "--out", str(out), "--quiet"]) == 2
    assert list(out.iterdir()) == []
    run = tmp_path / "run"
    assert main(["train", "--map", "small", "--steps", "0", "--out", str(run)]) == 2
    assert not run.exists()
