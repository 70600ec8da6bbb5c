"""Split the one-module command line approxtree/cli.py into the package approxtree/cli/.

Deterministic and re-runnable: it reads approxtree/cli.py with ``ast`` and writes

- ``cli/__init__.py``: the ``main`` group, ``main.add_command`` of every command, and the names
  tests and benchmarks reach as ``approxtree.cli.NAME`` (re-exported);
- ``cli/options.py``: option decorators (``reader_options``, ``cartographic_options``, ...),
  option callbacks used by several commands, and one named decorator per click.option stack
  that two or more commands repeat identically (``json_option``, ``threshold_options``, ...);
- ``cli/common.py``: helpers used by several commands (``_reports_errors``, ``_emit``,
  ``_open``, tree checks, ...);
- ``cli/<command>.py``: one thin module per command, with the helpers only it uses.

Names that tests monkeypatch (``monkeypatch.setattr("approxtree.cli.NAME", ...)``) are looked up
at call time: every module but the defining one calls them as ``common.NAME`` (an attribute of
the module), and the test's target string is rewritten to ``approxtree.cli.common.NAME``.

Then it deletes approxtree/cli.py, adds "approxtree.cli" to pyproject's packages, writes the
old commands' parameters to tests/data/cli_params.json (tests/test_cli_package.py compares the
package with it), checks the new package against the old module in a fresh process, and runs
``ruff check --fix`` and ``ruff format`` on the package.

    python tools/split_cli.py [--root REPO] [--ruff PATH]
"""

from __future__ import annotations

import argparse
import ast
import importlib.util
import json
import re
import shutil
import subprocess
import sys
import textwrap
from dataclasses import dataclass, field
from pathlib import Path

#: Named option groups: a run of identical click.options repeated by several commands whose
#: flags all belong to one of these is factored into a decorator of that name.
GROUPS = {
    "camera_options": ("--eye", "--target", "--fov", "--size"),
    "threshold_options": ("--alpha", "--gamma"),
    "json_option": ("--json",),
}

#: Top-level decorator functions that define option groups (they go to options.py).
OPTION_DECORATOR_SUFFIX = ("_option", "_options")

HEADER = "from __future__ import annotations\n"

INIT_DOC = """\
One module per command; option groups shared by several commands in options.py, helpers in
common.py (written from the one-module cli.py by tools/split_cli.py).
"""


@dataclass
class Unit:
    """One top-level statement of cli.py: its source text and the names it defines and uses."""

    node: ast.stmt
    text: str
    defines: list[str]
    uses: set[str] = field(default_factory=set)
    #: Names used only inside click.option(...) calls (option callbacks).
    decorator_uses: set[str] = field(default_factory=set)
    command: str | None = None  # command name, for a @main.command() function
    module: str | None = None  # the generated module it goes to


def _names(node: ast.AST) -> set[str]:
    """Every plain name loaded in ``node``."""
    return {n.id for n in ast.walk(node) if isinstance(n, ast.Name)}


def _is_main_command(dec: ast.expr) -> bool:
    return (
        isinstance(dec, ast.Call)
        and isinstance(dec.func, ast.Attribute)
        and isinstance(dec.func.value, ast.Name)
        and dec.func.value.id == "main"
        and dec.func.attr == "command"
    )


def _is_group(node: ast.stmt) -> bool:
    return isinstance(node, ast.FunctionDef) and any(
        isinstance(d, ast.Call) and ast.unparse(d.func) == "click.group"
        for d in node.decorator_list
    )


def _option_flags(dec: ast.expr) -> tuple[str, ...] | None:
    """The flags (``--name``) of a ``click.option(...)`` decorator, else None."""
    if not (isinstance(dec, ast.Call) and ast.unparse(dec.func) == "click.option"):
        return None
    flags = tuple(
        a.value
        for a in dec.args
        if isinstance(a, ast.Constant) and isinstance(a.value, str) and a.value.startswith("-")
    )
    return flags or None


def _main_flag(dec: ast.expr) -> str:
    """The long flag of a click.option (``--quiet`` of ``"-q", "--quiet"``)."""
    flags = _option_flags(dec) or ("",)
    return next((f for f in flags if f.startswith("--")), flags[0])


def _start_line(node: ast.stmt) -> int:
    decs = getattr(node, "decorator_list", [])
    return min([node.lineno] + [d.lineno for d in decs])


def _read_units(source: str) -> tuple[str | None, list[ast.stmt], list[Unit]]:
    """The module docstring, its import statements and its other top-level statements."""
    tree = ast.parse(source)
    lines = source.splitlines(keepends=True)
    doc = ast.get_docstring(tree, clean=False)
    imports: list[ast.stmt] = []
    units: list[Unit] = []
    prev_end = 0
    for node in tree.body:
        start = _start_line(node)
        if (
            isinstance(node, ast.Expr)
            and isinstance(node.value, ast.Constant)
            and node is tree.body[0]
        ):
            prev_end = node.end_lineno
            continue
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            imports.append(node)
            prev_end = node.end_lineno
            continue
        # The comment block right above the statement travels with it.
        first = start
        while first - 1 > prev_end and lines[first - 2].lstrip().startswith("#"):
            first -= 1
        text = "".join(lines[first - 1 : node.end_lineno])
        prev_end = node.end_lineno
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            defines = [node.name]
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            defines = sorted(
                {n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)}
            )
        else:
            raise SystemExit(f"split_cli: cannot place the top-level statement at line {start}")
        unit = Unit(node, text, defines)
        decs = getattr(node, "decorator_list", [])
        body_names: set[str] = set()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for part in [node.args, *node.body]:
                body_names |= _names(part)
            if node.returns is not None:
                body_names |= _names(node.returns)
        else:
            body_names = _names(node)
        dec_names = set().union(set(), *(_names(d) for d in decs))
        option_names = set().union(set(), *(_names(d) for d in decs if _option_flags(d)))
        # Option decorators defined as functions (reader_options) call click.option inside.
        for call in ast.walk(node) if not decs else []:
            if isinstance(call, ast.Call) and _option_flags(call):
                option_names |= _names(call)
        unit.uses = (body_names | dec_names) - set(defines)
        unit.decorator_uses = option_names - (body_names - option_names) - {"click"}
        for d in decs:
            if _is_main_command(d):
                arg = d.args[0].value if d.args else node.name
                unit.command = arg
        units.append(unit)
    return doc, imports, units


def _import_bindings(imports: list[ast.stmt]) -> dict[str, str]:
    """Bound name -> the import statement binding it (one name per statement)."""
    out: dict[str, str] = {}
    for node in imports:
        if isinstance(node, ast.Import):
            for a in node.names:
                bound = a.asname or a.name.split(".")[0]
                out[bound] = f"import {a.name}" + (f" as {a.asname}" if a.asname else "")
        else:
            assert isinstance(node, ast.ImportFrom)
            mod = "." * node.level + (node.module or "")
            for a in node.names:
                if mod == "__future__":
                    continue
                bound = a.asname or a.name
                out[bound] = f"from {mod} import {a.name}" + (f" as {a.asname}" if a.asname else "")
    return out


def _place(units: list[Unit]) -> None:
    """Assign every unit a module: a command's own module, options, common or __init__."""
    by_name = {n: u for u in units for n in u.defines}
    for u in units:
        if u.command is not None:
            u.module = u.command
        elif _is_group(u.node):
            u.module = "__init__"
    # Users of each helper: the units whose code names it.
    users: dict[str, set[int]] = {n: set() for n in by_name}
    for i, u in enumerate(units):
        for n in u.uses:
            if n in users:
                users[n].add(i)
    # Helpers go where all their users are (one command), else options or common; repeated
    # until nothing moves (a helper of a helper follows it).
    changed = True
    while changed:
        changed = False
        for u in units:
            if u.module in ("__init__",) or u.command is not None:
                continue
            name = u.defines[0]
            mods = {units[i].module for i in users[name] if units[i] is not u}
            if u.defines[0].endswith(OPTION_DECORATOR_SUFFIX):
                want = "options"
            elif len(mods) == 1 and None not in mods and mods != {"__init__"}:
                want = mods.pop()
            elif (
                all(
                    name in units[i].decorator_uses or units[i].module == "options"
                    for i in users[name]
                    if units[i] is not u
                )
                and users[name]
            ):
                want = "options"
            elif None in mods:
                want = u.module  # wait for the users to be placed
            else:
                want = "common"
            if want is not None and want != u.module:
                u.module = want
                changed = True
    for u in units:
        if u.module is None:
            u.module = "common"  # used by nobody: a shared helper
    # A helper of common or options used by a command module's helper is fine; one that common
    # needs from a command module is not (imports point down): move it to common.
    changed = True
    while changed:
        changed = False
        for u in units:
            if u.module not in ("common", "options"):
                continue
            for n in u.uses:
                dep = by_name.get(n)
                if dep is not None and dep.module not in ("common", "options", "__init__"):
                    dep.module = "common"
                    changed = True
                if dep is not None and u.module == "common" and dep.module == "options":
                    # common never imports options.
                    dep.module = "common"
                    changed = True


@dataclass
class Shared:
    """A named option decorator: a run of click.options repeated identically."""

    name: str
    texts: list[str]  # the option decorators' source, top to bottom
    dumps: tuple[str, ...]
    commands: list[str]  # the commands that repeat it


def _shared_options(units: list[Unit], source: str) -> dict[tuple[str, ...], Shared]:
    """Runs of identical click.options that two or more commands repeat, named by GROUPS."""
    commands = [u for u in units if u.command is not None]
    count: dict[str, int] = {}
    for u in commands:
        for d in set(ast.dump(d) for d in u.node.decorator_list if _option_flags(d)):
            count[d] = count.get(d, 0) + 1
    group_of = {flag: g for g, flags in GROUPS.items() for flag in flags}

    def key_of(d: ast.expr) -> str:
        return group_of.get(_main_flag(d), _main_flag(d))

    runs: dict[tuple[str, ...], list[ast.expr]] = {}
    for u in commands:
        run: list[ast.expr] = []
        for d in [*u.node.decorator_list, None]:
            flags = _option_flags(d) if d is not None else None
            ok = flags is not None and count[ast.dump(d)] >= 2
            if ok and run and key_of(run[0]) != key_of(d):
                runs.setdefault(tuple(ast.dump(x) for x in run), run)
                run = []
            if ok:
                run.append(d)
            else:
                if run:
                    runs.setdefault(tuple(ast.dump(x) for x in run), run)
                run = []
    shared: dict[tuple[str, ...], Shared] = {}
    # Named decorators never take the name of a function of cli.py (quiet_option).
    taken: set[str] = {n for u in units for n in u.defines}
    for key in sorted(runs, key=lambda k: (-len(k), k)):
        run = runs[key]
        users = sum(
            1
            for u in commands
            if _contains_run([ast.dump(d) for d in u.node.decorator_list], list(key))
        )
        if users < 2:
            continue
        flags = [_main_flag(d) for d in run]
        group = group_of.get(flags[0])
        name = group if group and (len(GROUPS[group]) == 1 or len(flags) > 1) else None
        if name is None or name in taken:
            name = "_".join(f.lstrip("-").replace("-", "_") for f in flags) + (
                "_option" if len(flags) == 1 else "_options"
            )
        while name in taken:
            name = name.replace("_option", "_shared_option", 1)
        taken.add(name)
        texts = [ast.get_source_segment(source, d) for d in run]
        users_of = [
            u.command
            for u in commands
            if _contains_run([ast.dump(d) for d in u.node.decorator_list], list(key))
        ]
        shared[key] = Shared(name, texts, key, users_of)
    return shared


def _contains_run(seq: list[str], run: list[str]) -> bool:
    return any(seq[i : i + len(run)] == run for i in range(len(seq) - len(run) + 1))


def _command_text(
    u: Unit, source: str, shared: dict[tuple[str, ...], Shared]
) -> tuple[str, set[str]]:
    """The command's source with @main.command -> @click.command and shared option runs
    replaced by their named decorator; the decorator names it now uses."""
    node = u.node
    lines = source.splitlines(keepends=True)
    decs = node.decorator_list
    dumps = [ast.dump(d) for d in decs]
    out: list[str] = []
    used: set[str] = set()
    i = 0
    # Longest shared run first at each position.
    keys = sorted(shared, key=lambda k: -len(k))
    while i < len(decs):
        for key in keys:
            if dumps[i : i + len(key)] == list(key):
                out.append(f"@{shared[key].name}\n")
                used.add(shared[key].name)
                i += len(key)
                break
        else:
            d = decs[i]
            seg = "".join(lines[d.lineno - 1 : d.end_lineno])
            if _is_main_command(d):
                seg = seg.replace("@main.command(", "@click.command(", 1)
            out.append(seg)
            i += 1
    body = "".join(lines[node.lineno - 1 : node.end_lineno])
    # Comment lines above the decorators stay with the command.
    head = u.text[: u.text.index(lines[_start_line(node) - 1])] if u.text else ""
    return head + "".join(out) + body, used


def _rewrite_patchable(text: str, names: set[str]) -> str:
    """Replace loads of ``names`` by ``common.NAME`` (looked up when called, so patchable)."""
    if not names:
        return text
    tree = ast.parse(text)
    spots = sorted(
        (
            (n.lineno, n.col_offset)
            for n in ast.walk(tree)
            if isinstance(n, ast.Name) and n.id in names and isinstance(n.ctx, ast.Load)
        ),
        reverse=True,
    )
    lines = text.splitlines(keepends=True)
    # ast's column offsets count UTF-8 bytes.
    for line, col in spots:
        b = lines[line - 1].encode()
        lines[line - 1] = (b[:col] + b"common." + b[col:]).decode()
    return "".join(lines)


def _module_doc(name: str, units: list[Unit]) -> str:
    cmd = next((u for u in units if u.command == name), None)
    summary = ""
    if cmd is not None:
        doc = ast.get_docstring(cmd.node) or ""
        summary = " ".join(doc.split("\n\n")[0].split())
        summary = summary.split(". ")[0].rstrip(".")
    text = f"``approxtree {name}``: {summary}." if summary else f"``approxtree {name}``."
    lines = textwrap.wrap(text, width=94)
    return '"""' + "\n".join(lines) + ('"""\n' if len(lines) == 1 else '\n"""\n')


def _write_package(root: Path, source: str, ruff: str | None) -> tuple[list[str], dict[str, str]]:
    """Write approxtree/cli/; the files written and the module of each monkeypatched name."""
    doc, imports, units = _read_units(source)
    bindings = _import_bindings(imports)
    _place(units)
    shared = _shared_options(units, source)
    by_name = {n: u for u in units for n in u.defines}
    # A patched name of one command module is a global there, looked up when called: tests
    # patch it in that module. One of common is called as common.NAME everywhere else.
    targets = {n: by_name[n].module for n in _patched_names(root) if n in by_name}
    patchable = {n for n, m in targets.items() if m == "common"}
    for n, m in targets.items():
        if m in ("options", "__init__"):
            raise SystemExit(f"split_cli: {n} is monkeypatched by tests but lands in {m}.py")

    pkg = root / "approxtree" / "cli"
    if pkg.exists():
        shutil.rmtree(pkg)
    pkg.mkdir()

    commands = [u for u in units if u.command is not None]
    modules: dict[str, list[str]] = {}
    module_uses: dict[str, set[str]] = {}
    order = ["common", "options"] + [u.command for u in commands]
    for m in order:
        modules[m] = []
        module_uses[m] = set()
    # Shared option decorators go to options.py.
    for s in sorted(shared.values(), key=lambda s: s.name):
        flags = ", ".join(_main_flag(ast.parse(t, mode="eval").body) for t in s.texts)
        body = "".join(f"    fn = {t.strip()}(fn)\n" for t in reversed(s.texts))
        text = (
            f"def {s.name}(fn: Callable[..., Any]) -> Callable[..., Any]:\n"
            f'    """{flags}, the same on {", ".join(s.commands)}."""\n{body}    return fn\n'
        )
        modules["options"].append(text)
        module_uses["options"] |= _names(ast.parse(text)) - {s.name}
    for u in units:
        if u.module == "__init__":
            continue
        if u.command is not None:
            text, used = _command_text(u, source, shared)
            uses = (u.uses - {"main"}) | used | {"click"}
        else:
            text, uses = u.text, set(u.uses)
        local = set().union(*(x.defines for x in units if x.module == u.module))
        calls = patchable if u.module != "common" else set()
        text = _rewrite_patchable(text, calls & uses - local)
        if calls & uses - local:
            uses = (uses - patchable) | {"common"}
        modules[u.module].append(text)
        module_uses[u.module] |= uses
    shared_names = {s.name for s in shared.values()}

    written = []
    for m in order:
        if not modules[m]:
            continue
        local = set().union(*(x.defines for x in units if x.module == m))
        if m == "options":
            local |= shared_names
        header_imports = []
        for n in sorted(module_uses[m] - local):
            if n in bindings:
                header_imports.append(bindings[n])
            elif n == "common":
                header_imports.append("from approxtree.cli import common")
            elif n in shared_names:
                header_imports.append(f"from approxtree.cli.options import {n}")
            elif n in by_name and by_name[n].module in ("common", "options"):
                header_imports.append(f"from approxtree.cli.{by_name[n].module} import {n}")
            elif n in by_name:
                raise SystemExit(f"split_cli: {m} needs {n} of {by_name[n].module}")
        if m == "common":
            mdoc = '"""Helpers of several commands: errors, output, reading terrains, trees."""\n'
        elif m == "options":
            mdoc = '"""Option groups shared by the commands (click decorators and callbacks)."""\n'
        else:
            mdoc = _module_doc(m, units)
        text = mdoc + "\n" + HEADER + "\n" + "\n".join(sorted(set(header_imports))) + "\n\n\n"
        text += "\n\n".join(t.rstrip("\n") + "\n" for t in modules[m])
        fname = m + ".py"
        (pkg / fname).write_text(text)
        written.append(fname)

    # __init__: the group, every command added, the names tests reach re-exported.
    group = next(u for u in units if u.module == "__init__")
    reexport = sorted(
        n for n in _reached_names(root) if n in by_name and n not in targets and n != "main"
    )
    init = [
        '"""' + (doc or "The approxtree command line.").strip() + "\n\n" + INIT_DOC + '"""\n',
        HEADER,
    ]
    init.append("import click\n")
    init.append(
        "from approxtree.cli import " + ", ".join(sorted({u.command for u in commands})) + "\n"
    )
    for n in reexport:
        init.append(f"from approxtree.cli.{by_name[n].module} import {n}\n")
    init.append("\n")
    init.append(f"__all__ = {['main', *reexport]!r}\n\n\n")
    init.append(group.text.rstrip("\n") + "\n\n\n")
    init.append("# The commands, in the order of the one-module command line.\n")
    for u in commands:
        init.append(f"main.add_command({u.command}.{u.node.name})\n")
    (pkg / "__init__.py").write_text("".join(init))
    written.insert(0, "__init__.py")

    if ruff:
        files = [str(pkg / f) for f in written]
        # Format first (long generated lines), then sort and prune imports, then format again.
        subprocess.run([ruff, "format", "--quiet", *files], cwd=root, check=True)
        subprocess.run([ruff, "check", "--fix", "--quiet", *files], cwd=root, check=False)
        subprocess.run([ruff, "format", "--quiet", *files], cwd=root, check=True)
    return written, targets


def _patched_names(root: Path) -> set[str]:
    """Names that tests monkeypatch as "approxtree.cli.NAME" (or "approxtree.cli.MODULE.NAME")."""
    out: set[str] = set()
    pat = re.compile(r"""setattr\(\s*["']approxtree\.cli\.(?:\w+\.)?(\w+)["']""")
    for path in sorted((root / "tests").glob("*.py")):
        out |= set(pat.findall(path.read_text()))
    return out


def _reached_names(root: Path) -> set[str]:
    """Names reached as ``approxtree.cli.NAME`` or imported from approxtree.cli elsewhere."""
    out: set[str] = set()
    attr = re.compile(r"approxtree\.cli\.(\w+)")
    frm = re.compile(r"from approxtree\.cli import ([\w, ]+)")
    for folder in ("tests", "benchmarks", "approxtree", "examples", "tools"):
        for path in sorted((root / folder).rglob("*.py")):
            if path.is_relative_to(root / "approxtree" / "cli") or path.name == "split_cli.py":
                continue
            text = path.read_text()
            out |= set(attr.findall(text))
            for m in frm.findall(text):
                out |= {n.strip().split(" as ")[0] for n in m.split(",")}
    return out


def _rewrite_patch_targets(root: Path, targets: dict[str, str]) -> list[str]:
    """Point monkeypatch targets "approxtree.cli.NAME" at the module where NAME is looked up."""
    changed = []
    for path in sorted((root / "tests").glob("*.py")):
        text = path.read_text()
        new = text
        for n, m in sorted(targets.items()):
            new = re.sub(
                rf"""(setattr\(\s*["'])approxtree\.cli\.(?:\w+\.)?{n}(["'])""",
                rf"\1approxtree.cli.{m}.{n}\2",
                new,
            )
        if new != text:
            path.write_text(new)
            changed.append(str(path.relative_to(root)))
    return changed


def _add_package(root: Path) -> None:
    path = root / "pyproject.toml"
    text = path.read_text()
    if '"approxtree.cli",' in text:
        return
    new = text.replace('    "approxtree",\n', '    "approxtree",\n    "approxtree.cli",\n', 1)
    if new == text:
        raise SystemExit('split_cli: no "approxtree", line in pyproject\'s packages')
    path.write_text(new)


def params_of(main) -> dict:
    """Every command's parameters: name -> flags, default, type, required, flag, multiple, help."""
    out = {}
    for name, cmd in sorted(main.commands.items()):
        out[name] = {
            p.name: {
                "opts": sorted(p.opts),
                "default": repr(p.default),
                "type": p.type.name,
                "required": p.required,
                "is_flag": getattr(p, "is_flag", False),
                "multiple": p.multiple,
                "help": getattr(p, "help", None),
                "callback": getattr(p.callback, "__name__", None),
                "expose_value": p.expose_value,
            }
            for p in cmd.params
        }
    return out


def _old_params(path: Path) -> dict:
    spec = importlib.util.spec_from_file_location("_approxtree_cli_before_split", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return params_of(module.main)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[1])
    ruff = shutil.which("ruff") or str(Path(sys.executable).with_name("ruff"))
    parser.add_argument("--ruff", default=ruff, help="ruff executable [default: %(default)s]")
    args = parser.parse_args(argv)
    root = args.root.resolve()
    old = root / "approxtree" / "cli.py"
    if not old.exists():
        print("split_cli: approxtree/cli.py is gone (already split); nothing to do.")
        return 0
    source = old.read_text()
    before = _old_params(old)
    ruff = args.ruff if Path(args.ruff).exists() or shutil.which(args.ruff) else None
    written, targets = _write_package(root, source, ruff)
    changed = _rewrite_patch_targets(root, targets)
    old.unlink()
    _add_package(root)
    data = root / "tests" / "data"
    data.mkdir(exist_ok=True)
    (data / "cli_params.json").write_text(json.dumps(before, indent=1, sort_keys=True) + "\n")
    # The package must offer the same commands with the same parameters (fresh process).
    check = subprocess.run(
        [
            sys.executable,
            "-c",
            "import json, sys; sys.path.insert(0, 'tools'); from split_cli import params_of; "
            "from approxtree.cli import main; print(json.dumps(params_of(main)))",
        ],
        cwd=root,
        capture_output=True,
        text=True,
    )
    if check.returncode != 0:
        print(check.stderr, file=sys.stderr)
        return 1
    after = json.loads(check.stdout)
    if after != json.loads(json.dumps(before)):
        for name in sorted(set(before) | set(after)):
            if before.get(name) != after.get(name):
                print(f"split_cli: command {name} differs after the split", file=sys.stderr)
        return 1
    print(
        f"split_cli: wrote approxtree/cli/ ({', '.join(written)}); same parameters for "
        f"{len(after)} commands; tests retargeted: {', '.join(changed) or 'none'}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
