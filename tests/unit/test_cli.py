"""The command line's assembly: every area on one app, none importing the CLI back, and
``--version`` answering without loading any command."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

from typer.testing import CliRunner

import posefix
from posefix.cli import AREAS, COMMAND_AREA, build_app

COMMANDS_DIR = Path(posefix.__file__).parent / "commands"


def test_version_answers_before_any_command_module_is_loaded() -> None:
    code = ("import sys; from posefix.cli import main; main(['--version']); "
            "print(sorted(m for m in sys.modules if m.startswith(('posefix.commands', 'typer', 'numpy'))))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines() == [f"posefix {posefix.__version__}", "[]"]


def test_version_is_listed_in_help_and_works_through_typer() -> None:
    res = CliRunner().invoke(build_app(), ["--version"])
    assert res.exit_code == 0 and res.output.strip() == f"posefix {posefix.__version__}"
    assert "--version" in CliRunner().invoke(build_app(), ["--help"]).output


def test_every_top_level_command_belongs_to_the_area_main_loads_for_it() -> None:
    for area in AREAS:
        app = build_app([area])
        import typer.main

        names = set(typer.main.get_command(app).commands)  # type: ignore[attr-defined]
        assert names == {c for c, a in COMMAND_AREA.items() if a == area}, area


def test_no_command_module_imports_the_cli() -> None:
    for path in COMMANDS_DIR.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                assert node.module != "posefix.cli", path.name
            elif isinstance(node, ast.Import):
                assert all(a.name != "posefix.cli" for a in node.names), path.name
