"""The command line as a package: thin command modules, one command each, shared option groups."""

from __future__ import annotations

import ast
from pathlib import Path

import click
from click.testing import CliRunner

import approxtree.cli
from approxtree.cli import common, main, options
from approxtree.errors import InvalidParameterError

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = Path(approxtree.cli.__file__).parent
HELPERS = {"__init__", "common", "compile_notice", "options", "web_tiles"}


def _command_modules() -> dict[str, ast.Module]:
    return {
        p.stem: ast.parse(p.read_text())
        for p in sorted(PACKAGE.glob("*.py"))
        if p.stem not in HELPERS
    }


def _decorator_names(tree: ast.Module) -> set[str]:
    """Names used as decorators in a module, bare (``@json_option``) or called with the
    command's own help (``@textures_option("...")``)."""
    return {
        d.id if isinstance(d, ast.Name) else d.func.id
        for node in ast.walk(tree)
        if isinstance(node, ast.FunctionDef)
        for d in node.decorator_list
        if isinstance(d, ast.Name) or (isinstance(d, ast.Call) and isinstance(d.func, ast.Name))
    }


#: Option factories of options.py: each command passes its own help text (compared without it).
_FACTORIES = {"textures_option"}


def test_help_lists_every_command():
    out = CliRunner().invoke(main, ["--help"])
    assert out.exit_code == 0
    for name in main.commands:
        assert f"  {name}" in out.output


def test_each_command_module_is_thin_and_holds_one_command():
    modules = _command_modules()
    assert sorted(modules) == sorted(main.commands)
    for name, tree in modules.items():
        lines = len((PACKAGE / f"{name}.py").read_text().splitlines())
        assert lines < 250, f"{name}.py has {lines} lines"
        commands = [
            node
            for node in tree.body
            if isinstance(node, ast.FunctionDef)
            and any(ast.unparse(d).startswith("click.command") for d in node.decorator_list)
        ]
        assert len(commands) == 1, name
        # Command modules import other command modules never (imports point down).
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith(
                "approxtree.cli"
            ):
                assert node.module in (
                    "approxtree.cli",
                    "approxtree.cli.common",
                    "approxtree.cli.options",
                )
                if node.module == "approxtree.cli":
                    assert {a.name for a in node.names} <= {"common", "web_tiles"}


def test_option_groups_are_shared_objects():
    """Each option group of options.py decorates two or more commands, with the same click
    parameters on each; no click.option is repeated verbatim by two command modules."""
    groups = [
        name
        for name, value in vars(options).items()
        if callable(value) and name.endswith(("_option", "_options")) and not name.startswith("_")
    ]
    for name in ("json_option", "threshold_options", "reader_options", "cartographic_options"):
        assert name in groups
    modules = _command_modules()
    for name in groups:
        users = [m for m, tree in modules.items() if name in _decorator_names(tree)]
        assert len(users) >= 2, (name, users)
        group = getattr(options, name)
        decorator = group("help") if name in _FACTORIES else group
        made = {p.name for p in click.command()(decorator(lambda **kw: None)).params}
        infos = [
            [
                {k: v for k, v in p.to_info_dict().items() if k != "help" or name not in _FACTORIES}
                for p in main.commands[m].params
                if p.name in made
            ]
            for m in users
        ]
        assert all(len(i) == len(made) for i in infos), name
        assert all(i == infos[0] for i in infos), name
    seen: dict[str, str] = {}
    for m, tree in modules.items():
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and ast.unparse(node.func) == "click.option":
                text = ast.dump(node)
                assert seen.setdefault(text, m) == m, f"{ast.unparse(node)} in {seen[text]}, {m}"


def test_open_is_looked_up_when_a_command_runs(tmp_path, monkeypatch):
    """Commands call common._open through the module, so a test can replace it."""
    calls = []

    def fake(path, *args, **kwargs):
        calls.append(path)
        raise InvalidParameterError("replaced")

    monkeypatch.setattr("approxtree.cli.common._open", fake)
    dem = tmp_path / "dem.tif"
    dem.write_bytes(b"")
    for args in (["info", str(dem)], ["rd", str(dem)]):
        out = CliRunner().invoke(main, args)
        assert out.exit_code == 2 and "Error: replaced" in out.output
    assert calls == [str(dem)] * 2
    assert common._open is fake


def test_names_reached_from_outside_stay_on_the_package():
    assert approxtree.cli.main is main
    assert approxtree.cli._is_tree("x.atree")
    assert not approxtree.cli._is_tree("dem.tif")


def test_a_command_imports_its_own_module_only():
    """Starting one command imports that command's module (and the shared helpers), not the
    other commands' modules; help still lists every command."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from approxtree.cli import main\n"
        "main(['fractal', '--help'], standalone_mode=False)\n"
        "print(sorted(m for m in sys.modules if m.startswith('approxtree.cli.')))\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    loaded = run.stdout.strip().splitlines()[-1]
    # The group itself listens for compiles (compile_notice) before any command runs.
    helpers = ["common", "compile_notice", "fractal", "options"]
    assert loaded == str([f"approxtree.cli.{name}" for name in helpers])
    assert sorted(main.commands) == sorted(_command_modules())
    assert main.get_command(click.Context(main), "nope") is None


def test_every_subpackage_is_listed_for_the_wheel():
    """pyproject.toml lists the packages a wheel ships by hand: every folder of approxtree with
    an __init__.py is in it (approxtree.verify was missing: installed wheels had no verify)."""
    import tomllib

    listed = set(
        tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    )
    found = {
        ".".join(p.parent.relative_to(ROOT).parts)
        for p in (ROOT / "approxtree").rglob("__init__.py")
        if "_kernel_cache" not in p.parts
    }
    assert found <= listed, sorted(found - listed)
