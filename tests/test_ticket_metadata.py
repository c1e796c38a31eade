import json

import numpy as np
import pytest
from safetensors.numpy import save_file

from goldenticket.cli import main
from goldenticket.errors import UserError
from goldenticket.tickets import Ticket


def _saved(tmp_path, metadata: dict, name: str = "t"):
    path = tmp_path / f"{name}.safetensors"
    save_file({"noise": np.zeros((8, 4), np.float32)}, str(path),
              metadata={"goldenticket": json.dumps(metadata)})
    return path


@pytest.mark.parametrize("shape", [[7, 4], [4, 8], "abc", [8, 4, 1], [8], [8.0, 4], [True, 4], [-8, 4], {}])
def test_a_noise_shape_that_contradicts_the_tensor_is_refused(tmp_path, shape):
    path = _saved(tmp_path, {"noise_shape": shape})
    with pytest.raises(UserError) as info:
        Ticket.load(path)
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"{path}: metadata noise_shape")


@pytest.mark.parametrize("metadata", [{"noise_shape": [8, 4]}, {"noise_shape": None}, {}])
def test_a_noise_shape_that_matches_the_tensor_loads(tmp_path, metadata):
    assert Ticket.load(_saved(tmp_path, metadata)).noise.shape == (8, 4)


@pytest.mark.parametrize("metadata", [{"policy": "metaworld/reach-v3/flow\x1b[2J\x1b[31m"},
                                      {"task": "reach\x1b]0;title\x07"}, {"tasks": ["a", "b\x1b[A"]}])
def test_metadata_with_terminal_control_codes_is_refused_without_printing_them(tmp_path, capsys, metadata):
    path = _saved(tmp_path, metadata)
    for argv in (["tickets", "show", str(path)],
                 ["evaluate", "--policy", "metaworld/reach-v3/flow", "--ticket", str(path),
                  "--seeds", "1000000:1000002"]):
        assert main(argv) == 2
        out, err = capsys.readouterr()
        assert "\x1b" not in out + err and "\x07" not in out + err
        assert err.count("\n") == 1 and "printable" in err


def test_evaluate_runs_a_ticket_under_the_env_options_it_was_found_with(tmp_path, monkeypatch, capsys):
    """As its rename_map and policy_override: the ticket's env_option where evaluate is given none, the
    one given where it is; tickets found under different ones need one given."""
    from goldenticket.job import evaluate

    def built(task, max_steps, success, env_options):
        raise UserError(f"built {task} with {env_options}")

    monkeypatch.setattr(evaluate, "get_task", built)
    found = {"control_mode": "absolute", "observation_height": 128}
    ticket = str(_saved(tmp_path, {"task": "libero/object/0", "env_option": found}))
    relative = {"task": "libero/object/0", "env_option": {"control_mode": "relative"}}
    other = str(_saved(tmp_path, relative, "u"))
    for tickets, given, says in (([ticket], [], f"built libero/object/0 with {found}"),
                                 ([ticket], ["--env-option", "control_mode=relative"],
                                  "built libero/object/0 with {'control_mode': 'relative'}"),
                                 ([ticket, other], [], "the tickets were found under different --env-option; "
                                                       "give --env-option")):
        argv = ["evaluate", "--policy", "metaworld/reach-v3/flow", "--seeds", "1000000:1000002", *given]
        assert main(argv + [arg for path in tickets for arg in ("--ticket", path)]) == 2
        assert capsys.readouterr().err == f"goldenticket: error: {says}\n"
