"""The documentation a user reads: README short, every link and anchor resolving, every quoted command alive.

README is the front door (at most 300 lines); the rest lives in docs/. A link that points nowhere, an
anchor whose heading was renamed, or a command in README whose option no longer exists is a defect a
reader meets first, so each is checked here: the links by :mod:`doclinks`, the commands by running them
as README quotes them with ``--help`` (nothing starts, nothing is written) and finding every option the
quoted line uses in that help.
"""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from doclinks import anchors, broken_links, links, slug

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
PAGES = sorted([README, ROOT / "CONTRIBUTING.md", ROOT / "BENCHMARKS.md", ROOT / "recordings" / "README.md",
                *(ROOT / "docs").glob("*.md")])
BIN = Path(sys.executable).parent
#: What a README command starts with -> the executable whose --help lists its options.
COMMANDS = {"./scripts/demo": BIN / "nni-demo", "./scripts/test": None, ".venv/bin/nni-simulate": BIN / "nni-simulate",
            ".venv/bin/nni-demo": BIN / "nni-demo", ".venv/bin/nni-replay": BIN / "nni-replay"}


def test_readme_is_a_front_door_of_at_most_300_lines():
    assert len(README.read_text().splitlines()) <= 300


def test_every_page_is_reachable_from_the_documentation_index():
    index = (ROOT / "docs" / "index.md").read_text()
    linked = {target.partition("#")[0] for _, target in links(index)}
    pages = {path.name for path in (ROOT / "docs").glob("*.md")} - {"index.md"}
    assert pages <= linked, f"docs pages not in docs/index.md: {sorted(pages - linked)}"


@pytest.mark.parametrize("page", PAGES, ids=lambda page: str(page.relative_to(ROOT)))
def test_every_relative_link_and_anchor_resolves(page):
    assert page.exists(), f"{page.relative_to(ROOT)} is missing"
    assert broken_links(page, ROOT) == []


def test_the_link_check_sees_a_broken_anchor_and_a_missing_file(tmp_path):
    """The check itself: a renamed heading and a moved file are found, code is not read as text."""
    (tmp_path / "other.md").write_text("# Other page\n\n## A `code` heading, with: punctuation\n")
    page = tmp_path / "page.md"
    page.write_text("# Page\n\n[ok](other.md#a-code-heading-with-punctuation) [self](#page)\n"
                    "[gone](missing.md) [renamed](other.md#old-heading) [nothing here](#nowhere)\n"
                    "```\n[in code](ignored.md)\n```\n`[inline](ignored.md)`\n")
    problems = broken_links(page, tmp_path)
    assert [problem.split(": ", 1)[1] for problem in problems] == [
        "missing.md (no such file)", "other.md#old-heading (no heading with that anchor)",
        "#nowhere (no heading with that anchor)"]
    assert slug("Networks of generators, offline: `nni-simulate --case`") == \
        "networks-of-generators-offline-nni-simulate---case"
    assert anchors("# A\n## A\n") == {"a", "a-1"}


def readme_commands() -> list[str]:
    """Every command line in README's ``bash`` blocks that runs one of our tools (comments dropped)."""
    commands, in_bash = [], False
    for line in README.read_text().splitlines():
        if line.startswith("```"):
            in_bash = line.strip() == "```bash"
            continue
        if in_bash:
            command = line.split("  #", 1)[0].strip()
            if command.split(" ", 1)[0] in COMMANDS:
                commands.append(command)
    return commands


def test_readme_quotes_the_two_commands_and_the_network_and_live_ones():
    commands = readme_commands()
    assert {"./scripts/demo", "./scripts/test"} <= set(commands)
    assert any("--case" in command for command in commands) and any("--rerun" in command for command in commands)


@pytest.mark.parametrize("command", readme_commands())
def test_every_command_readme_quotes_answers_help_and_knows_its_options(command):
    """The command as quoted, with --help after its words (``--case X`` keeps its own help)."""
    words = shlex.split(command)
    if words[0] == "./scripts/test":
        result = subprocess.run([str(ROOT / "scripts" / "test"), "--help"], capture_output=True, text=True,
                                timeout=300, cwd=ROOT)
        assert result.returncode == 0 and "usage:" in result.stdout and "--quick" in result.stdout
        return
    exe = COMMANDS[words[0]]
    case = words[words.index("--case"):words.index("--case") + 2] if "--case" in words else []
    result = subprocess.run([str(exe), *case, "--help"], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("usage:")
    for option in (word.split("=", 1)[0] for word in words[1:] if word.startswith("--")):
        assert re.search(rf"(^|[\s\[,]){re.escape(option)}\b", result.stdout, re.M), \
            f"{option} of `{command}` is not in {exe.name} --help"


def test_readme_ros2_commands_name_what_the_packages_install():
    """``ros2 run PKG EXE`` / ``ros2 launch PKG FILE`` in README: the entry point or launch file exists."""
    quoted = re.findall(r"ros2 (run|launch) (\w+) ([\w.]+)", README.read_text())
    assert quoted
    for kind, package, name in quoted:
        if kind == "launch":
            assert (ROOT / package / "launch" / name).exists(), f"no {package}/launch/{name}"
        else:
            setup = (ROOT / package / "setup.py").read_text()
            assert re.search(rf"\b{re.escape(name)} = ", setup), f"{package} installs no {name}"


def cited_tests(text: str):
    """``(file, test or None)`` of every test a page cites: ``tests/test_x.py::name``, and ``::name`` after it."""
    current = None
    for match in re.finditer(r"`(?:tests/(test_\w+\.py))?(?:::(\w+))?[\[`]", text):
        path, name = match.groups()
        if path:
            current = path
        if current and (path or name):
            yield current, name


@pytest.mark.parametrize("page", PAGES, ids=lambda page: str(page.relative_to(ROOT)))
def test_every_test_a_page_cites_exists(page):
    """A page that says which test shows a behaviour names a test that is there (tests get renamed)."""
    missing = []
    for path, name in cited_tests(page.read_text()):
        source = ROOT / "tests" / path
        if not source.exists():
            missing.append(path)
        elif name and not re.search(rf"^(async )?def {name}\(", source.read_text(), re.M):
            missing.append(f"{path}::{name}")
    assert missing == []
