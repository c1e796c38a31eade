"""A ticket file from someone else runs no code it names: its task or success predicate is used
only when it is a registered task, or the user names it."""

import json
from pathlib import Path

import numpy as np
import pytest
from safetensors.numpy import save_file

import goldenticket
from goldenticket.cli import main
from goldenticket.errors import UserError

HERE = Path(__file__).parent
POLICY = "metaworld/reach-v3/flow"


def shared_ticket(tmp_path, **metadata) -> str:
    path = tmp_path / "shared.safetensors"
    save_file({"noise": np.zeros((8, 4), np.float32)}, str(path),
              metadata={"goldenticket": json.dumps(metadata)})
    return str(path)


@pytest.mark.parametrize("metadata, says", [
    ({"task": "spy:touch"}, "names 'spy:touch', code of its own, as its --task"),
    ({"task": ".spy:touch"}, "names '.spy:touch', code of its own, as its --task"),
    ({"task": "metaworld/reach-v3", "success": "spy:touch"},
     "names 'spy:touch', code of its own, as its --success"),
], ids=["a factory", "a relative import string", "a success predicate"])
def test_evaluate_never_imports_what_a_ticket_names(tmp_path, capsys, monkeypatch, metadata, says):
    (tmp_path / "spy.py").write_text("from pathlib import Path\n"
                                     "def touch(*args):\n    Path(__file__).with_name('ran').touch()\n")
    monkeypatch.chdir(tmp_path)  # where a user's import strings are looked up
    ticket = shared_ticket(tmp_path, **metadata)
    code = main(["evaluate", "--policy", POLICY, "--ticket", ticket, "--seeds", "1000000:1000002"])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and says in err and "give --" in err, err
    assert not (tmp_path / "ran").exists()


def test_a_registered_task_in_a_ticket_is_used(tmp_path):
    ticket = shared_ticket(tmp_path, task="metaworld/reach-v3")
    rows = goldenticket.evaluate(POLICY, tickets=[ticket], seeds=range(1_000_000, 1_000_002), workers=1,
                                 max_steps=20)
    assert len(rows) == 3 and {"base", "zero"} < set(rows)


def test_naming_the_task_runs_it(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(HERE))
    ticket = shared_ticket(tmp_path, task="builtins:print")
    with pytest.raises(UserError, match="noise shape"):  # the user's env is built: the ticket is for others
        goldenticket.evaluate("byo_example:make_exact_policy", "byo_example:make_env", [ticket],
                              range(1_000_000, 1_000_002), workers=1)
