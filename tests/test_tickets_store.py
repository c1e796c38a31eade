import json
import sqlite3
import struct
from pathlib import Path

import numpy as np
import pytest
from safetensors.numpy import save_file

from goldenticket.errors import UserError
from goldenticket.rollout import NONFINITE
from goldenticket.store import EpisodeRow, RunStore
from goldenticket.tickets import Ticket, TicketRecord, ticket_id, zero_ticket


def noise(seed=0, shape=(16, 4)):
    return np.random.default_rng(seed).standard_normal(shape).astype(np.float32)


def load_error(path, **kwargs) -> str:
    with pytest.raises(UserError) as info:
        Ticket.load(path, **kwargs)
    message = str(info.value)
    assert "\n" not in message and str(path) in message
    return message


# --- tickets ---------------------------------------------------------------------------------


def test_ticket_round_trip(tmp_path):
    meta = {"policy": "dp-pusht", "method": "cmaes", "budget": 200, "score": np.float32(0.75)}
    ticket = Ticket(noise(), TicketRecord.from_metadata(meta, "t"))
    path = ticket.save(tmp_path / "sub" / "t.safetensors")
    loaded = Ticket.load(path, expected_shape=(16, 4))
    assert loaded.noise.dtype == np.float32
    np.testing.assert_array_equal(loaded.noise, ticket.noise)
    assert loaded.metadata == {**meta, "score": 0.75}
    assert type(loaded.metadata["score"]) is float
    assert loaded.id == ticket.id


def test_ticket_id_stable_and_distinct():
    a = noise(0)
    assert Ticket(a).id == Ticket(a.copy(), TicketRecord(extra={"other": 1})).id == ticket_id(a, None)
    assert Ticket(a.astype(np.float64)).id == Ticket(a).id
    assert len(Ticket(a).id) == 12 and int(Ticket(a).id, 16) >= 0
    assert Ticket(noise(1)).id != Ticket(a).id
    assert zero_ticket((2, 3)).id != zero_ticket((3, 2)).id  # same bytes, different shape


def test_zero_ticket():
    ticket = zero_ticket((8, 2))
    assert ticket.noise.shape == (8, 2) and ticket.noise.dtype == np.float32
    assert not ticket.noise.any()


@pytest.mark.parametrize(
    "bad, match",
    [(np.full((4, 2), np.nan), "NaN"), (np.full((4, 2), np.inf), "inf"), (np.zeros(8), "2-D")],
)
def test_ticket_constructor_validates(bad, match):
    with pytest.raises(UserError, match=match):
        Ticket(bad)


def test_load_missing_file(tmp_path):
    assert "not found" in load_error(tmp_path / "nope.safetensors")


def test_load_truncated_and_junk(tmp_path):
    path = Ticket(noise(), TicketRecord(extra={"a": 1})).save(tmp_path / "t.safetensors")
    path.write_bytes(path.read_bytes()[:-10])
    assert "not a valid safetensors" in load_error(path)
    path.write_bytes(b"definitely not safetensors")
    assert "not a valid safetensors" in load_error(path)


def test_load_without_noise_tensor(tmp_path):
    path = tmp_path / "t.safetensors"
    save_file({"weights": noise()}, str(path))
    assert "no 'noise' tensor" in load_error(path)


def test_load_wrong_dtype(tmp_path):
    path = tmp_path / "t.safetensors"
    save_file({"noise": noise().astype(np.float64)}, str(path))
    assert "F64" in load_error(path)


def test_load_nan(tmp_path):
    path = tmp_path / "t.safetensors"
    bad = noise()
    bad[3, 1] = np.nan
    save_file({"noise": bad}, str(path))
    assert "NaN" in load_error(path)


def test_load_wrong_shape(tmp_path):
    path = Ticket(noise()).save(tmp_path / "t.safetensors")
    message = load_error(path, expected_shape=(8, 4))
    assert "(16, 4)" in message and "(8, 4)" in message
    save_file({"noise": np.zeros(5, np.float32)}, str(path))
    assert "2-D" in load_error(path)


def test_load_bad_metadata(tmp_path):
    path = tmp_path / "t.safetensors"
    save_file({"noise": noise()}, str(path), metadata={"goldenticket": "{oops"})
    assert "JSON" in load_error(path)


@pytest.mark.parametrize("metadata, says", [
    ('{"tasks": 5}', "tasks must be a list of task names, got 5"),
    ('{"tasks": "metaworld/reach-v3 + metaworld/push-v3", "task": "metaworld/reach-v3 + metaworld/push-v3"}',
     "tasks must be a list"),  # a string would match any of its substrings
    ('{"tasks": ["metaworld/reach-v3", 3], "task": "metaworld/reach-v3"}', "tasks must be a list"),
    ('{"tasks": ["metaworld/reach-v3"]}', "has tasks but no task"),
    ('{"task": ["metaworld/reach-v3"]}', "task must be a string, got list"),
    ('{"policy_fingerprint": 7}', "policy_fingerprint must be a string, got int"),
    ('{"max_steps": "150"}', "max_steps must be an integer > 0"),
    ('{"success": 1}', "success must be an import string or null"),
    ("[" * 100_000 + "]" * 100_000, "nested too deeply"),
], ids=["tasks a number", "tasks a string", "tasks with a number", "tasks without task", "task a list",
        "fingerprint a number", "max_steps a string", "success a number", "100k-deep JSON"])
def test_load_metadata_of_the_wrong_types(tmp_path, metadata, says):
    path = tmp_path / "t.safetensors"
    save_file({"noise": noise()}, str(path), metadata={"goldenticket": metadata})
    assert says in load_error(path)


def test_load_checks_the_header_shape_before_reading_the_tensor(tmp_path):
    """A header declaring 2^25 values over a sparse file (the file is as long as the header says,
    but nothing is written): refused from the header, never read."""
    path = tmp_path / "t.safetensors"
    header = json.dumps({"noise": {"dtype": "F32", "shape": [2**13, 2**12], "data_offsets": [0, 2**27]}})
    with path.open("wb") as f:
        f.write(struct.pack("<Q", len(header)) + header.encode())
        f.truncate(8 + len(header) + 2**27)
    assert "holds more than the 16777216 values" in load_error(path)
    assert "(8192, 4096) does not match the policy's expected shape (16, 4)" in load_error(
        path, expected_shape=(16, 4))


# --- run store -------------------------------------------------------------------------------


def row(seed, success=True, ticket_id="abc123abc123", task="push", seed_set="search"):
    return EpisodeRow(ticket_id, task, seed, seed_set, success, 1.5 * seed, 100 + seed, 0.25)


def test_store_resume(tmp_path):
    path = tmp_path / "run.sqlite"
    with RunStore(path) as store:
        assert store.claim_config({"policy": "dp", "budget": 10})
        store.record([row(s) for s in range(3)])
        store.record([row(0, ticket_id="base", seed_set="heldout")])
    with RunStore(path) as store:
        assert store.claim_config({"policy": "dp", "budget": 10})
        assert not store.claim_config({"policy": "dp", "budget": 11})
        assert store.episodes(ticket_id="abc123abc123") == [row(s) for s in range(3)]
        assert store.episodes(ticket_id="abc123abc123", seed_set="heldout") == []
        assert store.episodes(ticket_id="base") == [row(0, ticket_id="base", seed_set="heldout")]


def test_store_replaces_same_episode(tmp_path):
    store = RunStore(tmp_path / "run.sqlite")
    store.record([row(1, success=True), row(2)])
    store.record([row(1, success=False)])
    assert store.episodes() == [row(1, success=False), row(2)]
    store.record([row(1, task="reach")])  # different task: a different episode
    assert len(store.episodes()) == 3


def test_store_filters_and_tasks(tmp_path):
    store = RunStore(tmp_path / "run.sqlite")
    store.record([row(0), row(0, task="reach"), row(1, ticket_id="zero", seed_set="heldout")])
    assert store.episodes(ticket_id="zero") == [row(1, ticket_id="zero", seed_set="heldout")]
    assert store.episodes(seed_set="search", task="reach") == [row(0, task="reach")]
    assert store.episodes(ticket_id="abc123abc123", task="push") == [row(0)]


def test_store_accepts_numpy_scalars(tmp_path):
    store = RunStore(tmp_path / "run.sqlite")
    r = EpisodeRow("base", "push", np.int64(4), "heldout", np.bool_(True), np.float32(2.5), 7, 0.1)
    store.record([r])
    (got,) = store.episodes()
    assert (got.seed, got.success, got.ret) == (4, True, 2.5)
    assert type(got.seed) is int and type(got.success) is bool


def test_store_record_is_one_transaction(tmp_path):
    store = RunStore(tmp_path / "run.sqlite")
    bad = EpisodeRow("base", "push", 1, "search", True, "not a number", 1, 0.0)
    with pytest.raises(ValueError):
        store.record([row(0), bad])
    assert store.episodes() == []


def test_store_rejects_corrupt_and_foreign_files(tmp_path):
    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"this is not a database" * 100)
    foreign = tmp_path / "foreign.sqlite"
    con = sqlite3.connect(foreign)
    con.execute("CREATE TABLE things (x)")
    con.commit()
    con.close()
    for path in (junk, foreign, tmp_path):
        with pytest.raises(UserError) as info:
            RunStore(path)
        assert "\n" not in str(info.value) and str(path) in str(info.value)


def test_ticket_id_names_one_ticket_for_one_policy():
    a = noise(0)
    assert ticket_id(a, "aa@8") != ticket_id(a, "aa@2")
    same = TicketRecord(policy_fingerprint="aa@8")
    assert Ticket(a, TicketRecord(policy_fingerprint="aa@8", extra={"x": 1})).id == Ticket(a, same).id == \
        ticket_id(a, "aa@8")


def test_ambiguous_bundled_ticket_id_lists_the_candidates(tmp_path, monkeypatch):
    from goldenticket import zoo
    from goldenticket.policies import find_ticket

    monkeypatch.setattr(zoo, "BUNDLED_DIR", tmp_path)
    for policy in ("a/flow", "b/flow"):
        Ticket(noise(0)).save(tmp_path / policy / "tickets" / "abcabcabcabc.safetensors")
    with pytest.raises(UserError, match="ambiguous.*a/flow.*b/flow"):
        find_ticket("abcabcabcabc")


def test_ticket_found_for_another_policy_or_task_does_not_fit():
    ticket = Ticket(noise(0), TicketRecord(policy_fingerprint="aa@8", task="metaworld/reach-v3", policy="p"))
    ticket.check_fits("aa@8", "metaworld/reach-v3", "t")
    for fingerprint, task in (("bb@8", "metaworld/reach-v3"), ("aa@8", "metaworld/push-v3")):
        with pytest.raises(UserError, match="allow_transfer runs it anyway"):
            ticket.check_fits(fingerprint, task, "t")
    Ticket(noise(0)).check_fits("bb@8", "metaworld/push-v3", "t")  # made by hand: no provenance


def test_store_of_an_older_version_opens_and_gains_the_new_columns(tmp_path):
    path = tmp_path / "run.sqlite"
    con = sqlite3.connect(path)
    con.executescript("""
        CREATE TABLE config (id INTEGER PRIMARY KEY CHECK (id = 0), value TEXT NOT NULL);
        CREATE TABLE episodes (
            ticket_id TEXT NOT NULL, task TEXT NOT NULL, seed INTEGER NOT NULL, seed_set TEXT NOT NULL,
            success INTEGER NOT NULL, ret REAL NOT NULL, length INTEGER NOT NULL, wall_time REAL NOT NULL,
            PRIMARY KEY (ticket_id, task, seed, seed_set));
        INSERT INTO episodes VALUES ('abc123abc123', 'push', 1, 'search', 1, 1.5, 101, 0.25);
        PRAGMA user_version = 1;""")
    con.close()
    with RunStore(path) as store:
        assert store.episodes() == [row(1)]
        store.record([EpisodeRow("base", "push", 1_000_000, "heldout", False, 0.0, 3, 0.1, NONFINITE)])
        assert store.first_digests("push", [(1, "d1")]) == ["d1"]
    with RunStore(path) as store:
        assert store.episodes(ticket_id="base")[0].cause == NONFINITE
        assert store.first_digests("push", [(1, "other"), (2, "d2"), (2, "d3")]) == ["d1", "d2", "d2"]
        assert store.first_digests("reach", [(1, "other")]) == ["other"]  # seeds are per task


def test_store_with_a_damaged_config_or_return_is_one_line(tmp_path):
    path = tmp_path / "run.sqlite"
    with RunStore(path) as store:
        store.claim_config({"policy": "dp"})
        store.record([row(1), row(2)])
    with sqlite3.connect(path) as con:
        con.execute("UPDATE episodes SET ret = 'lots' WHERE seed = 2")
    with RunStore(path) as store, pytest.raises(UserError) as info:
        store.episodes()
    assert str(path) in str(info.value) and "non-numeric ret ('lots')" in str(info.value)
    with sqlite3.connect(path) as con:
        con.execute("UPDATE config SET value = '{not json'")
    with RunStore(path) as store, pytest.raises(UserError) as info:
        store.claim_config({"policy": "dp"})
    assert str(path) in str(info.value) and "config is not JSON" in str(info.value)


@pytest.mark.parametrize("name", ["run.sqlite", "run.sqlite-journal", "run.sqlite-wal"])
@pytest.mark.parametrize("dangling", [True, False])
def test_store_refuses_a_symbolic_link(tmp_path, name, dangling):
    target = tmp_path / "elsewhere"
    if not dangling:
        target.write_bytes(b"")
    (tmp_path / name).symlink_to(target)
    with pytest.raises(UserError) as info:
        RunStore(tmp_path / "run.sqlite")
    assert str(info.value) == f"{tmp_path / name} is a symbolic link; move it away: a run store and its " \
        "journal are regular files"
    assert target.exists() != dangling and (dangling or target.read_bytes() == b"")


def _damaged_page(path):
    """A run store with one page in the middle overwritten by noise."""
    with RunStore(path) as store:
        store.record([row(s, ticket_id=f"t{s % 50:011d}") for s in range(3000)])
    data = path.read_bytes()
    middle = len(data) // 4096 // 2 * 4096
    path.write_bytes(data[:middle] + np.random.default_rng(0).bytes(4096) + data[middle + 4096:])


def _truncated(path):
    with RunStore(path) as store:
        store.record([row(s) for s in range(3000)])
    path.write_bytes(path.read_bytes()[:100_000])


@pytest.mark.parametrize("damage", [_damaged_page, _truncated,
                                    lambda path: path.write_bytes(np.random.default_rng(0).bytes(5000))])
def test_a_damaged_store_is_one_line_on_the_command_line(tmp_path, tiny_policies, capsys, damage):
    from goldenticket.cli import main

    tiny_policies["flow"].save(tmp_path / "policy")
    out = tmp_path / "run"
    out.mkdir()
    damage(out / "run.sqlite")
    before = (out / "run.sqlite").read_bytes()
    capsys.readouterr()
    code = main(["search", "--policy", str(tmp_path / "policy"), "--task", "metaworld/pick-place-v3",
                 "--budget", "4", "--search-seeds", "2", "--heldout", "2", "--max-steps", "5",
                 "--workers", "1", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert f"{out / 'run.sqlite'}: damaged run store (" in err and "move it away" in err
    assert (out / "run.sqlite").read_bytes() == before


def test_open_folder_says_what_is_in_the_way(tmp_path, monkeypatch):
    from goldenticket.files import open_folder

    monkeypatch.chdir(tmp_path)
    Path("gone").symlink_to("nowhere")
    Path("loop").symlink_to("loop")
    Path("file").write_text("")
    cases = {"": "the output folder's name is empty; name a folder",
             "gone": "output folder gone is a dangling symbolic link (to nowhere); name a folder",
             "loop": "output folder loop is a symbolic link loop; name a folder",
             "loop/run": "output folder loop/run: loop is a symbolic link loop; name a folder",
             "gone/run": "output folder gone/run: gone is a dangling symbolic link (to nowhere); name a "
                         "folder",
             "file": "output folder file is a file; name a folder",
             "file/run": "cannot create output folder file/run: Not a directory"}
    for out, message in cases.items():
        with pytest.raises(UserError) as info:
            open_folder(out)
        assert str(info.value) == message
    assert not Path("nowhere").exists()
    Path("linked").symlink_to("a", target_is_directory=True)
    for out in (Path("a/b"), "a/b", tmp_path / "linked", "linked/c", "."):
        open_folder(out)
        assert Path(out).is_dir()


def test_every_shipped_ticket_reads_into_its_record_and_writes_back_byte_for_byte(tmp_path):
    root = Path(__file__).parents[1]
    shipped = [*(root / "src/goldenticket/policies/bundled").rglob("tickets/*.safetensors"),
               *(root / "benchmarks/results").rglob("*.safetensors")]
    assert len(shipped) > 30
    for path in shipped:
        ticket = Ticket.load(path)
        assert ticket.record.policy_fingerprint and ticket.record.heldout, path
        assert ticket.save(tmp_path / "again.safetensors").read_bytes() == path.read_bytes(), path


def test_a_record_says_how_its_ticket_came():
    from goldenticket.tickets import ZERO_SOURCE

    assert zero_ticket((2, 2)).record.provenance == "zero"
    assert TicketRecord(source=ZERO_SOURCE).provenance == "zero"
    assert TicketRecord(source="given: runs/a/tickets/x.safetensors").provenance == "given"
    assert TicketRecord(method="cma-es", search_score=0.5).provenance == "search"
    assert TicketRecord().provenance == "unknown"  # made by hand
