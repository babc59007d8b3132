"""The package's structure: layers import downwards only, runtime loads no offline code, each
interface is defined once (the plugin's header is generated from Python; the library and the tables
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
PACKAGE = ROOT / "hexgym"
# lower layers first: a module may import its own layer and those before it
LAYERS = (
    "parallel", "files", "interpolation", "machine", "hydraulics", "mbl", "model", "envs", "planning", "wrappers",
    "agents", "tools",
)  # fmt: skip
OFFLINE = ("hexgym.mbl.collect", "hexgym.mbl.fit", "hexgym.mbl.lwr", "hexgym.mbl.baselines", "hexgym.mbl.grid")


def _layer(module: str) -> int:
    part = module.split(".")[1]
    return LAYERS.index(part) if part in LAYERS else -1  # hexgym.assets, hexgym itself: data, the root


def _imports(path: Path) -> set[str]:
    """The hexgym modules ``path`` imports anywhere in it (function-local imports included): a name imported
    from a package counts as the module of that name where there is one."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("hexgym."):
            out.add(node.module)
            out.update(f"{node.module}.{a.name}" for a in node.names if _module_path(f"{node.module}.{a.name}"))
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.startswith("hexgym."))
    return out


def _module_path(module: str) -> Path | None:
    """The file of a hexgym module, or None."""
    base = ROOT.joinpath(*module.split("."))
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path
    return None


def _module_of(path: Path) -> str:
    return "hexgym." + ".".join(path.relative_to(PACKAGE).with_suffix("").parts).removesuffix(".__init__")


def test_layers_import_downwards_only():
    wrong = []
    for path in PACKAGE.rglob("*.py"):
        module = _module_of(path)
        if module.count(".") < 1 or _layer(module) < 0:
            continue
        for target in _imports(path):
            if _layer(target) > _layer(module):
                wrong.append(f"{module} imports {target}")
    assert not wrong, wrong


def test_no_module_imports_itself_through_others():
    """No import circle, function-local imports included (a package's ``__init__`` re-exporting its modules is
    no circle: its modules never import the package)."""
    graph = {}
    for path in PACKAGE.rglob("*.py"):
        module = _module_of(path)
        graph[module] = {t for t in _imports(path) if t != module and _module_path(t) and t != "hexgym"}
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
    offline = [m for m in loaded if m in OFFLINE or m.startswith(("hexgym.tools", "hexgym.agents", "matplotlib"))]
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
