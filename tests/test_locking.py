"""One writer per directory (issue 15, item 2): while a tpo process works in a run
or reproduction directory, every other command on it gets one line naming the
holder's pid, and nothing in the directory changes."""

import os
import subprocess
import sys

import pytest

from tpo.cli.main import main
from tpo.locking import LOCK_FILE, LockError, exclusive


def snapshot(directory):
    return {p.relative_to(directory): p.read_bytes() for p in directory.rglob("*")
            if p.is_file() and p.name != LOCK_FILE}


@pytest.mark.parametrize("command", [
    ["train", "--resume", "{d}"],
    ["train", "--map", "small", "--steps", "6144", "--out", "{d}", "--force"],
    ["train", "--map", "small", "--steps", "6144", "--out", "{d}"],
    ["eval", "{d}"],
    ["reproduce", "--quick", "--out", "{d}"],
])
def test_a_second_process_is_refused_with_the_holders_pid(tmp_path, capsys, command):
    d = tmp_path / "run"
    (d / "model").mkdir(parents=True)
    (d / "config.toml").write_text('map = "small"\n')
    before = snapshot(d)
    with exclusive(d):
        assert main([a.replace("{d}", str(d)) for a in command]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert f"{d} is in use by another tpo process (pid {os.getpid()})" in err
    assert snapshot(d) == before


def test_the_lock_is_released_when_its_holder_dies(tmp_path):
    d = tmp_path / "run"
    d.mkdir()
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from tpo.locking import exclusive\n"
         f"with exclusive({str(d)!r}):\n    print('held', flush=True); time.sleep(60)"],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(LockError, match=f"pid {holder.pid}"), exclusive(d):
            pass
    finally:
        holder.kill()
        holder.wait()
    with exclusive(d):  # a killed holder leaves no stale lock
        pass


def test_a_directory_made_for_a_failed_command_is_removed(tmp_path):
    d = tmp_path / "new" / "run"
    with pytest.raises(RuntimeError), exclusive(d, create=True):
        raise RuntimeError("failed before writing anything")
    assert not d.exists()


def test_two_trainings_on_one_out_one_wins_and_keeps_its_own_settings(tmp_path):
    out = tmp_path / "run"
    procs = [subprocess.Popen(
        [sys.executable, "-m", "tpo.cli.main", "train", "--map", "small", "--dag", "A>G",
         "--steps", "6144", "--seed", str(seed), "--episodes", "2", "--quiet",
         "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for seed in (1, 2)]
    results = [(p.wait(timeout=300), p.stderr.read()) for p in procs]
    codes = sorted(code for code, _ in results)
    assert codes == [0, 2], results
    winner = next(seed for seed, (code, _) in zip((1, 2), results, strict=True) if code == 0)
    loser_err = next(err for code, err in results if code == 2)
    assert "is in use by another tpo process" in loser_err or "exists; pass --force" \
        in loser_err, loser_err
    assert f"seed = {winner}\n" in (out / "config.toml").read_text()
