import json
import os
import warnings

import numpy as np
import pytest
from safetensors.numpy import save_file

from goldenticket.cli import main
from goldenticket.tickets import ZERO_SOURCE, Ticket, TicketRecord

TASK = "metaworld/pick-place-v3"


def _search(policy_dir, out, workers):
    return main(["search", "--policy", policy_dir, "--task", TASK, "--method", "cem-racing",
                 "--budget", "12", "--search-seeds", "5", "--validation-seeds", "3", "--heldout", "4",
                 "--top-k", "2", "--max-steps", "50", "--workers", str(workers), "--out", str(out)])


@pytest.fixture(scope="module")
def search_run(policy_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    assert _search(policy_dir, out, workers=1) == 0
    return out


def test_search_writes_summary_tickets_and_store(search_run):
    summary = json.loads((search_run / "summary.json").read_text())
    assert summary["task"] == TASK and summary["search_episodes"] <= 12
    for key in ("base", "zero", "best"):
        assert {"success_rate", "ci_low", "ci_high", "n"} <= summary[key].keys()
    assert {"ticket_id", "p_vs_base", "p_vs_zero", "verdict", "ticket_path"} <= summary["best"].keys()
    assert "p_value" not in summary["best"] and "p_vs_base" not in summary["base"]
    ticket = Ticket.load(summary["best"]["ticket_path"])
    assert ticket.id == summary["best"]["ticket_id"]
    assert ticket.metadata["heldout"]["n"] == 4
    assert (search_run / "run.sqlite").is_file()


@pytest.mark.slow
def test_same_command_same_numbers_in_process_or_pool(search_run, policy_dir, tmp_path):
    assert _search(policy_dir, tmp_path, workers=2) == 0
    first = json.loads((search_run / "summary.json").read_text())
    second = json.loads((tmp_path / "summary.json").read_text())
    strip = lambda s: {k: v for k, v in s.items() if k not in ("best", "tickets")}  # noqa: E731
    assert strip(first) == strip(second)
    assert [t["ticket_id"] for t in first["tickets"]] == [t["ticket_id"] for t in second["tickets"]]


def test_rerun_resumes_from_the_store(search_run, policy_dir):
    before = (search_run / "summary.json").read_text()
    assert _search(policy_dir, search_run, workers=1) == 0
    assert (search_run / "summary.json").read_text() == before


def test_search_picture_names_the_heldout_seeds_as_the_cli_takes_them(search_run, policy_dir, monkeypatch):
    from goldenticket import plots

    figures = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: figures.append(fig) or path)
    assert _search(policy_dir, search_run, workers=1) == 0  # resumed: only the pictures are drawn again
    assert figures[-1].axes[1].get_title(loc="left") == "judged on held-out seeds 1000000:1000004"


def test_evaluate_json_and_tickets_show(search_run, policy_dir, capsys, tmp_path):
    path = json.loads((search_run / "summary.json").read_text())["best"]["ticket_path"]
    capsys.readouterr()
    evaluate = ["evaluate", "--policy", policy_dir, "--task", TASK, "--ticket", path,
                "--seeds", "1000100:1000103", "--workers", "1", "--plot", str(tmp_path / "e.png")]
    assert main([*evaluate, "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    ticket_id = Ticket.load(path).id
    assert set(rows) == {"base", "zero", ticket_id}
    assert rows[ticket_id]["n"] == 3 and {"p_vs_base", "p_vs_zero"} <= rows[ticket_id].keys()
    assert main(evaluate) == 0
    text = capsys.readouterr().out
    assert f"ticket {ticket_id}" in text and "No golden ticket" in text and (tmp_path / "e.png").is_file()
    assert main(["tickets", "show", path]) == 0
    assert ticket_id in capsys.readouterr().out


def test_search_writes_pictures_with_the_users_umask(search_run):
    assert {"verdict.png", "search.png"} <= {p.name for p in search_run.iterdir()}
    assert (search_run / "verdict.png").read_bytes().startswith(b"\x89PNG")
    umask = os.umask(0)
    os.umask(umask)
    files = [p for p in search_run.rglob("*") if p.is_file() and p.name != "run.sqlite"]  # SQLite's own
    assert files and all(p.stat().st_mode & 0o777 == 0o666 & ~umask for p in files), files


def test_help_says_defaults_and_version(capsys):
    with pytest.raises(SystemExit):
        main(["search", "--help"])
    help_text = capsys.readouterr().out
    assert "(default: portfolio)" in help_text and "(default: 200)" in help_text
    with pytest.raises(SystemExit):
        main(["--version"])
    assert capsys.readouterr().out.startswith("goldenticket 0.")


def test_listings_as_json(capsys):
    assert main(["policies", "--json"]) == 0
    cards = json.loads(capsys.readouterr().out)
    assert len(cards) >= 20 and {"policy", "base", "zero"} <= cards[0].keys()
    assert main(["tickets", "list", "--json"]) == 0
    tickets = json.loads(capsys.readouterr().out)
    assert tickets and {"id", "path", "policy", "task", "heldout"} <= tickets[0].keys()


def test_huge_ticket_shows_without_warnings(tmp_path, capsys):
    path = Ticket(np.full((8, 4), 1e30, np.float32)).save(tmp_path / "huge.safetensors")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert main(["tickets", "show", str(path)]) == 0
    assert "5.657e+30" in capsys.readouterr().out


def test_transfer_needs_the_flag(search_run, policy_dir, tmp_path, capsys):
    ticket = Ticket.load(json.loads((search_run / "summary.json").read_text())["best"]["ticket_path"])
    evaluate = ["evaluate", "--policy", policy_dir, "--seeds", "1000000:1000002", "--workers", "1",
                "--plot", str(tmp_path / "e.png"), "--ticket", str(ticket.save(tmp_path / "t.safetensors"))]
    assert main([*evaluate, "--task", "metaworld/reach-v3"]) == 2
    assert "--allow-transfer" in capsys.readouterr().err
    assert main([*evaluate, "--task", "metaworld/reach-v3", "--allow-transfer"]) == 0


def _bad_ticket_files(tmp_path):
    files = {}
    save_file({"noise": np.zeros((3, 4), np.float32)}, str(tmp_path / "shape.safetensors"))
    files["shape"] = tmp_path / "shape.safetensors"
    nan = np.zeros((8, 4), np.float32)
    nan[0, 0] = np.nan
    save_file({"noise": nan}, str(tmp_path / "nan.safetensors"))
    files["nan"] = tmp_path / "nan.safetensors"
    (tmp_path / "corrupt.safetensors").write_bytes(b"\x00\x01garbage")
    files["corrupt"] = tmp_path / "corrupt.safetensors"
    return files


def test_bad_inputs_exit_2_with_one_line(policy_dir, search_run, tmp_path, capsys):
    files = _bad_ticket_files(tmp_path)
    ticket = json.loads((search_run / "summary.json").read_text())["best"]["ticket_path"]
    evaluate = ["evaluate", "--policy", policy_dir, "--task", TASK, "--seeds", "1000000:1000002"]
    other_policy = Ticket(np.zeros((8, 4)), TicketRecord(policy_fingerprint="0123@4", policy="x"))
    cases = {
        "unknown policy": ["evaluate", "--policy", "nope/x/flow", "--task", TASK, "--seeds",
                           "1000000:1000002"],
        "unknown task": ["evaluate", "--policy", policy_dir, "--task", "metaworld/x", "--seeds",
                         "1000000:1000002"],
        "negative seed range": evaluate[:-1] + ["-5:3"],
        "search seeds without ticket": evaluate[:-1] + ["0:1"],
        "seeds outside every set": evaluate[:-1] + ["3000000:3000001"],
        "no workers": evaluate + ["--workers", "0"],
        "negative workers": evaluate + ["--workers", "-1"],
        "ticket of another policy": evaluate + ["--ticket",
                                                str(other_policy.save(tmp_path / "o.safetensors"))],
        "search_seeds not a list": evaluate + ["--ticket", str(_with_search_seeds(tmp_path, "ab"))],
        "search_seeds of one seed": evaluate + ["--ticket", str(_with_search_seeds(tmp_path, [5]))],
        "wrong ticket shape": evaluate + ["--ticket", str(files["shape"])],
        "nan ticket": evaluate + ["--ticket", str(files["nan"])],
        "corrupt ticket": evaluate + ["--ticket", str(files["corrupt"])],
        "missing ticket": evaluate + ["--ticket", str(tmp_path / "none.safetensors")],
        "overlapping seeds": ["evaluate", "--policy", policy_dir, "--task", TASK, "--seeds",
                              "0:3", "--ticket", ticket],
        "training seeds": evaluate[:-1] + ["2000000:2000003"],
        "bad seed range": evaluate[:-1] + ["5:2"],
        "zero budget": ["search", "--policy", policy_dir, "--task", TASK, "--budget", "0",
                        "--out", str(tmp_path / "o")],
        "bad step count": ["search", "--policy", policy_dir + "@0", "--task", TASK, "--budget", "5",
                           "--out", str(tmp_path / "o")],
        "unknown ticket id": evaluate + ["--ticket", "abcdef123456"],
        "unknown method": ["search", "--policy", policy_dir, "--task", TASK, "--budget", "5",
                           "--method", "magic", "--out", str(tmp_path / "o")],
    }
    for name, argv in cases.items():  # in this process: an exception would fail the test
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse's own errors
            code = exc.code
        err = capsys.readouterr().err
        assert code == 2 and len(err.strip().splitlines()) == 1, (name, err)


def _with_search_seeds(tmp_path, span):
    path = tmp_path / f"seeds{len(span)}.safetensors"  # written raw: a bad span must reach Ticket.load
    save_file({"noise": np.zeros((8, 4), np.float32)}, str(path), metadata={"goldenticket": json.dumps(
        {"search_seeds": span})})
    return path


def test_policies_lists_bundled_policies_with_measured_numbers(capsys):
    assert main(["policies"]) == 0
    out = capsys.readouterr().out
    assert "metaworld/pick-place-v3/flow " in out and "%" in out


def test_bundled_tickets_are_listed_and_found_by_id(search_run, capsys, monkeypatch, tmp_path):
    from goldenticket import zoo

    monkeypatch.setattr(zoo, "BUNDLED_DIR", tmp_path)
    assert main(["tickets", "list"]) == 0 and "No bundled tickets" in capsys.readouterr().out
    ticket = Ticket.load(json.loads((search_run / "summary.json").read_text())["best"]["ticket_path"])
    ticket.save(tmp_path / "a" / "flow" / "tickets" / f"{ticket.id}.safetensors")
    assert main(["tickets", "list"]) == 0
    listing = capsys.readouterr().out
    assert ticket.id in listing and "1000000:1000004" in listing
    assert main(["tickets", "show", ticket.id]) == 0 and ticket.id in capsys.readouterr().out
    assert main(["tickets", "show", "000000000000"]) == 2


def test_tickets_written_before_p_vs_base_list_the_same(search_run):
    """Older files (the bundled tickets among them) call the p-value against the base `p_value`."""
    from goldenticket.report import ticket_table

    ticket = Ticket.load(json.loads((search_run / "summary.json").read_text())["best"]["ticket_path"])
    held = ticket.record.heldout
    old = ticket.with_record(heldout={k: v for k, v in held.items() if k != "p_vs_base"} | {
        "p_value": held["p_vs_base"]})
    assert ticket_table([old]) == ticket_table([ticket])


def test_a_shipped_zero_ticket_lists_without_a_search_score(search_run):
    from goldenticket.report import ticket_table

    ticket = Ticket.load(json.loads((search_run / "summary.json").read_text())["best"]["ticket_path"])
    zero = ticket.with_record(search_score=None, source=ZERO_SOURCE)
    assert ticket_table([zero]).splitlines()[1].split()[2] == "-"


def test_a_ticket_named_twice_is_judged_once(search_run, policy_dir, tmp_path, capsys):
    path = json.loads((search_run / "summary.json").read_text())["best"]["ticket_path"]
    capsys.readouterr()
    assert main(["evaluate", "--policy", policy_dir, "--task", TASK, "--ticket", path, "--ticket", path,
                 "--seeds", "1000100:1000102", "--workers", "1", "--plot", str(tmp_path / "e.png"),
                 "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert len(rows) == 3


def test_absurd_worker_counts_are_refused(policy_dir, capsys):
    for workers in ("0", "100000"):
        assert main(["evaluate", "--policy", policy_dir, "--task", TASK, "--seeds", "1000000:1000002",
                     "--workers", workers]) == 2
        assert "--workers must be between 1" in capsys.readouterr().err
