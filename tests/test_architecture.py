"""The tree is the architecture: synth at the bottom; planner and reconstruct use synth, never each
other; field uses them all; experiments (the measuring harnesses) use everything and no product
package imports them."""

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("synth", "planner", "reconstruct", "field", "experiments")
ALLOWED = {
    "synth": set(),
    "planner": {"synth"},
    "reconstruct": {"synth"},
    "field": {"synth", "planner", "reconstruct"},
    "experiments": {"synth", "planner", "reconstruct", "field"},
}


def imported_packages(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        found |= {n.split(".")[0] for n in names if n.split(".")[0] in PACKAGES}
    return found


def is_cli(module: str) -> bool:
    """A command-line module: ``<package>/cli.py`` (and anything below a ``cli`` folder), e.g.
    ``synth/common/cli.py``, the helpers those share."""
    return "cli" in module.split(".")


def imported_modules(path: Path) -> set[str]:
    """Every module ``path`` imports, by absolute dotted name (``from synth import cli`` counts as
    ``synth.cli``)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.add(node.module)
            found |= {f"{node.module}.{a.name}" for a in node.names}
    return found


def test_no_library_module_imports_a_cli_module():
    """Commands sit on top of the library: a library module (anything but a CLI module) never
    imports one, so library code does not depend on typer, flag parsing or printing."""
    bad = []
    for package in PACKAGES:
        for f in sorted((ROOT / package).rglob("*.py")):
            me = ".".join(f.relative_to(ROOT).with_suffix("").parts)
            if is_cli(me):
                continue
            clis = sorted(m for m in imported_modules(f) if m.split(".")[0] in PACKAGES and is_cli(m))
            if clis:
                bad.append(f"{f.relative_to(ROOT)} imports {clis}")
    assert not bad, "library modules import CLI modules (move what they need into the library):\n" + "\n".join(bad)


def test_cli_checker_sees_violations(tmp_path):
    bad = tmp_path / "m.py"
    bad.write_text("def f():\n    from planner.cli import DEFAULT_MODEL\nfrom synth.common import cli\n")
    assert {m for m in imported_modules(bad) if is_cli(m)} >= {"planner.cli", "synth.common.cli"}
    assert not is_cli("planner.inference") and is_cli("field.cli") and is_cli("synth.common.cli")


@pytest.mark.parametrize("package", PACKAGES)
def test_dependency_direction(package):
    files = sorted((ROOT / package).rglob("*.py"))
    assert files, f"package {package} has no modules"
    for f in files:
        bad = imported_packages(f) - ALLOWED[package] - {package}
        assert not bad, f"{f.relative_to(ROOT)} imports {sorted(bad)}, which {package} must not use"


def test_checker_sees_violations(tmp_path):
    bad = tmp_path / "m.py"
    bad.write_text("import os\nfrom field.cli import app\ndef f():\n    import planner.model\n")
    assert imported_packages(bad) == {"field", "planner"}


#: synth's sub-packages, one per stage, and the only modules at its top level
SYNTH_STAGES = {"common", "geometry", "scene", "physics", "render", "data"}
SYNTH_TOP_MODULES = {"__init__.py", "cli.py", "errors.py"}
#: what each synth sub-package may import from synth (besides itself): common and geometry see no
#: simulator, so reconstruction and the field stack read frames, geodesy and calibrations through them
SYNTH_ALLOWED = {
    "common": set(),
    "geometry": {"common", "errors"},
}


def test_synth_is_split_by_stage():
    top = {p.name for p in (ROOT / "synth").iterdir() if p.suffix == ".py"}
    stages = {p.name for p in (ROOT / "synth").iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    assert top == SYNTH_TOP_MODULES, f"synth/ has modules outside its stages: {sorted(top - SYNTH_TOP_MODULES)}"
    assert stages == SYNTH_STAGES, f"synth's sub-packages are {sorted(stages)}, want {sorted(SYNTH_STAGES)}"


#: reconstruct's stages, and what sits at its top: georegistration (the scan pose and its refinement;
#: the coarse placement is the scan stage's), the pipeline that runs the stages, its configuration and
#: its report, the comparison with a true pile, the command line and the errors
RECONSTRUCT_STAGES = {"scan", "survey", "fitting"}
RECONSTRUCT_TOP_MODULES = {"__init__.py", "cli.py", "errors.py", "registration.py", "pipeline.py", "config.py",
                           "report.py", "compare.py"}


def test_reconstruct_is_split_by_stage():
    root = ROOT / "reconstruct"
    top = {p.name for p in root.iterdir() if p.suffix == ".py"}
    stages = {p.name for p in root.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    assert top == RECONSTRUCT_TOP_MODULES, f"modules outside reconstruct's stages: {sorted(top - RECONSTRUCT_TOP_MODULES)}"
    assert stages == RECONSTRUCT_STAGES, f"reconstruct's sub-packages: {sorted(stages)}, want {sorted(RECONSTRUCT_STAGES)}"


def synth_parts(path: Path) -> set[str]:
    """The synth sub-packages (or top-level modules) ``path`` imports: ``synth.scene.pile`` -> scene."""
    return {m.split(".")[1] for m in imported_modules(path) if m.startswith("synth.") and len(m.split(".")) > 1}


@pytest.mark.parametrize("stage", sorted(SYNTH_ALLOWED))
def test_shared_stages_do_not_reach_into_the_simulator(stage):
    for f in sorted((ROOT / "synth" / stage).rglob("*.py")):
        if is_cli(".".join(f.relative_to(ROOT).with_suffix("").parts)):
            continue
        bad = synth_parts(f) - SYNTH_ALLOWED[stage] - {stage}
        assert not bad, f"{f.relative_to(ROOT)} imports synth.{sorted(bad)}, which synth.{stage} must not use"


def test_stage_checker_sees_violations(tmp_path):
    bad = tmp_path / "m.py"
    bad.write_text("from synth.scene.pile import PileSpec\ndef f():\n    import synth.physics.world\n")
    assert synth_parts(bad) >= {"scene", "physics"}


#: experiment scripts that still edit sys.path, each with its reason
SYS_PATH_EDITS: dict[str, str] = {}


def experiment_scripts() -> list[Path]:
    return sorted([*(ROOT / "bench").glob("*.py"), *(ROOT / "scripts").glob("*.py")])


def private_imports(path: Path) -> list[str]:
    """The ``_private`` names ``path`` imports from loggrasp's packages."""
    tree = ast.parse(path.read_text(), filename=str(path))
    return [f"{node.module}.{a.name}" for node in ast.walk(tree)
            if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in PACKAGES
            for a in node.names if a.name.startswith("_")]


def test_experiments_use_the_installed_packages_public_functions():
    """bench/ and scripts/ are thin calls over the packages: no sys.path edits (the package is
    installed), no private names (what they need is public)."""
    edits = [str(f.relative_to(ROOT)) for f in experiment_scripts()
             if "sys.path.insert" in f.read_text() or "sys.path.append" in f.read_text()]
    assert sorted(set(edits) - set(SYS_PATH_EDITS)) == [], f"{edits} edit sys.path"
    private = {str(f.relative_to(ROOT)): private_imports(f) for f in experiment_scripts()}
    assert not {f: p for f, p in private.items() if p}, f"experiments import private names: {private}"


def test_no_package_imports_another_packages_private_names():
    """What one package needs of another is public: a ``_name`` is free to change inside its own
    package (experiments/ reached into planner.inference's ``_observation_arrays`` before)."""
    crossing = {}
    for package in PACKAGES:
        for f in (ROOT / package).rglob("*.py"):
            names = [n for n in private_imports(f) if n.split(".")[0] != package]
            if names:
                crossing[str(f.relative_to(ROOT))] = names
    assert not crossing, f"private names imported across packages: {crossing}"


def test_private_import_checker_sees_violations(tmp_path):
    bad = tmp_path / "m.py"
    bad.write_text("from experiments.real_test import _execute, summarize\nfrom os import _exit\n")
    assert private_imports(bad) == ["experiments.real_test._execute"]


#: library files that still read ``format_version`` by hand, each with its reason; every other
#: versioned JSON file is read through synth.common.formats.VersionedJson
HAND_VERSION_READS = {
    "synth/common/formats.py": "the one reader",
    "synth/data/shards.py": "a minor-version detail: 1.0 shards are re-encoded on load",
    "synth/data/dataset.py": "a resumed job compares the major version in its recorded parameters",
}


def test_versioned_json_is_checked_in_one_place():
    pattern = re.compile(r"""\.get\(\s*["']format_version["']""")
    bad = []
    for package in PACKAGES:
        for f in sorted((ROOT / package).rglob("*.py")):
            rel = str(f.relative_to(ROOT))
            by_hand = [line for line in f.read_text().splitlines()
                       if pattern.search(line) and "check_version(" not in line]
            if by_hand and rel not in HAND_VERSION_READS:
                bad.append(rel)
    assert not bad, (f"{bad} check format_version by hand; declare a synth.common.formats.VersionedJson and use "
                     "its read / check")


#: how long a module may grow (STYLE.md: one concern each, at most 600 lines)
MAX_MODULE_LINES = 600


def test_every_module_is_at_most_600_lines():
    """A module past 600 lines holds more than one concern: split it by concern (e.g.
    experiments.survey_conditions runs the bench, experiments.survey_report reports it)."""
    roots = [ROOT / p for p in (*PACKAGES, "bench", "scripts", "tests")]
    long = {str(f.relative_to(ROOT)): n for r in roots for f in r.rglob("*.py")
            if (n := len(f.read_text().splitlines())) > MAX_MODULE_LINES}
    assert not long, f"modules over {MAX_MODULE_LINES} lines: {long}"
