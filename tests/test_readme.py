"""Every command in README runs as written: here (the goldenticket commands, checked against the
numbers README gives for them) or in CI (`.ci/run`: install, tests, docs, LeRobot's venv).
README's Python blocks run in test_byo.py and test_deploy.py."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
README = (ROOT / "README.md").read_text()
RUN_HERE = ("goldenticket demo ", "goldenticket evaluate ", "goldenticket search --policy mine:make_policy ")


def _commands(text: str) -> list[str]:
    """The commands of `text`'s bash blocks (or of a shell script): continuation lines joined,
    comments dropped, spaces collapsed."""
    blocks = re.findall(r"```bash\n(.*?)```", text, re.S) if "```" in text else [text]
    lines = "\n".join(blocks).replace("\\\n", " ").splitlines()
    return [" ".join(line.split()) for line in (re.sub(r"(^|\s)#.*", "", line) for line in lines)
            if line.strip()]


def _ci() -> set[str]:
    """What .ci/run runs: each command and each run of commands joined by && within one, its
    LeRobot venv "$V" and robomimic venv "$R" written as README writes them."""
    script = re.sub(r'"\$V(/[^"]*)?"', r"lerobot-venv\1", (ROOT / ".ci" / "run").read_text())
    script = re.sub(r'"\$R(/[^"]*)?"', r"robomimic-venv\1", script)
    chains = [command.split(" && ") for command in _commands(script)]
    return {" && ".join(c[i:j]) for c in chains for i in range(len(c)) for j in range(i + 1, len(c) + 1)}


def _readme_block(starts: str) -> str:
    """README's bash block whose command starts with `starts`, as written."""
    [block] = [b for b in re.findall(r"```bash\n(.*?)```", README, re.S) if b.startswith(starts)]
    return block


def _run(block: str, cwd: Path) -> str:
    """Runs `block` with the `goldenticket` of the Python running the tests, activated or not."""
    path = f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"
    done = subprocess.run(["bash", "-e", "-c", block], cwd=cwd, capture_output=True, text=True, timeout=1800,
                          env=os.environ | {"PATH": path})
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout


def test_every_readme_command_is_run_here_or_in_ci():
    ci = _ci()
    for command in _commands(README):
        assert command in ci or command.startswith(RUN_HERE), f"README runs nowhere: {command}"
    assert all(sum(c.startswith(p) for c in _commands(README)) == 1 for p in RUN_HERE)


def test_readme_is_a_five_minute_read_whose_links_resolve():
    assert len(README.splitlines()) <= 160
    for link in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", README):
        assert (ROOT / link).is_file(), link


@pytest.mark.slow
def test_readme_demo_and_its_fresh_seed_check_print_what_readme_says(tmp_path):
    verdict = re.search(r"```text\n(.*?)```", README, re.S).group(1)
    assert verdict in _run(_readme_block("goldenticket demo "), tmp_path)
    printed = _run(_readme_block("goldenticket evaluate "), tmp_path)
    said = re.search(r"It gives the ticket (\S+ \[.*?\]) against the base's (\S+ \[.*?\]) \(p = (\S+)\)\.",
                     README)
    ticket, base, p = said.groups()
    ticket_id = re.search(r"--ticket demo-out/tickets/(\w{12})\.safetensors", README).group(1)
    assert re.search(rf"ticket {ticket_id} +{re.escape(ticket).replace(' ', ' +')} +300 +{p} ", printed)
    assert re.search(rf"base +{re.escape(base).replace(' ', ' +')} +300 ", printed)
    spent = json.loads((tmp_path / "demo-out" / "summary.json").read_text())["search_episodes"]
    assert f"(it spends {spent}:" in " ".join(README.split())  # what the search spends, not only its budget
    deploy = re.search(r"## Deploy a ticket.*?```python\n(.*?)```", README, re.S).group(1)
    assert f"demo-out/tickets/{ticket_id}.safetensors" in deploy  # the ticket the demo wrote, deployed
    assert re.fullmatch(r"\(8, 4\) 4 (True|False) \d+\n", _run(f"python - <<'EOF'\n{deploy}EOF", tmp_path))


@pytest.mark.slow
def test_readme_own_policy_search_prints_what_readme_says(tmp_path):
    section = README.split("## Use your own policy")[1]
    (tmp_path / "mine.py").write_text(re.search(r"```python\n(.*?)```", section, re.S).group(1))
    printed = _run(_readme_block("goldenticket search --policy mine:make_policy "), tmp_path)
    said = re.search(r"golden ticket: (\S+ \[.*?\]) on 100 held-out seeds, against\s+(\S+) for the base and "
                     r"(\S+) for the zero ticket \(p = (\S+)\)", section)
    ticket, base, zero, p = said.groups()
    assert re.search(rf"base +{re.escape(base)} ", printed) and re.search(rf"zero ticket +{re.escape(zero)} ",
                                                                             printed)
    assert re.search(rf"ticket \w{{12}} +{re.escape(ticket).replace(' ', ' +')} +100 +{p} ", printed)
