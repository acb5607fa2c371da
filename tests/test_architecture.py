"""The package's layers: every import points downward, and no import hook or shim remains."""

import ast
import importlib
import subprocess
import sys
from pathlib import Path

import pytest

import mpipe

PACKAGE = Path(mpipe.__file__).parent
#: Subpackages from the bottom up: a module may import its own layer and the ones below.
LAYERS = ("core", "acoustics", "measurement", "reed", "inversion", "pipeline", "cli")


def _imports(path: Path):
    """(line, imported module) of every import in a file, including those inside functions."""
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            if node.module == "mpipe":  # from mpipe import x: x is a module or the version
                for alias in node.names:
                    if alias.name != "__version__":
                        yield node.lineno, f"mpipe.{alias.name}"
            else:
                yield node.lineno, node.module


def _modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE).parts
        if len(parts) > 1:  # the facade (mpipe/__init__.py) is exempt
            yield parts[0], path


def test_every_module_lives_in_a_layer():
    assert {layer for layer, _ in _modules()} <= set(LAYERS)


def test_imports_point_downward_and_name_real_modules():
    wrong = []
    for layer, path in _modules():
        for line, name in _imports(path):
            if not name.startswith("mpipe.") and name != "mpipe":
                continue
            where = f"{path.relative_to(PACKAGE.parent)}:{line} imports {name}"
            target = name.split(".")[1] if "." in name else None
            if target not in LAYERS:
                wrong.append(f"{where}: not a module of the layered package")
            elif LAYERS.index(target) > LAYERS.index(layer):
                wrong.append(f"{where}: {layer} may not import the higher layer {target}")
    assert not wrong, "\n".join(wrong)


def test_the_check_catches_an_upward_import(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("def f():\n    from mpipe.pipeline.report import write_take_report\n")
    assert list(_imports(bad)) == [(2, "mpipe.pipeline.report")]


#: Module paths of mpipe 0.1, before the subpackages: no shim keeps them importable.
OLD_PATHS = ("mpipe.separation", "mpipe.takes", "mpipe.model", "mpipe.commands.run")


def test_importing_mpipe_installs_no_import_hook():
    code = (
        "import sys; before = list(sys.meta_path); import mpipe, mpipe.pipeline; "
        "print(sys.meta_path == before)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == "True", out.stderr[-500:]


@pytest.mark.parametrize("old", OLD_PATHS)
def test_old_module_paths_are_gone(old):
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module(old)


def test_no_module_forwards_names_with_a_module_level_getattr():
    # only the facade has one, and it serves the public API, not moved names
    found = [
        path.relative_to(PACKAGE.parent)
        for path in sorted(PACKAGE.rglob("*.py"))
        for node in ast.parse(path.read_text()).body
        if isinstance(node, ast.FunctionDef) and node.name == "__getattr__"
    ]
    assert [str(p) for p in found] == ["mpipe/__init__.py"]
    with pytest.raises(ImportError):
        from mpipe.pipeline import InversionConfig  # noqa: F401  (0.1 had it here)
    with pytest.raises(AttributeError, match="no attribute 'separation'"):
        mpipe.separation  # noqa: B018


def test_public_api_names_resolve():
    for name in mpipe.__all__:
        assert getattr(mpipe, name) is not None


def test_submodules_of_pipeline_import_in_a_fresh_interpreter():
    code = "from mpipe.pipeline import settings, report; print(settings.load_pipeline.__name__)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == "load_pipeline", out.stderr[-500:]


def test_architecture_page_lists_every_module():
    page = (PACKAGE.parent / "docs" / "architecture.md").read_text()
    start = page.index("```\nmpipe/\n")
    block = page[start : page.index("```\n", start + 4)]
    for sep in ",()/":
        block = block.replace(sep, " ")
    words = set(block.split())
    missing = [
        f"{layer}/{path.stem}"
        for layer, path in _modules()
        if path.stem != "__init__" and path.parent.name != "commands" and path.stem not in words
    ]
    assert not missing, f"docs/architecture.md does not name: {missing}"


#: A module a reader can hold: lines per module, code lines per function (docstring excluded).
MAX_MODULE_LINES = 500
MAX_FUNCTION_LINES = 80


def test_modules_and_functions_stay_readable():
    long_modules, long_functions = [], []
    for path in sorted(PACKAGE.rglob("*.py")):
        text = path.read_text()
        if text.count("\n") > MAX_MODULE_LINES:
            long_modules.append(f"{path.relative_to(PACKAGE)} ({text.count(chr(10))} lines)")
        lines = text.splitlines()
        for node in ast.walk(ast.parse(text)):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            first = node.body[0]
            has_doc = isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant)
            start = first.end_lineno + 1 if has_doc else first.lineno
            # a function may be long on purpose when the comment just above it says so
            above = lines[max(node.lineno - 4, 0) : node.lineno - 1]
            if node.end_lineno - start + 1 > MAX_FUNCTION_LINES and not any(
                "Long on purpose" in line for line in above
            ):
                long_functions.append(f"{path.relative_to(PACKAGE)}:{node.lineno} {node.name}")
    assert not long_modules, long_modules
    assert not long_functions, long_functions


#: Functions that may take more than ten parameters: none (issue 45's house; issue 23 had
#: turned long positional lists into records). One that must would say why in a comment just
#: above it containing "More than ten parameters", and raise this count.
MAX_LONG_SIGNATURES = 0


def _parameter_count(node: ast.FunctionDef) -> int:
    a = node.args
    n = len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs)
    n += (a.vararg is not None) + (a.kwarg is not None)
    return n - bool(a.args and a.args[0].arg in ("self", "cls"))


def _long_signatures(text: str):
    """(line, name, parameters, explained) of each function with more than ten parameters."""
    lines = text.splitlines()
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            n = _parameter_count(node)
            if n > 10:
                first = min([node.lineno] + [d.lineno for d in node.decorator_list])
                above = lines[max(first - 4, 0) : first - 1]
                why = any("More than ten parameters" in line for line in above)
                yield node.lineno, node.name, n, why


def test_few_functions_take_more_than_ten_parameters_and_each_says_why():
    found = [
        (f"{path.relative_to(PACKAGE)}:{line} {name} ({n})", why)
        for path in sorted(PACKAGE.rglob("*.py"))
        for line, name, n, why in _long_signatures(path.read_text())
    ]
    assert len(found) <= MAX_LONG_SIGNATURES, [f for f, _ in found]
    assert all(why for _, why in found), [f for f, why in found if not why]


def test_the_signature_check_counts_every_kind_of_parameter():
    text = (
        "def short(a, b, *, c=1):\n    pass\n\n\n"
        "def f(a, b, c, d, /, e, f, g, *args, h, i, **kw):\n    pass\n\n\n"
        "class C:\n"
        "    # More than ten parameters: a test of the reason\n"
        "    def m(self, a, b, c, d, e, f, g, h, i, j, k):\n        pass\n"
    )
    assert [(name, n, why) for _, name, n, why in _long_signatures(text)] == [
        ("f", 11, False),
        ("m", 11, True),
    ]


def _private_imports(text: str):
    """Names with a leading underscore imported from another mpipe module."""
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("mpipe"):
            for alias in node.names:
                if alias.name.startswith("_") and not alias.name.startswith("__"):
                    yield node.lineno, f"{node.module}.{alias.name}"


def test_no_private_name_crosses_a_module():
    found = [
        f"{path.relative_to(PACKAGE)}:{line} imports {name}"
        for path in sorted(PACKAGE.rglob("*.py"))
        for line, name in _private_imports(path.read_text())
    ]
    assert not found, "\n".join(found)
    bad = "from mpipe.reed.kernels import _step, run\nfrom mpipe import __version__\n"
    assert list(_private_imports(bad)) == [(1, "mpipe.reed.kernels._step")]
