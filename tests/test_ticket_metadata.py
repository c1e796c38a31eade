import json

import numpy as np
import pytest
from safetensors.numpy import save_file

from goldenticket.cli import main
from goldenticket.errors import UserError
from goldenticket.tickets import Ticket


def _saved(tmp_path, metadata: dict):
    path = tmp_path / "t.safetensors"
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
