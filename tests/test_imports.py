"""The package's imports follow its layers (kddrl_trl.devtools.imports): no cycle, no upward import."""

from kddrl_trl.devtools import imports


def test_the_package_has_no_cycle_and_no_upward_import():
    assert imports.findings() == []


def test_the_scan_reports_a_cycle_and_an_upward_import(monkeypatch):
    edges = imports.graph()
    edges["kddrl_trl.envs.episode_metrics"] = edges["kddrl_trl.envs.episode_metrics"] | {"kddrl_trl.training.trainer"}
    monkeypatch.setattr(imports, "graph", lambda: edges)
    found = imports.findings()
    assert any(
        f.startswith("upward import: envs") and "kddrl_trl.envs.episode_metrics -> kddrl_trl.training.trainer" in f
        for f in found
    )
    assert any(f.startswith("cycle between modules") and "kddrl_trl.envs.episode_metrics" in f for f in found)
    assert any(f.startswith("cycle between parts") and "envs" in f and "training" in f for f in found)


def test_lazy_and_relative_imports_are_seen():
    edges = imports.graph()
    assert "kddrl_trl.eval.render" in edges["kddrl_trl.reporting.figures"]  # imported inside a function
    assert "kddrl_trl.envs.episode_metrics" in edges["kddrl_trl.training.trainer"]  # from ..envs.episode_metrics


def test_the_schema_imports_nothing_lazily():
    """The typed configs import what they validate against at the top of the module, never inside a function."""
    import ast

    path = imports.root() / "conf" / "schema.py"
    lazy = [
        f"line {node.lineno}"
        for fn in ast.walk(ast.parse(path.read_text()))
        if isinstance(fn, ast.FunctionDef)
        for node in ast.walk(fn)
        if isinstance(node, ast.ImportFrom) and (node.level or (node.module or "").startswith("kddrl_trl"))
    ]
    assert not lazy, f"{path}: imports inside functions at {', '.join(lazy)}"


def test_one_checkpoint_error_for_every_checkpoint():
    """A training checkpoint and a GAN checkpoint that cannot be used raise the same error, a refusal (ValueError)
    that an entry point reports in one line."""
    from kddrl_trl.atomic_files import CheckpointError
    from kddrl_trl.generative import CheckpointError as GenerativeError
    from kddrl_trl.training import CheckpointError as TrainingError

    assert TrainingError is GenerativeError is CheckpointError and issubclass(CheckpointError, ValueError)


def test_parsing_a_config_imports_neither_the_runtime_parts_nor_torch():
    """The schema reads its choices from leaf modules: importing it (as every entry point's config parsing does)
    loads no simulator, network, collector, learner or evaluation code, and neither torch nor SUMO."""
    import subprocess
    import sys

    code = "import sys, kddrl_trl.conf.schema; print(' '.join(sorted(sys.modules)))"
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    parts = ("collectors", "envs", "training", "generative", "modules", "eval", "physics", "transforms", "objectives")
    runtime = [
        m for m in loaded if m.split(".")[0] == "kddrl_trl" and len(m.split(".")) > 1 and m.split(".")[1] in parts
    ]
    heavy = [m for m in loaded if m.split(".")[0] in ("torch", "torchrl", "tensordict", "libsumo", "traci", "pandas")]
    assert not runtime and not heavy, (runtime, heavy)
