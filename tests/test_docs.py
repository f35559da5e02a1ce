"""The README and docs/ name only what exists, and say what the code says.

What the users read must stay true when the code moves on. These checks are cheap (no subprocess but ``git
ls-files``, no compiled kernel): the command line is the typer app's own tree, files and modules are looked up in
the checkout, the rest is read from the sources as text.

- every ``omnirotor <cmd> [--option]`` written in a code span or a code block (also ``run --ulog``, a span that
  starts with a command) names a command of the app, a sub-command of a group (``ctl arm``) and options that
  command has; an option written alone (``--blend smooth``) is an option of some command or script;
- the README's command table has one row per command, and a number in a usage line's `[--option N]` is the default;
- every relative link and image resolves to a file of the checkout (``../shared`` beside it is not checked);
- every ``src/...``, ``tests/...`` or package-relative path (``px4/windows.py``), every bare ``*.py`` file name,
  every ``tests/test_x.py::test_name`` and every dotted ``omnirotor.module.Name`` exists; so does every
  ``:func:``/``:class:`` cross-reference to ``omnirotor`` in the package's docstrings;
- every ``python`` example parses and imports only what exists;
- every ROS 2 message type named ships here or is ROS 2's; every key the README's file formats name is in the
  sources; every ``make`` target exists; every pinned dependency has its row in docs/dependencies.md;
- the README's list of disagreements with the paper names exactly the strict xfails;
- every ``SPEC §N.M`` cited is a section of ``../shared/SPEC.md``.

Each checker is also run on a made-up page that names something gone, to show that it would fail.
"""

from __future__ import annotations

import re
import subprocess
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "omnirotor"
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


# --- reading a page: code spans and code blocks ----------------------------------------------------------------


def code_texts(text: str) -> list[str]:
    """The code of a Markdown page: each inline code span, and each line of a fenced or indented code block.

    A code block's lines continued with a backslash are joined; an inline span may run over a line break.
    """
    out: list[str] = []
    prose: list[str] = []
    lines = text.splitlines()
    fenced = False
    pending = ""
    for line in lines:
        if line.lstrip().startswith("```"):
            fenced = not fenced
            continue
        indented = line.startswith("    ") and line.lstrip().startswith("omnirotor")
        if fenced or indented or pending:
            joined = pending + " " + line.strip() if pending else line.strip()
            if joined.endswith("\\"):
                pending = joined[:-1]
                continue
            pending = ""
            out.append(joined)
            prose.append("")
        else:
            prose.append(line)
    out += [m.group(1) for m in re.finditer(r"`([^`\n]+(?:\n[^`\n]+)?)`", "\n".join(prose))]
    return [" ".join(t.split()) for t in out]


# --- the command line -------------------------------------------------------------------------------------------


@cache
def cli_tree():
    """The click command of ``omnirotor`` with every command module registered."""
    import typer.main

    from omnirotor.cli import _register, app

    _register()
    return typer.main.get_command(app)


def _options(command) -> dict[str, bool]:
    """Option name -> whether it takes a value, for ``command`` (``--help`` included)."""
    opts = {"--help": False}
    for p in command.params:
        if p.param_type_name != "option":
            continue
        for name in [*p.opts, *p.secondary_opts]:
            opts[name] = not p.is_flag
    return opts


_INVOCATION = re.compile(r"(?<![\w./-])omnirotor\s+(--?[a-z][\w-]*|[a-z][a-z0-9-]*)(?![\w:.-])")


def invocations(code: str) -> list[str]:
    """The ``omnirotor ...`` invocations in one piece of code, each up to a comment, ``&&``, ``;`` or the next.

    A span that starts with a command's name and an option (``run --ulog``, the pages' short form) counts as one.
    """
    code = re.sub(r"\s#\s.*$", "", code)  # a shell comment
    short = re.match(r"([a-z][a-z0-9-]*) --", code)
    if short and short.group(1) in cli_tree().commands:
        code = "omnirotor " + code
    python = re.compile(r"\b(?:from|import)\s+$")  # `from omnirotor import ...` is Python, not the command
    starts = [m.start() for m in _INVOCATION.finditer(code) if not python.search(code[: m.start()])]
    out = []
    for i, s in enumerate(starts):
        end = starts[i + 1] if i + 1 < len(starts) else len(code)
        out.append(re.split(r"&&|;|\|\|", code[s:end])[0].strip())
    return out


def cli_problems(code: str) -> list[str]:
    """What an ``omnirotor ...`` invocation names that the app does not have (empty: all of it exists)."""
    root = cli_tree()
    problems = []
    for inv in invocations(code):
        tokens = re.sub(r"[][`,()]", " ", inv.replace("\\|", "|")).split()[1:]
        command, path = root, ["omnirotor"]
        if not tokens[0].startswith("-"):
            if tokens[0] not in root.commands:
                problems.append(f"{inv!r}: no command {tokens[0]!r}")
                continue
            command, path = root.commands[tokens[0]], ["omnirotor", tokens[0]]
            tokens = tokens[1:]
        subs = dict(getattr(command, "commands", {}))
        allowed = _options(command)
        for sub in subs.values():
            allowed.update(_options(sub))
        expect_sub = bool(subs)
        skip_value = False
        for tok in tokens:
            if skip_value:
                skip_value = False
                continue
            for word in tok.split("|"):
                opt = re.match(r"--?[a-z][\w-]*", word)
                if word.startswith("-") and opt:
                    name = opt.group(0).split("/")[0]
                    if name not in allowed:
                        problems.append(f"{inv!r}: {' '.join(path)} has no option {name}")
                    elif allowed[name] and "=" not in word and tok == word:
                        skip_value = True
                elif expect_sub and re.fullmatch(r"[a-z][a-z0-9-]*", word):
                    if word not in subs:
                        problems.append(f"{inv!r}: {' '.join(path)} has no sub-command {word!r}")
            if expect_sub and not tok.startswith("-"):
                expect_sub = False
    return problems


# --- links and images ---------------------------------------------------------------------------------------------


def link_problems(text: str, page: Path) -> list[str]:
    """Relative links and images of ``page`` that resolve to no file or folder of the checkout."""
    problems = []
    for m in re.finditer(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)", text):
        target = m.group(1).split("#")[0]
        if not target or re.match(r"[a-z][a-z0-9+.-]*:", target):  # an anchor, http:, mailto:
            continue
        path = (page.parent / target).resolve()
        if not path.is_relative_to(ROOT):  # ../shared beside the checkout (not part of it)
            continue
        if not path.exists():
            problems.append(f"{page.name}: {m.group(0)} -> {target} does not exist")
    return problems


# --- files and modules -------------------------------------------------------------------------------------------


@cache
def tracked_files() -> tuple[str, ...]:
    """Every file of the checkout (git's list, untracked but not ignored ones included; without git, the tree's)."""
    try:
        out = subprocess.run(
            ["git", "ls-files", "--cached", "--others", "--exclude-standard"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            check=True,
        ).stdout
    except (OSError, subprocess.CalledProcessError):  # not a git checkout (an unpacked archive)
        skip = {".git", ".venv", "out", "__pycache__", ".pytest_cache"}
        files = (p.relative_to(ROOT) for p in ROOT.rglob("*") if p.is_file())
        return tuple(str(p) for p in files if not skip & set(p.parts))
    return tuple(out.split())


@cache
def _top_folders() -> frozenset[str]:
    roots = {p.split("/")[0] for p in tracked_files() if "/" in p}
    packages = {p.name for p in PACKAGE.iterdir() if p.is_dir() and not p.name.startswith("__")}
    return frozenset(roots | packages)


NOT_OURS = {"numpy.py", "queue.py", "my_observer.py"}
"""Bare file names the pages use for what is not the project's: a user's module, the files a working folder must
not run (docs/architecture.md)."""

_PATH = re.compile(r"(?<![\w./-])([\w.-]+(?:/[\w.-]+)*\.(?:py|toml|md|json|json5|msg|txt|png|csv)(?:::\w+)?)")
_DOTTED = re.compile(r"(?<![\w./-])omnirotor((?:\.\w+)+)")


def _resolve(rel: str, page: Path) -> Path | None:
    for base in (ROOT, ROOT / "src", PACKAGE, page.parent):
        if (base / rel).exists():
            return base / rel
    return None


def path_problems(code: str, page: Path) -> list[str]:
    """Files, tests and modules that ``code`` names and the checkout does not have."""
    problems = []
    basenames = {p.rsplit("/", 1)[-1] for p in tracked_files()}
    for m in _PATH.finditer(code):
        name, _, test = m.group(1).partition("::")
        if "/" in name:
            if name.split("/")[0] not in _top_folders():
                continue  # a file the user names (flight/flight.csv)
            found = _resolve(name, page)
            if found is None:
                problems.append(f"{page.name}: {name} does not exist")
            elif test and not re.search(rf"^\s*def {test}\(", found.read_text(), re.M):
                problems.append(f"{page.name}: {name} has no test {test}")
        elif name.endswith(".py") and name not in basenames | NOT_OURS:
            problems.append(f"{page.name}: no file {name} in the checkout")
    for m in _DOTTED.finditer(code):
        problems += _dotted_problems("omnirotor" + m.group(1), page)
    return problems


def _dotted_problems(dotted: str, page: Path) -> list[str]:
    """``omnirotor.a.b.Name``: the longest module prefix must exist and define the next name (statically)."""
    parts = dotted.split(".")
    module = None
    i = len(parts)
    while i > 0:
        base = ROOT / "src" / Path(*parts[:i])
        for candidate in (base.with_suffix(".py"), base / "__init__.py"):
            if candidate.is_file():
                module = candidate
                break
        if module:
            break
        i -= 1
    if module is None:
        return [f"{page.name}: {dotted}: no such module"]
    if i == len(parts):
        return []
    name = parts[i]
    source = module.read_text()
    defined = (  # defined, assigned, imported, or listed by name (``__all__``, a lazy table)
        rf"^\s*(?:def|class|async def)\s+{name}\b|^\s*{name}\s*[:=]|\bimport\b[^\n]*\b{name}\b|^\s+{name},?$"
        rf"|[\"']{name}[\"']"
    )
    if not re.search(defined, source, re.M):
        return [f"{page.name}: {dotted}: {module.relative_to(ROOT)} defines no {name}"]
    return []


# --- the tests -----------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("page", DOCS, ids=lambda p: p.name)
def test_every_command_and_option_written_exists(page):
    problems = [p for code in code_texts(page.read_text()) for p in cli_problems(code)]
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("page", DOCS, ids=lambda p: p.name)
def test_every_relative_link_and_image_resolves(page):
    problems = link_problems(page.read_text(), page)
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("page", DOCS, ids=lambda p: p.name)
def test_every_file_and_module_named_exists(page):
    problems = [p for code in code_texts(page.read_text()) for p in path_problems(code, page)]
    assert not problems, "\n".join(problems)


def test_the_pages_name_commands_at_all():
    """The checks above see the invocations: the README's table alone names every command of the app."""
    named = {inv.split()[1] for page in DOCS for c in code_texts(page.read_text()) for inv in invocations(c)}
    assert set(cli_tree().commands) <= named, set(cli_tree().commands) - named


# --- each checker fails on a page that names something gone -------------------------------------------------------

MADE_UP = """
Fly with `omnirotor fly --mission-from-sim --warp-drive` and `omnirotor teleport --to mars`.
`omnirotor ctl [--connect EP] arm\\|somersault` and `omnirotor run sliding --quick --seed 3` (this one is right).

    omnirotor sim --serve --task hover \\
        --no-such-flag

See [the gone page](docs/gone.md), ![a gone figure](docs/img/gone.png) and [the paper](../shared/SPEC.md).
`src/omnirotor/gone.py`, `px4/gone.py`, `gone_module.py`, `tests/test_transport.py::test_that_never_was`,
`omnirotor.fly.bridge.NoSuchClass`, `omnirotor.no_such_module`; `flight/flight.csv` is the user's own file.
"""


def test_the_checkers_find_what_is_gone():
    page = ROOT / "MADE-UP.md"
    codes = code_texts(MADE_UP)
    cli = [p for c in codes for p in cli_problems(c)]
    assert len(cli) == 4, cli
    assert any("no option --warp-drive" in p for p in cli)
    assert any("no command 'teleport'" in p for p in cli)
    assert any("no sub-command 'somersault'" in p for p in cli)
    assert any("no option --no-such-flag" in p for p in cli)  # on a line continued with a backslash

    links = link_problems(MADE_UP, page)
    assert [p.split("-> ")[1] for p in links] == ["docs/gone.md does not exist", "docs/img/gone.png does not exist"]

    paths = [p for c in codes for p in path_problems(c, page)]
    assert len(paths) == 6, paths
    for gone in ("src/omnirotor/gone.py", "px4/gone.py", "gone_module.py", "test_that_never_was", "NoSuchClass"):
        assert any(gone in p for p in paths), gone
    assert any("omnirotor.no_such_module: src/omnirotor/__init__.py defines no no_such_module" in p for p in paths)


def test_the_checkers_accept_what_exists():
    page = ROOT / "README.md"
    right = (
        "`omnirotor ctl [--connect EP] arm\\|takeoff [--height H]\\|goto X Y Z [--yaw D]` "
        "`omnirotor study partitions\\|points-per-region\\|torque-rows --out DIR` `omnirotor --version` "
        "`omnirotor run hover --zero/--no-zero --set pose.kp=1` `src/omnirotor/limits.py` `px4/ulog_guard.py` "
        "`tests/test_docs.py::test_the_checkers_accept_what_exists` `omnirotor.fly.bridge.ImuRateWatch` `_jit.py` "
        "[docs](docs/fly.md)"
    )
    codes = code_texts(right)
    assert [p for c in codes for p in cli_problems(c)] == []
    assert [p for c in codes for p in path_problems(c, page)] == []
    assert link_problems(right, page) == []


def command_table_rows(text: str) -> list[str]:
    """The command names of the README's "Command line" table, one per row (``--version`` for the version's)."""
    section = text.split("\n## Command line\n", 1)[1].split("\n## ", 1)[0]
    rows = [line for line in section.splitlines() if line.startswith("| `omnirotor ")]
    return [row.split("`")[1].split()[1] for row in rows]


def test_the_readme_command_table_has_one_row_per_command():
    rows = command_table_rows((ROOT / "README.md").read_text())
    assert sorted(rows) == sorted({*cli_tree().commands, "--version"}), rows


def test_the_command_table_check_sees_a_missing_or_doubled_row():
    text = (
        "\n## Command line\n\n| command | what |\n|---|---|\n| `omnirotor run TASK` | x |\n| `omnirotor run X` | y |\n"
    )
    text += "\n## Next section\n\n| `omnirotor info` | not the table |\n"
    assert command_table_rows(text) == ["run", "run"]
    assert sorted(command_table_rows(text)) != sorted({*cli_tree().commands, "--version"})


_MSG_TYPE = re.compile(r"\b([a-z]\w*_msgs|builtin_interfaces)/msg/([A-Z]\w*)\b")


def message_type_problems(text: str) -> list[str]:
    """ROS 2 message types (``pkg/msg/Name``) the text names that neither ship here nor are ROS 2's standard ones."""
    from omnirotor.rosmsg import typestore

    known = typestore().fielddefs
    return [f"{m.group(0)} is not a known type" for m in _MSG_TYPE.finditer(text) if m.group(0) not in known]


@pytest.mark.parametrize("page", DOCS, ids=lambda p: p.name)
def test_every_message_type_named_exists(page):
    problems = message_type_problems(page.read_text())
    assert not problems, "\n".join(problems)


def test_the_message_check_finds_a_gone_type():
    text = "`omnirotor_msgs/msg/SensorFrame`, `px4_msgs/msg/EscStatus`, `sensor_msgs/msg/Imu`; `px4_msgs/msg/Gone`"
    assert message_type_problems(text) == ["px4_msgs/msg/Gone is not a known type"]


def strict_xfails(sources: dict[str, str]) -> set[str]:
    """The tests marked ``pytest.mark.xfail(strict=True, ...)`` in ``sources`` (file name -> Python source).

    A decorated function counts, and so does a parametrised case of ``test_sustained_faults.py``'s ``KNOWN`` table
    (scenario name -> reason), written as ``test_each_sustained_fault_ends_within_its_bound[NAME]``.
    """
    import ast

    found = set()
    for source in sources.values():
        tree = ast.parse(source)
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef):
                for deco in node.decorator_list:
                    if (
                        isinstance(deco, ast.Call)
                        and ast.unparse(deco.func).endswith("mark.xfail")
                        and any(k.arg == "strict" and ast.unparse(k.value) == "True" for k in deco.keywords)
                    ):
                        found.add(node.name)
            elif isinstance(node, ast.AnnAssign | ast.Assign):
                targets = [node.target] if isinstance(node, ast.AnnAssign) else node.targets
                if any(isinstance(t, ast.Name) and t.id == "KNOWN" for t in targets) and node.value is not None:
                    found |= {
                        f"test_each_sustained_fault_ends_within_its_bound[{k}]" for k in ast.literal_eval(node.value)
                    }
    return found


def disagreements_listed(text: str) -> list[str]:
    """The tests the README's "Where the simulation still disagrees with the paper" names, in its order."""
    section = text.split("\n### Where the simulation still disagrees with the paper\n", 1)[1].split("\n#", 1)[0]
    return re.findall(r"`(test_[\w\[\]-]+)`", section)


def test_the_readme_lists_every_strict_xfail_as_a_disagreement():
    sources = {p.name: p.read_text() for p in (ROOT / "tests").glob("test_*.py")}
    listed = disagreements_listed((ROOT / "README.md").read_text())
    assert len(listed) == len(set(listed))
    assert set(listed) == strict_xfails(sources)


def test_the_disagreement_check_sees_a_new_or_a_fixed_xfail():
    source = (
        "import pytest\nKNOWN: dict[str, str] = {'frozen-mocap': 'measured 6 cm'}\n"
        "@pytest.mark.xfail(strict=True, reason='0.8 N')\ndef test_a():\n    pass\n"
        "@pytest.mark.xfail(reason='flaky')\ndef test_b():\n    pass\n"
    )
    assert strict_xfails({"t.py": source}) == {
        "test_a",
        "test_each_sustained_fault_ends_within_its_bound[frozen-mocap]",
    }
    readme = "\n### Where the simulation still disagrees with the paper\n\n- one (`test_a`)\n\n## Next\n`test_c`\n"
    assert disagreements_listed(readme) == ["test_a"]  # the new KNOWN case is missing: the test above would fail


def make_problems(code: str, makefile: str) -> list[str]:
    """``make TARGET`` in a piece of code whose target the Makefile does not define."""
    targets = set(re.findall(r"^([a-z][\w-]*)\s*:(?!=)", makefile, re.M))
    return [f"make {t}: no such target" for t in re.findall(r"(?<![\w-])make ([a-z][\w-]*)", code) if t not in targets]


@pytest.mark.parametrize("page", DOCS, ids=lambda p: p.name)
def test_every_make_target_named_exists(page):
    makefile = (ROOT / "Makefile").read_text()
    problems = [p for code in code_texts(page.read_text()) for p in make_problems(code, makefile)]
    assert not problems, "\n".join(problems)


def test_the_make_check_finds_a_gone_target():
    makefile = "demo: $(STAMP)\n\techo\nBENCH_ARGS ?=\ntest: x\n"
    assert make_problems("make demo\nmake test\nmake deploy BENCH_ARGS=--quick", makefile) == [
        "make deploy: no such target"
    ]


def dependency_problems(pyproject: str, table: str) -> list[str]:
    """Pinned dependencies (main and extras) without a row in docs/dependencies.md's table, or with another version.

    A row names one or more packages in its first cell and their versions, in the same order, in its second (a
    cell with no digits, such as "dev extra", names no version).
    """
    import tomllib

    project = tomllib.loads(pyproject)["project"]
    specs = [*project["dependencies"], *(r for extra in project["optional-dependencies"].values() for r in extra)]
    rows = {}
    for line in table.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) >= 2 and line.startswith("| "):
            names = [n.strip() for n in cells[0].split(",")]
            versions = [v.strip() for v in cells[1].split(";")] if ">=" in cells[1] else cells[1].split(", ")
            for i, name in enumerate(names):
                rows[name] = versions[i] if i < len(versions) and re.search(r"\d", cells[1]) else None
    problems = []
    for spec in specs:
        name, version = re.match(r"([A-Za-z0-9_.-]+)\s*(\S*)", spec).groups()
        version = version.removeprefix("==")
        if name not in rows:
            problems.append(f"{name}: no row")
        elif rows[name] is not None and not rows[name].startswith(version):
            problems.append(f"{name}: pinned {version}, the table says {rows[name]}")
    return problems


def test_every_pinned_dependency_is_in_the_table_with_its_version():
    problems = dependency_problems((ROOT / "pyproject.toml").read_text(), (ROOT / "docs/dependencies.md").read_text())
    assert not problems, problems


def test_the_dependency_check_finds_a_missing_or_stale_row():
    pyproject = (
        '[project]\ndependencies = ["numpy==2.4.6", "numba>=0.68.1,<0.70", "zenoh==1.0"]\n'
        '[project.optional-dependencies]\ndev = ["pytest==9.2.0"]\n'
    )
    table = (
        "| package | version | why |\n|---|---|---|\n| numpy | 2.4.5 | arrays |\n"
        "| numba, llvmlite | >=0.68.1,<0.70; >=0.50.0,<0.52 | kernels |\n| pytest, ruff | dev extra | tests |\n"
    )
    assert dependency_problems(pyproject, table) == ["numpy: pinned 2.4.6, the table says 2.4.5", "zenoh: no row"]


def python_block_problems(text: str, page: Path) -> list[str]:
    """The ``python`` code blocks of a page: each must parse, and each name it imports from omnirotor must exist."""
    import ast

    problems = []
    for block in re.findall(r"^```python\n(.*?)^```", text, re.M | re.S):
        try:
            tree = ast.parse(block)
        except SyntaxError as exc:
            problems.append(f"{page.name}: a python block does not parse: {exc}")
            continue
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "omnirotor":
                problems += [p for a in node.names for p in _dotted_problems(f"{node.module}.{a.name}", page)]
            elif isinstance(node, ast.Import):
                problems += [
                    p for a in node.names if a.name.startswith("omnirotor") for p in _dotted_problems(a.name, page)
                ]
    return problems


@pytest.mark.parametrize("page", DOCS, ids=lambda p: p.name)
def test_every_python_example_parses_and_imports_what_exists(page):
    problems = python_block_problems(page.read_text(), page)
    assert not problems, "\n".join(problems)


def test_the_python_check_finds_a_gone_import_and_broken_code():
    page = ROOT / "MADE-UP.md"
    text = (
        "```python\nfrom omnirotor.control.controller import InteractionController, GoneController\n"
        "import omnirotor.gone_package\n```\n\n```python\ncontroller.step(frame\n```\n"
    )
    problems = python_block_problems(text, page)
    assert len(problems) == 3, problems
    for expected in ("defines no GoneController", "defines no gone_package", "does not parse"):
        assert any(expected in p for p in problems), expected


@cache
def known_options() -> frozenset[str]:
    """Every option of every command of the app, and of the scripts in benchmarks/ and tools/ (argparse's)."""
    found: set[str] = set()

    def walk(command) -> None:
        found.update(_options(command))
        for sub in getattr(command, "commands", {}).values():
            walk(sub)

    walk(cli_tree())
    for script in [*(ROOT / "benchmarks").glob("*.py"), *(ROOT / "tools").glob("*.py")]:
        found.update(re.findall(r"[\"'](--[a-z][\w-]*)[\"']", script.read_text()))
    return frozenset(found)


def bare_option_problems(code: str) -> list[str]:
    """A code span that is an option alone (``--blend smooth``): some command or script must have it."""
    m = re.match(r"(--[a-z][\w-]*)", code)
    if m and m.group(1).split("/")[0] not in known_options():
        return [f"{code!r}: no command or script has {m.group(1)}"]
    return []


@pytest.mark.parametrize("page", DOCS, ids=lambda p: p.name)
def test_every_option_written_alone_exists_somewhere(page):
    problems = [p for code in code_texts(page.read_text()) for p in bare_option_problems(code)]
    assert not problems, "\n".join(problems)


def test_the_bare_option_check_finds_a_gone_option():
    codes = code_texts("More options of `run`: `--quick`, `--blend smooth`, `--warp 9`; `bench.py --placements`.")
    assert [p for c in codes for p in bare_option_problems(c)] == ["'--warp 9': no command or script has --warp"]


@cache
def source_words() -> frozenset[str]:
    """Every identifier-like word of the package's Python, TOML and .msg files, lower-cased."""
    words: set[str] = set()
    for path in PACKAGE.rglob("*"):
        if path.suffix in (".py", ".toml", ".msg") and path.is_file():
            words.update(w.lower() for w in re.findall(r"[A-Za-z_][A-Za-z0-9_]*", path.read_text()))
    return frozenset(words)


def format_key_problems(text: str) -> list[str]:
    """Keys and field names in the code spans of the README's "File formats" section that no source file has.

    A file format's key (`reversal_delay_s`, `ee_rms_error_true`, a ULog topic) is read or written by the code
    under that name, so a name the sources no longer contain is a format that changed under the page.
    """
    section = text.split("\n## File formats\n", 1)[1].split("\n## ", 1)[0]
    names = {
        name
        for code in code_texts(section)
        for name in re.findall(r"(?<![\w./-])([a-z][a-z0-9_]*[a-z0-9])(?![\w/(.-])", code)
    }
    return [f"`{name}` is in no source file" for name in sorted(names) if name not in source_words()]


def test_every_file_format_key_named_is_in_the_sources():
    problems = format_key_problems((ROOT / "README.md").read_text())
    assert not problems, problems


def test_the_format_key_check_finds_a_renamed_key():
    text = (
        "\n## File formats\n\n- **Simulator** `[rotors] reversal_delay_s`, `tau_motor_s`; `frame_rejected`\n\n## Next\n"
    )
    assert format_key_problems(text) == ["`tau_motor_s` is in no source file"]


_ROLE = re.compile(r":(?:func|class|mod|data|meth|attr|obj|exc):`~?(omnirotor(?:\.\w+)+)`")


def docstring_problems(source: str, path: Path) -> list[str]:
    """Cross-references (``:func:`omnirotor.x.f```, ``:class:`~omnirotor.y.C```) in a module that point nowhere."""
    return [p for m in _ROLE.finditer(source) for p in _dotted_problems(m.group(1), path)]


def test_every_cross_reference_in_the_docstrings_exists():
    problems = [
        p
        for path in sorted(PACKAGE.rglob("*.py"))
        for p in docstring_problems(path.read_text(), path.relative_to(ROOT))
    ]
    assert not problems, "\n".join(problems)


def test_the_cross_reference_check_finds_a_moved_function():
    source = '"""Flies it (:func:`omnirotor.experiments.loop.run_task`, :class:`~omnirotor.sim.VideoRecorder`)."""'
    assert docstring_problems(source, Path("x.py")) == [
        "x.py: omnirotor.experiments.loop.run_task: src/omnirotor/experiments/loop.py defines no run_task"
    ]


SPEC = ROOT.parent / "shared" / "SPEC.md"


def spec_problems(text: str, spec: str) -> list[str]:
    """``SPEC §N.M`` citations in ``text`` whose section ``spec`` (the SPEC's Markdown) does not have."""
    sections = set(re.findall(r"^#+ (\d+(?:\.\d+)*)[. ]", spec, re.M))
    return [m.group(0) for m in re.finditer(r"SPEC\s*§\s*(\d+(?:\.\d+)*)", text) if m.group(1) not in sections]


def test_every_spec_section_cited_exists():
    if not SPEC.is_file():
        pytest.skip(f"{SPEC} not found (../shared is not beside the checkout)")
    spec = SPEC.read_text()
    problems = [
        f"{path.name}: {p}"
        for path in [*DOCS, *sorted(PACKAGE.rglob("*.py"))]
        for p in spec_problems(path.read_text(), spec)
    ]
    assert not problems, problems


def test_the_spec_check_finds_a_section_that_is_not_there():
    spec = "# SPEC\n## 1. Geometry\n### 1.1 Frames\n## 4. Control\n### 4.5 Other facts\n"
    assert spec_problems("frames (SPEC §1.1), supervision (SPEC §4.5), the lost one (SPEC §4.9)", spec) == ["SPEC §4.9"]


def default_problems(code: str) -> list[str]:
    """``[--option NUMBER]`` in an ``omnirotor`` usage line names the option's default: it must be the app's."""
    problems = []
    for inv in invocations(code):
        words = inv.split()
        command = cli_tree().commands.get(words[1]) if len(words) > 1 else None
        if command is None:
            continue
        params = {name: p for p in command.params for name in getattr(p, "opts", ())}
        for opt, number in re.findall(r"\[(--[a-z][\w-]*) (-?[0-9][0-9.e+-]*)\]", inv):
            default = params[opt].default if opt in params else None
            try:
                same = default is not None and float(default) == float(number)
            except (TypeError, ValueError):
                same = False
            if not same:
                problems.append(f"{inv!r}: {opt} defaults to {default!r}, not {number}")
    return problems


@pytest.mark.parametrize("page", DOCS, ids=lambda p: p.name)
def test_every_default_written_in_a_usage_line_is_the_apps(page):
    problems = [p for code in code_texts(page.read_text()) for p in default_problems(code)]
    assert not problems, "\n".join(problems)


def test_the_default_check_finds_a_changed_default():
    assert default_problems("omnirotor regions --from-signs [--bands 4] [--min-area-frac 0.02]") == []
    assert default_problems("omnirotor identify DATA [--delta 1e-4]") == [
        "'omnirotor identify DATA [--delta 1e-4]': --delta defaults to '3e-5', not 1e-4"
    ]
