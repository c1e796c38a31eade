"""Run and session folders: nothing is written or removed outside the folder named, nor any file
the command did not write itself, whatever the folder holds (another run, links, a forged store)."""

import csv
import os
import sqlite3
from dataclasses import astuple

import numpy as np
import pytest

from goldenticket.cli import main
from goldenticket.errors import UserError
from goldenticket.session import Plan, Session
from goldenticket.session.server import make_app
from goldenticket.tickets import Ticket, TicketRecord
from goldenticket.tracking import COLUMNS, CsvSink, Row

POLICY, TASK = "metaworld/pick-place-v3/flow", "metaworld/pick-place-v3"


def _plan(**kw) -> Plan:
    fields = dict(policy="p", policy_fingerprint="fp", noise_shape=(8, 4), tickets=3,
                  episodes_per_ticket=2, confirm=3, seed=0, stopping="fixed") | kw
    return Plan(**fields)


def _ticket_file(path) -> bytes:
    """A ticket file at `path`, as a search writes one; returns its bytes."""
    noise = np.random.default_rng(len(str(path))).standard_normal((8, 4)).astype(np.float32)
    return Ticket(noise, TicketRecord(policy="p", policy_fingerprint="fp")).save(path).read_bytes()


def _contents(folder) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in folder.iterdir()}


def _one_error_line(capsys) -> str:
    errors = [line for line in capsys.readouterr().err.splitlines() if line]
    assert len(errors) == 1 and errors[0].startswith("goldenticket: error: "), errors
    return errors[0]


def _files(folder) -> dict[str, bytes]:
    """Every file's bytes under `folder`, by its path there."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def _search_run(folder) -> None:
    """What `search --out folder` leaves: its store, summary.json, verdict.png and tickets."""
    (folder / "tickets").mkdir(parents=True)
    sqlite3.connect(folder / "run.sqlite").execute("CREATE TABLE config (value TEXT)").connection.commit()
    (folder / "summary.json").write_text('{"task": "metaworld/pick-place-v3"}\n')
    (folder / "verdict.png").write_bytes(b"\x89PNG")
    for name in ("0123456789ab", "ba9876543210"):
        _ticket_file(folder / "tickets" / f"{name}.safetensors")


def test_session_new_refuses_a_search_run_folder_and_removes_nothing(tmp_path, capsys):
    run = tmp_path / "run"
    _search_run(run)
    files = _files(run)
    assert main(["session", "new", "--policy", POLICY, "--out", str(run), "--tickets", "2",
                 "--episodes-per-ticket", "1", "--confirm", "1", "--stopping", "fixed"]) == 2
    assert "holds another run" in _one_error_line(capsys)
    assert _files(run) == files


@pytest.mark.parametrize("name", ["run.sqlite", "summary.json", "verdict.png", "tickets"])
def test_session_new_refuses_any_file_of_another_run(tmp_path, name):
    _search_run(tmp_path / "run")
    only = tmp_path / "only"
    only.mkdir()
    os.rename(tmp_path / "run" / name, only / name)
    files = _files(only)
    with pytest.raises(UserError, match=f"holds another run.*{name}"):
        Session.new(only, _plan())
    assert _files(only) == files


def test_a_session_removes_only_ticket_files_of_its_own_candidates(tmp_path):
    session = Session.new(tmp_path, _plan())
    tickets = tmp_path / "tickets"
    foreign = {f"{name}.safetensors": _ticket_file(tickets / f"{name}.safetensors")
               for name in ("0123456789ab", "notes")}
    _ticket_file(tickets / f"{session.scores()[0]['arm']}.safetensors")  # a candidate, not a finalist
    session.status()
    assert _contents(tickets) == foreign
    while (due := session.next()) is not None:
        session.score(due.episode, due.ticket_id != "base")
    finalists = {f"{arm}.safetensors" for arm in session.verdict().arms if arm != "base"}
    assert len(finalists) == 2 and _contents(tickets).keys() == finalists | foreign.keys()
    assert foreign.items() <= _contents(tickets).items()


def _linked_tickets(folder, candidate: str):
    """folder/tickets made a symbolic link to a folder elsewhere holding a file named after one of the
    session's candidates and one of another run; returns that folder and its files."""
    elsewhere = folder.parent / "elsewhere"
    elsewhere.mkdir()
    for name in (candidate, "0123456789ab"):
        _ticket_file(elsewhere / f"{name}.safetensors")
    if (folder / "tickets").exists():
        (folder / "tickets").rmdir()
    (folder / "tickets").symlink_to(elsewhere, target_is_directory=True)
    return elsewhere, _contents(elsewhere)


def test_a_symlinked_tickets_folder_is_refused_and_nothing_behind_it_touched(tmp_path, capsys):
    folder = tmp_path / "cup"
    candidate = Session.new(folder, _plan()).scores()[0]["arm"]
    elsewhere, files = _linked_tickets(folder, candidate)
    assert main(["session", "score", str(folder)]) == 2
    assert "symbolic link" in _one_error_line(capsys)
    for open_it in (Session, make_app):
        with pytest.raises(UserError, match="symbolic link"):
            open_it(folder)
    assert _contents(elsewhere) == files


def test_session_new_refuses_a_symlinked_tickets_folder(tmp_path):
    folder = tmp_path / "cup"
    folder.mkdir()
    (tmp_path / "empty").mkdir()
    (folder / "tickets").symlink_to(tmp_path / "empty", target_is_directory=True)
    with pytest.raises(UserError, match="symbolic link"):
        Session.new(folder, _plan())
    assert not (folder / "session.sqlite").exists()


def _forge(folder, *statements: str) -> None:
    with sqlite3.connect(folder / "session.sqlite") as con:
        for sql in statements:
            con.execute(sql)


@pytest.mark.parametrize("forged", [
    ["UPDATE arms SET arm = '../../x' WHERE rowid = 1",
     "UPDATE episodes SET arm = '../../x' WHERE episode = 0"],
    ["UPDATE arms SET arm = 'ABCDEF012345' WHERE rowid = 1"],
    ["UPDATE arms SET arm = '0123456789abc' WHERE rowid = 1"],
    ["UPDATE episodes SET arm = '/tmp/x' WHERE episode = 0"],
    ["UPDATE arms SET noise = x'00' WHERE rowid = 1"],
    ["UPDATE arms SET noise = x'00' WHERE arm = 'base'"],
], ids=["path", "upper case", "too long", "episode of no arm", "short noise", "noisy base"])
def test_a_forged_session_store_is_refused_in_one_line(tmp_path, capsys, forged):
    folder = tmp_path / "a" / "b" / "cup"
    Session.new(folder, _plan())
    _forge(folder, *forged)
    assert main(["session", "score", str(folder)]) == 2
    assert "damaged" in _one_error_line(capsys)
    assert {p.name for p in tmp_path.rglob("*") if p.is_file()} <= {"session.sqlite", "session.sqlite-wal",
                                                                     "session.sqlite-shm"}


def test_a_forged_finalist_name_writes_nothing_outside_the_folder(tmp_path):
    folder = tmp_path / "cup"
    session = Session.new(folder, _plan())
    for episode in range(6):
        session.score(episode, episode % 2 == 0)
    session.next()  # plans the confirm phase and writes the finalists' tickets
    finalist = next(r["arm"] for r in session.scores() if r["phase"] == "confirm" and r["arm"] != "base")
    _forge(folder, f"UPDATE arms SET arm = '../../x' WHERE arm = '{finalist}'",
           f"UPDATE episodes SET arm = '../../x' WHERE arm = '{finalist}'")
    (folder / "tickets" / f"{finalist}.safetensors").unlink()
    with pytest.raises(UserError, match="damaged"):
        Session(folder)
    assert not (tmp_path / "x.safetensors").exists()


def test_search_refuses_a_symlinked_tickets_folder_before_any_episode(policy_dir, tmp_path, capsys):
    out, elsewhere = tmp_path / "run", tmp_path / "elsewhere"
    elsewhere.mkdir()
    out.mkdir()
    (out / "tickets").symlink_to(elsewhere, target_is_directory=True)
    assert main(["search", "--policy", policy_dir, "--task", TASK, "--budget", "4", "--search-seeds", "2",
                 "--validation-seeds", "0", "--heldout", "2", "--max-steps", "10", "--out", str(out)]) == 2
    assert "symbolic link" in _one_error_line(capsys)
    assert not any(elsewhere.iterdir()) and not (out / "run.sqlite").exists()


def test_log_csv_is_never_written_through_a_hard_link(tmp_path):
    kept = tmp_path / "kept.txt"
    kept.write_text("someone else's file\n")
    os.link(kept, tmp_path / "log.csv")
    sink = CsvSink(tmp_path / "log.csv")
    row = Row("search", 1, 4, "", "0123456789ab", "score", 0.5)
    sink.write([row])
    with (tmp_path / "log.csv").open(newline="") as f:  # rows are there as they are written
        assert list(csv.reader(f)) == [list(COLUMNS), list(map(str, astuple(row)))]
    sink.write([row])
    sink.close()
    assert kept.read_text() == "someone else's file\n" and os.stat(kept).st_nlink == 1
    assert len((tmp_path / "log.csv").read_text().splitlines()) == 3
    again = CsvSink(tmp_path / "log.csv")  # a rerun writes its log from the start
    again.close()
    assert (tmp_path / "log.csv").read_text().splitlines() == [",".join(COLUMNS)]
