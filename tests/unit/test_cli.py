"""The command line's assembly: every area on one app, none importing the CLI back, and
``--version`` answering without loading any command."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

from click.testing import CliRunner

import posefix
from posefix.cli import AREAS, COMMAND_AREA, build_app

COMMANDS_DIR = Path(posefix.__file__).parent / "commands"


def test_version_answers_before_any_command_module_is_loaded() -> None:
    code = ("import sys; from posefix.cli import main; main(['--version']); "
            "print(sorted(m for m in sys.modules if m.startswith(('posefix.commands', 'click', 'typer', 'pydantic', 'numpy'))))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines() == [f"posefix {posefix.__version__}", "[]"]


def test_version_is_listed_in_help_and_works_through_click() -> None:
    res = CliRunner().invoke(build_app(), ["--version"])
    assert res.exit_code == 0 and res.output.strip() == f"posefix {posefix.__version__}"
    assert "--version" in CliRunner().invoke(build_app(), ["--help"]).output


def test_every_top_level_command_belongs_to_the_area_main_loads_for_it() -> None:
    for area in AREAS:
        names = set(build_app([area]).commands)
        assert names == {c for c, a in COMMAND_AREA.items() if a == area}, area


def test_a_short_correction_loads_neither_pydantic_nor_scipy(tmp_path: Path) -> None:
    # start-up is what a short correction costs: typer's coercion (pydantic) and scipy.linalg
    # each cost a few tenths of a second of CPU
    from posefix.core.simulate import simulate
    from posefix.io import EditSet, Move, write_edits, write_run

    sim = simulate(120.0, 10.0, 30.0, seed=7, regime="mixed")
    write_run(sim.run, tmp_path / "run.csv")
    write_edits(EditSet(moves=[Move(e.t_s, e.lat_deg, e.lon_deg) for e in sim.edits]), tmp_path / "edits.json")
    code = ("import sys\nfrom posefix.cli import main\ntry:\n"
            "    main(['correct', 'run.csv', '-e', 'edits.json', '-o', 'out.csv', '-q'])\nfinally:\n"
            "    print(sorted({m.split('.')[0] for m in sys.modules} & {'pydantic', 'scipy', 'typer'}))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines()[-1] == "[]"
    assert (tmp_path / "out.csv").stat().st_size > 0


def test_no_command_module_imports_the_cli() -> None:
    for path in COMMANDS_DIR.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                assert node.module != "posefix.cli", path.name
            elif isinstance(node, ast.Import):
                assert all(a.name != "posefix.cli" for a in node.names), path.name
