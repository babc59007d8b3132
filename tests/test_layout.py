"""The distribution's structure: the runtime library ``hexgym`` and the lab ``hexgym_lab`` beside it, hexgym
never importing the lab; in each, layers import downwards only and no import circles; runtime loads no offline
code; each interface is defined once (the plugin's header is generated from Python; the library and the tables
are checked against it at load)."""

import ast
import dataclasses
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from hexgym.mbl.schema import TABLE_SETS, check_table_schema
from hexgym.mbl.table import MBLTable, load_table, load_tables, packaged_tables_dir, table_path
from hexgym.model import plugin

ROOT = Path(__file__).resolve().parent.parent
PACKAGE, LAB = ROOT / "hexgym", ROOT / "hexgym_lab"
PACKAGES = ("hexgym", "hexgym_lab")
# lower layers first: a module may import its own layer and those before it; the lab sits above all of hexgym
LAYERS = (
    "parallel", "files", "interpolation", "machine", "hydraulics", "mbl", "model", "envs", "planning", "wrappers",
    "agents",
)  # fmt: skip
# the lab's: progress (what every long job shows), its offline MBL pipeline, agents, then the harnesses at its top
# level (bench, validate, plan, ...), then the command line over them all
LAB_LAYERS = ("progress", "mbl", "agents", "harnesses", "cli", "__main__")
OFFLINE_LIBRARIES = ("matplotlib", "stable_baselines3", "torch", "ray", "trimesh", "cmaes")


def _layer(module: str) -> int:
    package, part = module.split(".")[0], module.split(".")[1] if "." in module else ""
    if package == "hexgym":
        return LAYERS.index(part) if part in LAYERS else -1  # hexgym.assets, checks, hexgym itself: data, the root
    if not part:
        return -1  # the lab's package docstring
    return len(LAYERS) + LAB_LAYERS.index(part if part in LAB_LAYERS else "harnesses")


def _imports(path: Path) -> set[str]:
    """The hexgym and hexgym_lab modules ``path`` imports anywhere in it (function-local imports included): a
    name imported from a package counts as the module of that name where there is one."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in PACKAGES:
            out.add(node.module)
            out.update(f"{node.module}.{a.name}" for a in node.names if _module_path(f"{node.module}.{a.name}"))
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.split(".")[0] in PACKAGES)
    return out


def _module_path(module: str) -> Path | None:
    """The file of a hexgym or hexgym_lab module, or None."""
    base = ROOT.joinpath(*module.split("."))
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path
    return None


def _module_of(path: Path) -> str:
    return ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")


def _modules() -> list[Path]:
    return sorted([*PACKAGE.rglob("*.py"), *LAB.rglob("*.py")])


def lab_imports(source: str) -> list[tuple[str, int]]:
    """(module, line) of every import of the lab in ``source``: import statements anywhere (module level, in a
    function, under ``if``/``try``) and ``importlib.import_module``/``__import__`` of a literal name."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        elif (
            isinstance(node, ast.Call)
            and getattr(node.func, "attr", getattr(node.func, "id", None)) in ("import_module", "__import__")
            and node.args
            and isinstance(node.args[0], ast.Constant)
            and isinstance(node.args[0].value, str)
        ):
            names = [node.args[0].value]
        else:
            continue
        found += [(name, node.lineno) for name in names if name.split(".")[0] == "hexgym_lab"]
    return found


def test_hexgym_never_imports_the_lab():
    """The runtime library stands alone: what a program imports never reaches collection, fitting, training or
    the command line, not even in a function that runs rarely."""
    wrong = [
        f"{_module_of(path)} imports {name} (line {line})"
        for path in sorted(PACKAGE.rglob("*.py"))
        for name, line in lab_imports(path.read_text())
    ]
    assert not wrong, "hexgym must not import the lab: " + "; ".join(wrong)


def test_the_lab_import_scan_sees_local_and_dynamic_imports():
    source = (
        "import hexgym.envs\n"
        "def f():\n"
        "    from hexgym_lab.agents.evaluate import evaluate\n"
        "    import hexgym_lab.cli as cli\n"
        "    return importlib.import_module('hexgym_lab.validate'), __import__('hexgym_labs')\n"
    )
    assert lab_imports(source) == [("hexgym_lab.agents.evaluate", 3), ("hexgym_lab.cli", 4), ("hexgym_lab.validate", 5)]


def test_importing_every_hexgym_module_loads_no_lab_module():
    modules = [_module_of(path) for path in sorted(PACKAGE.rglob("*.py"))]
    code = f"import importlib, sys\nfor m in {modules!r}: importlib.import_module(m)\nprint(' '.join(sys.modules))"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stderr
    assert [m for m in result.stdout.split() if m.split(".")[0] == "hexgym_lab"] == []


def test_layers_import_downwards_only():
    wrong = []
    for path in _modules():
        module = _module_of(path)
        if _layer(module) < 0:
            continue
        for target in _imports(path):
            if _layer(target) > _layer(module):
                wrong.append(f"{module} imports {target}")
    assert not wrong, wrong


def test_no_module_imports_itself_through_others():
    """No import circle in either package or between them, function-local imports included (a package's
    ``__init__`` re-exporting its modules is no circle: its modules never import the package)."""
    graph = {}
    for path in _modules():
        module = _module_of(path)
        graph[module] = {t for t in _imports(path) if t != module and _module_path(t) and t not in PACKAGES}
    circles, done = [], set()

    def visit(module: str, trail: list[str]) -> None:
        for target in sorted(graph.get(module, ())):
            if target in trail:
                circles.append(" -> ".join([*trail[trail.index(target) :], target]))
            elif target not in done:
                visit(target, [*trail, target])
        done.add(module)

    for module in sorted(graph):
        if module not in done:
            visit(module, [module])
    assert not circles, circles


def test_runtime_loads_no_offline_code_and_the_plugin_only_for_a_native_model():
    code = (
        "import sys, hexgym, gymnasium\n"
        "assert 'hexgym.model.plugin' not in sys.modules, 'import hexgym loaded the plugin'\n"
        "gymnasium.make('HexLoading-v0').reset(seed=0)\n"
        "print(' '.join(sorted(sys.modules)))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stderr
    loaded = set(result.stdout.split())
    offline = [m for m in loaded if m.split(".")[0] in ("hexgym_lab", *OFFLINE_LIBRARIES)]
    assert not offline, offline
    offline = [m for m in loaded if m.startswith("hexgym.agents")]  # the scripted loader: only when asked for
    assert not offline, offline
    assert "hexgym.model.python_backend" in loaded or "hexgym.model.native_backend" in loaded


def test_the_committed_interface_header_is_generated_from_python():
    committed = (ROOT / plugin.HEADER).read_text()
    assert committed == plugin.header_text(), "native/plugin_interface.h is stale: run `hexgym build-assets`"


@pytest.mark.skipif(plugin.plugin_library() is None, reason="native plugin not built")
def test_the_library_reports_the_python_interface():
    assert plugin._interface_error(plugin.plugin_library()) == ""


def test_an_interface_mismatch_is_named(monkeypatch):
    if plugin.plugin_library() is None:
        pytest.skip("native plugin not built")
    changed = {**plugin.interface(), "state_size": plugin.STATE_SIZE + 1}
    monkeypatch.setattr(plugin, "interface", lambda: changed)
    message = plugin._interface_error(plugin.plugin_library())
    size = plugin.STATE_SIZE
    assert f"state_size: library {size} vs Python {size + 1}" in message and "rebuild" in message


def test_interface_differences_name_each_side():
    assert plugin.interface_differences({"a": 1, "b": [2]}, {"a": 1, "b": [3], "c": 0}) == [
        "b: library [2] vs Python [3]",
        "c: library null vs Python 0",
    ]


def test_a_table_that_differs_from_the_schema_is_refused_naming_file_and_difference(tmp_path):
    for name in TABLE_SETS["paper"]:
        shutil.copy(table_path(name, table_set="paper"), tmp_path / f"{name}.npz")
    boom = load_table(table_path("boom", packaged_tables_dir("paper")))
    order = (1, 0, 2, 3)
    swapped = MBLTable(
        boom.name,
        tuple(boom.inputs[i] for i in order),
        boom.output,
        tuple(boom.axes[i] for i in order),
        boom.values.transpose(order),
        boom.confidence.transpose(order),
        dataclasses.replace(boom.params, input_scales=tuple(boom.params.input_scales[i] for i in order)),
        boom.metrics,
        boom.data_hash,
    )
    (tmp_path / "boom.npz").unlink()
    swapped.save(tmp_path / "boom.npz")
    with pytest.raises(
        ValueError, match=r"boom\.npz: table 'boom' does not match the 'paper' schema: inputs in the order"
    ):
        load_tables(tmp_path, "paper")


def test_schema_check_names_missing_extra_and_output():
    spec = TABLE_SETS["paper"]["swing"]
    with pytest.raises(ValueError, match=r"f\.npz: .*missing inputs \['swing_rate_radps'\]"):
        check_table_schema("f.npz", "swing", spec.inputs[:-1], spec.output, "paper")
    with pytest.raises(ValueError, match=r"extra inputs \['boom_force_n'\].*output 'x'"):
        check_table_schema("f.npz", "swing", (*spec.inputs, "boom_force_n"), "x", "paper")


def test_interface_json_round_trips():
    assert json.loads(plugin.interface_json()) == plugin.interface()


def test_the_backend_variable_makes_auto_pick_python(monkeypatch):
    from hexgym.model.backend import resolve_backend

    monkeypatch.setenv("HEXGYM_BACKEND", "python")
    assert resolve_backend("auto") == "python"
    assert resolve_backend("native") == "native"  # an explicit choice stands
    monkeypatch.setenv("HEXGYM_BACKEND", "fortran")
    with pytest.raises(ValueError, match="HEXGYM_BACKEND='fortran'"):
        resolve_backend("auto")
    with pytest.raises(ValueError, match="backend must be one of"):
        resolve_backend("cuda")
