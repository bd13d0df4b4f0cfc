"""The tree is the architecture: synth at the bottom; planner and reconstruct use synth, never each
other; field uses them all; nothing imports field."""

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("synth", "planner", "reconstruct", "field")
ALLOWED = {
    "synth": set(),
    "planner": {"synth"},
    "reconstruct": {"synth"},
    "field": {"synth", "planner", "reconstruct"},
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
    """A command-line module: ``<package>/cli.py`` (and anything below a ``cli`` folder) or
    ``synth/cli_common.py``, the helpers those share."""
    parts = module.split(".")
    return "cli" in parts or parts[-1] == "cli_common"


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
    bad.write_text("def f():\n    from planner.cli import DEFAULT_MODEL\nfrom synth import cli_common\n")
    assert {m for m in imported_modules(bad) if is_cli(m)} >= {"planner.cli", "synth.cli_common"}
    assert not is_cli("planner.inference") and is_cli("field.cli") and is_cli("synth.cli_common")


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


#: library files that still read ``format_version`` by hand, each with its reason; every other
#: versioned JSON file is read through synth.common.formats.VersionedJson
HAND_VERSION_READS = {
    "synth/common/formats.py": "the one reader",
    "synth/dataset.py": "a minor-version detail: 1.0 shards are re-encoded on load",
    "reconstruct/pipeline.py": "read_scan_pose, read_report: to move to VersionedJson once the recon branch is merged",
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
