"""The repository keeps its promises: the README's commands are CI's, its example runs, and nothing
points outside the repository."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def _blocks(language):
    return re.findall(rf"```{language}\n(.*?)```", README, re.S)


def test_readme_commands_are_the_ones_ci_runs():
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    commands = [line for line in _blocks("bash")[0].splitlines() if line.strip()]
    assert len(commands) == 2, "the README starts with the two set-up commands"
    for command in commands:
        assert command in ci, f"README command not in .ci/run: {command}"


@pytest.mark.slow
def test_readme_python_example_runs(tmp_path):
    code = _blocks("python")[0]
    assert len(code.strip().splitlines()) <= 12
    assert "from spaceid." not in code, "the README example uses only the top-level API"
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr


def _tracked(suffixes=None):
    """``(name, text)`` of every file git tracks (of ``suffixes`` only, when given; the binary logs and images never)."""
    tracked = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True).stdout.split()
    if not tracked:
        pytest.skip("not a git checkout")
    for name in tracked:
        path = ROOT / name
        if path.is_file() and path.suffix not in {".png", ".bag", ".mcap", ".db3"}:
            if suffixes is None or path.suffix in suffixes:
                yield name, path.read_text(errors="ignore")


def test_nothing_links_outside_the_repository():
    outside = re.compile(r"\.\./shared|shared/design|shared/seed|MATH\.md")
    hits = [name for name, text in _tracked() if name != "tests/test_repository.py" and outside.search(text)]
    assert not hits, f"files that point outside the repository: {hits}"


def test_no_text_holds_a_control_character():
    """No tracked text file holds a control character but the newline: a LaTeX command written in a Python string
    whose backslash began an escape (``\\times`` as a tab and "imes", ``\\frac`` as a form feed or tab and "rac") rendered
    as garbage in the built documentation."""
    control = re.compile(r"[\x00-\x09\x0b-\x1f\x7f]")
    texts = _tracked({".md", ".py", ".rst", ".toml", ".yaml", ".yml", ".txt", ".urdf", ".json", ".cfg"})
    hits = [f"{name}:{number}" for name, text in texts
            for number, line in enumerate(text.split("\n"), 1) if control.search(line)]  # splitlines() splits at a form feed
    assert not hits, f"control characters (a backslash escape where a LaTeX command was meant?): {hits}"


def test_readme_fits_on_two_screens():
    assert len(README.splitlines()) <= 110


def test_readme_docs_build_is_the_one_ci_runs():
    ci = (ROOT / ".ci" / "run").read_text()
    commands = re.findall(r"`(\.venv/bin/(?:pip install -e \"\.\[docs\]\"|sphinx-build [^`]*))`", README)
    assert len(commands) == 2, "the README gives the docs install and build commands"
    for command in commands:
        assert command in ci, f"README docs command not in .ci/run: {command}"
    assert "sphinx-build -W" in ci


def test_readme_links_point_to_files_that_exist():
    missing = [link for link in re.findall(r"\]\(([^)#]+)\)", README)
               if "://" not in link and not (ROOT / link).exists()]
    assert not missing, f"README links to missing files: {missing}"
