"""Import strings `package.module:factory` that cannot name a module fail in one line."""

import pytest

from goldenticket.cli import main
from goldenticket.errors import UserError
from goldenticket.factories import resolve

POLICY = "metaworld/reach-v3/flow"


@pytest.mark.parametrize("name", [".x:y", "..x:y", ".:y", "..pkg.mod:factory"])
def test_a_relative_import_string_is_a_user_error(name):
    with pytest.raises(UserError, match=rf"task '{name}': import string {name} is relative; name the "
                                        "module by its full path, package.module:factory"):
        resolve(name, "task")


@pytest.mark.parametrize("option, name", [("--task", ".x:y"), ("--policy", "..x:y")])
def test_a_relative_import_string_on_the_command_line_is_one_line(capsys, option, name):
    given = {"--policy": POLICY, "--task": "metaworld/reach-v3", option: name}
    code = main(["evaluate", *[w for pair in given.items() for w in pair], "--seeds", "1000000:1000002",
                 "--workers", "1"])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert f"import string {name} is relative" in err, err


def test_a_module_that_raises_while_imported_is_one_line_naming_its_line(tmp_path, monkeypatch):
    (tmp_path / "broken_env.py").write_text("x = 1\nraise RuntimeError('no display')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(UserError) as info:
        resolve("broken_env:make", "task")
    message = str(info.value)
    assert "\n" not in message and "broken_env.py:2" in message and "RuntimeError: no display" in message
