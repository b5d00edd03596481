"""The sweep engine (tpo.experiments.engine): the driver writes every record, a
restart redoes no finished unit, checkpoints outlive a unit's worker and go once
the unit is recorded, and the local backend runs units in worker processes."""

import json
import os
import socket

import pytest

from tpo.errors import TPOError
from tpo.experiments.engine import (
    Backend,
    FileLink,
    LocalBackend,
    RayBackend,
    Tracker,
    Unit,
    backend,
    run_units,
)


def count_to(n: int, link) -> dict:
    """A unit that counts to ``n``, one step per report, keeping its count in its
    checkpoint: what a resumed attempt starts from."""
    saved = link.load()
    start = 0 if saved is None else int(saved)
    link.progress(start / n)
    for i in range(start + 1, n + 1):
        link.save(str(i).encode())
        link.progress(i / n)
    return {"n": n, "started_at": start, "pid": os.getpid()}


class Inline(Backend):
    """Runs units in the driver's process, in order."""

    def __init__(self):
        self.ran = []

    def run(self, units, tracker, done, folder):
        for u in units:
            self.ran.append(u.name)
            tracker.begin(u.name, os.getpid())
            link = FileLink(u.name, 0.0, folder / f"{u.name}.ckpt",
                            lambda name, f: tracker.progress(name, f))
            done(u.name, u.fn(*u.args, link))


def test_the_driver_writes_each_record_and_a_restart_redoes_nothing_finished(tmp_path):
    units = [Unit(f"u{i}", count_to, (i + 2,)) for i in range(3)]
    folder = tmp_path / "units"
    folder.mkdir()
    (folder / "u1.json").write_text(json.dumps({"n": 3, "earlier": True}))
    (folder / "u2.ckpt").write_text("2")  # a unit a killed sweep left half done
    seen = []
    inline = Inline()
    records = run_units(units, inline, folder, lambda t: seen.append(dict(t.fractions)))
    assert inline.ran == ["u0", "u2"]
    assert records["u1"] == {"n": 3, "earlier": True}
    assert records["u2"]["started_at"] == 2 and records["u0"]["started_at"] == 0
    assert seen[0] == {"u0": 0.0, "u1": 1.0, "u2": 0.0} and seen[-1] == dict.fromkeys(seen[0], 1.0)
    assert sorted(p.name for p in folder.iterdir()) == ["u0.json", "u1.json", "u2.json"]
    assert json.loads((folder / "u0.json").read_text())["n"] == 2
    again = Inline()
    assert run_units(units, again, folder) == records and again.ran == []


def test_the_tracker_records_where_each_attempt_started():
    tracker = Tracker({"a": 0.0})
    tracker.begin("a", 11)
    tracker.progress("a", 0.0)
    tracker.progress("a", 0.5)
    tracker.begin("a", 12)  # the worker died; the unit resumed from its checkpoint
    tracker.progress("a", 0.5)
    tracker.progress("a", 0.25)  # a late report of the dead worker never moves it back
    assert tracker.attempts == {"a": [[11, 0.0], [12, 0.5]]}
    assert tracker.fractions == {"a": 0.5}
    # A Ray unit's result may arrive before its reports: its attempt comes with it.
    tracker = Tracker({"b": 0.0})
    tracker.finished("b", 21, 0.0)
    tracker.begin("b", 21)
    tracker.progress("b", 0.25)
    assert tracker.attempts == {"b": [[21, 0.0]]}


def test_the_local_backend_runs_units_in_worker_processes(tmp_path):
    units = [Unit(f"u{i}", count_to, (3,)) for i in range(3)]
    seen = []
    records = run_units(units, LocalBackend(workers=2, every=0.0), tmp_path,
                        lambda t: seen.append(t))
    assert {r["pid"] for r in records.values()}.isdisjoint({os.getpid()})
    assert len({r["pid"] for r in records.values()}) <= 2
    assert seen[-1].fractions == {"u0": 1.0, "u1": 1.0, "u2": 1.0}
    assert {name: len(a) for name, a in seen[-1].attempts.items()} == {"u0": 1, "u1": 1,
                                                                       "u2": 1}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["u0.json", "u1.json", "u2.json"]


def test_backends_are_named_with_their_own_options(tmp_path):
    assert isinstance(backend("local", 3), LocalBackend) and backend("local", 3).workers == 3
    assert backend("local").workers == 2
    with socket.create_server(("127.0.0.1", 0)) as server:  # something that answers
        address = f"127.0.0.1:{server.getsockname()[1]}"
        ray = backend("ray", address=address, storage=str(tmp_path))
    assert isinstance(ray, RayBackend) and ray.address == address and ray.storage == tmp_path
    assert backend("ray").address == "auto"
    with pytest.raises(TPOError, match=r"^--storage .*nowhere is not a directory$"):
        backend("ray", storage=str(tmp_path / "nowhere"))
    with pytest.raises(TPOError, match=r"^--address and --storage are options of "
                                       r"--backend ray$"):
        backend("local", address="auto")
    with pytest.raises(TPOError, match=r"^--workers must be at least 1$"):
        backend("local", 0)
    with pytest.raises(TPOError, match=r"^--workers is an option of --backend local"):
        backend("ray", 3)


@pytest.mark.parametrize(("address", "message"), [
    ("127.0.0.1:1", r"^cannot connect to the Ray cluster at 127\.0\.0\.1:1: Connection refused$"),
    ("ray://127.0.0.1:1", r"^--address 'ray://127\.0\.0\.1:1': give the cluster's HOST:PORT"),
    ("nohost", r"^--address 'nohost': give the cluster's HOST:PORT"),
])
def test_a_ray_address_that_cannot_answer_fails_at_once_in_one_line(address, message):
    with pytest.raises(TPOError, match=message):
        backend("ray", address=address)


@pytest.mark.parametrize("text", ["{not json", "[1, 2]", "\udcff"])
def test_a_damaged_record_is_named_not_misread(tmp_path, text):
    (tmp_path / "u0.json").write_bytes(text.encode("utf-8", "surrogateescape"))
    with pytest.raises(TPOError, match=r"u0\.json is not a unit's record.*; delete it to run "
                                       r"the unit again$"):
        run_units([Unit("u0", count_to, (2,))], Inline(), tmp_path)
