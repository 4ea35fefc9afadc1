"""House rules that keep the repository honest."""

import re
import subprocess
import sys
from pathlib import Path

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


def test_recon_imports_nothing_upstream():
    pattern = re.compile(r"^\s*(from|import)\s+(poses|simulator|benchmarks)\b", re.M)
    offenders = [str(p) for p in (ROOT / "recon").rglob("*.py") if pattern.search(p.read_text())]
    assert offenders == []


def test_help_explains_every_command():
    out = subprocess.run([sys.executable, "-m", "benchmarks.cli", "--help"], capture_output=True,
                         text=True, check=True).stdout
    assert "poses" in out
