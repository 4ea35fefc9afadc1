"""House rules that keep the repository honest."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _readme_commands():
    text = (ROOT / "README.md").read_text()
    return re.findall(r"```bash\n(.+?)\n```", text, flags=re.S)


def test_ci_runs_the_readme_test_command():
    commands = _readme_commands()
    assert len(commands) >= 2
    assert commands[1].strip() in (ROOT / ".ci" / "run").read_text()
    assert "pytest" in commands[1]


def test_top_level_layout():
    for name in ("pyproject.toml", "simulator", "recon", "benchmarks", "poses", "tests", "reports"):
        assert (ROOT / name).exists(), name


#: Each stage and the stages it must not import (data flows poses -> simulator -> recon -> benchmarks).
UPSTREAM_FREE = {"poses": ("simulator", "recon", "benchmarks"), "simulator": ("recon", "benchmarks"),
                 "recon": ("poses", "simulator", "benchmarks")}


@pytest.mark.parametrize("stage", sorted(UPSTREAM_FREE))
def test_stages_import_nothing_downstream_or_sideways(stage):
    names = "|".join(UPSTREAM_FREE[stage])
    pattern = re.compile(rf"^\s*(from|import)\s+(bodyscan\.)?({names})\b", re.M)
    offenders = [str(p) for p in (ROOT / stage).rglob("*.py") if pattern.search(p.read_text())]
    assert offenders == []


def test_everything_imports_through_the_bodyscan_namespace():
    pattern = re.compile(r"^\s*(from|import)\s+(poses|simulator|recon|benchmarks)\b", re.M)
    files = [p for d in ("poses", "simulator", "recon", "benchmarks", "tests", "bodyscan")
             for p in (ROOT / d).rglob("*.py")]
    assert [str(p) for p in files if pattern.search(p.read_text())] == []


def test_no_generic_top_level_module_is_installed(tmp_path):
    code = ("import importlib.util, bodyscan; "
            "print([m for m in ('recon', 'simulator', 'poses', 'benchmarks') if importlib.util.find_spec(m)]); "
            "print(callable(bodyscan.scan), callable(bodyscan.reconstruct), callable(bodyscan.score))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=tmp_path).stdout.split("\n")
    assert out[:2] == ["[]", "True True True"]


def test_help_explains_every_command(capsys):
    """The commands the README's reference lists are the commands ``bodyscan --help`` lists, each
    with its line of explanation, and each explains itself under ``bodyscan COMMAND --help``."""
    from bodyscan.benchmarks.cli import main

    text = (ROOT / "README.md").read_text().split("## Commands", 1)[1]
    reference = re.search(r"```text\n(.+?)\n```", text, flags=re.S).group(1)
    documented = set(re.findall(r"^bodyscan (\w+)", reference, flags=re.M))
    assert {"poses", "scan", "fit", "reconstruct", "bench", "score", "sweep", "report"} <= documented
    out = subprocess.run([sys.executable, "-m", "bodyscan.benchmarks.cli", "--help"], capture_output=True,
                         text=True, check=True).stdout
    listing = out.split("COMMAND\n", 1)[1].split("\n\n", 1)[0]
    # "    name   help", or "    name" with its help on the next, deeper indented line
    explained = dict(re.findall(r"^ {4}(\w+)(?: +|\n {5,})(\S.*)$", listing, flags=re.M))
    assert set(explained) == documented, (sorted(explained), sorted(documented))
    for command in sorted(documented):
        with pytest.raises(SystemExit) as done:
            main([command, "--help"])
        usage = capsys.readouterr().out
        assert done.value.code == 0 and usage.startswith(f"usage: bodyscan {command} "), command
        assert "options:" in usage and "--help" in usage, command
