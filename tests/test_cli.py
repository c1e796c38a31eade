import json
import subprocess
import sys

import numpy as np
import pytest
from safetensors.numpy import save_file

from goldenticket.cli import main
from goldenticket.tickets import Ticket

TASK = "metaworld/pick-place-v3"


@pytest.fixture(scope="module")
def policy_dir(tiny_policies, tmp_path_factory):
    path = tmp_path_factory.mktemp("policy")
    tiny_policies["flow"].save(path)
    return str(path)


def _search(policy_dir, out, workers):
    return main(["search", "--policy", policy_dir, "--task", TASK, "--method", "cem-racing",
                 "--budget", "12", "--search-seeds", "5", "--heldout", "4", "--top-k", "2",
                 "--workers", str(workers), "--out", str(out)])


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
    assert {"ticket_id", "p_value", "verdict", "ticket_path"} <= summary["best"].keys()
    ticket = Ticket.load(summary["best"]["ticket_path"])
    assert ticket.id == summary["best"]["ticket_id"]
    assert ticket.metadata["heldout"]["n"] == 4
    assert (search_run / "run.sqlite").is_file()


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


def test_evaluate_json_and_tickets_show(search_run, policy_dir, capsys):
    path = json.loads((search_run / "summary.json").read_text())["best"]["ticket_path"]
    capsys.readouterr()
    assert main(["evaluate", "--policy", policy_dir, "--task", TASK, "--ticket", path,
                 "--seeds", "1000100:1000103", "--workers", "1", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    ticket_id = Ticket.load(path).id
    assert set(rows) == {"base", "zero", ticket_id}
    assert rows[ticket_id]["n"] == 3 and "p_value" in rows[ticket_id]
    assert main(["tickets", "show", path]) == 0
    assert ticket_id in capsys.readouterr().out


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


def test_bad_inputs_exit_2_with_one_line(policy_dir, search_run, tmp_path):
    files = _bad_ticket_files(tmp_path)
    ticket = json.loads((search_run / "summary.json").read_text())["best"]["ticket_path"]
    evaluate = ["evaluate", "--policy", policy_dir, "--task", TASK, "--seeds", "1000000:1000002"]
    cases = {
        "unknown policy": ["evaluate", "--policy", "nope/x/flow", "--task", TASK, "--seeds", "0:2"],
        "unknown task": ["evaluate", "--policy", policy_dir, "--task", "metaworld/x", "--seeds",
                         "0:2"],
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
    for name, argv in cases.items():
        proc = subprocess.run([sys.executable, "-m", "goldenticket.cli", *argv],
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 2, (name, proc.stderr)
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in proc.stderr, (name, proc.stderr)


def test_policies_lists_bundled_policies_with_measured_numbers(capsys):
    assert main(["policies"]) == 0
    out = capsys.readouterr().out
    assert "metaworld/pick-place-v3/flow " in out and "%" in out


def test_bundled_tickets_are_listed_and_found_by_id(search_run, capsys, monkeypatch, tmp_path):
    from goldenticket.policies import registry

    monkeypatch.setattr(registry, "BUNDLED_DIR", tmp_path)
    assert main(["tickets", "list"]) == 0 and "No bundled tickets" in capsys.readouterr().out
    ticket = Ticket.load(json.loads((search_run / "summary.json").read_text())["best"]["ticket_path"])
    ticket.save(tmp_path / "a" / "flow" / "tickets" / f"{ticket.id}.safetensors")
    assert main(["tickets", "list"]) == 0
    listing = capsys.readouterr().out
    assert ticket.id in listing and "1000000:1000004" in listing
    assert main(["tickets", "show", ticket.id]) == 0 and ticket.id in capsys.readouterr().out
    assert main(["tickets", "show", "000000000000"]) == 2
