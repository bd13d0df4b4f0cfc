"""The one versioned-JSON reader/writer (synth.common.formats), as a contract every format of the
tree passes: what it writes it reads back; a missing, non-JSON, foreign or other-major-version
file fails with the format's own error class and a one-line message naming the file."""

import importlib
import json

import pytest

from synth.common.formats import VersionedJson, major

#: modules that declare the tree's versioned JSON formats (module-level VersionedJson objects)
MODULES = ("synth.scene.pile", "synth.data.shards", "synth.data.datastore", "synth.render.ortho", "synth.render.stereo",
           "synth.geometry.calibration", "experiments.case_studies", "planner.verify", "planner.train", "field.geo", "experiments.real_test",
           "field.trial_record")


def all_formats() -> list[tuple[str, VersionedJson]]:
    out = []
    for name in MODULES:
        mod = importlib.import_module(name)
        out += [(f"{name}.{k}", v) for k, v in vars(mod).items() if isinstance(v, VersionedJson)]
    return out


FORMATS = all_formats()


def test_every_module_declares_its_formats():
    assert len(FORMATS) >= 14, [n for n, _ in FORMATS]
    names = [f.name for _, f in FORMATS]
    assert len(set(names)) == len(names), "two VersionedJson objects for one format name"


@pytest.mark.parametrize("label,fmt", FORMATS, ids=[n for n, _ in FORMATS])
def test_contract(tmp_path, label, fmt):
    p = fmt.write(tmp_path / "f.json", {"x": 1.5, "format": "ignored"})
    d = json.loads(p.read_text())
    assert list(d)[:2] == ["format", "format_version"] and d["format"] == fmt.name
    assert fmt.read(p) == {"format": fmt.name, "format_version": fmt.version, "x": 1.5}
    later_minor = f"{fmt.major}.99"
    p.write_text(json.dumps({"format": fmt.name, "format_version": later_minor}))
    assert fmt.read(p)["format_version"] == later_minor  # same major: read

    def fails(text, *fragments, path=p):
        if text is not None:
            path.write_text(text)
        with pytest.raises(fmt.error) as ei:
            fmt.read(path)
        msg = str(ei.value)
        assert "\n" not in msg and str(path) in msg, msg
        for frag in fragments:
            assert frag in msg, msg
        return msg

    fails(None, "missing", path=tmp_path / "none.json")
    fails("{not json", "not valid JSON")
    fails("[1, 2]", f"not a loggrasp {fmt.what}")
    fails(json.dumps({"format": "someone.else", "format_version": fmt.version}), "someone.else", fmt.name)
    newer = f"{int(fmt.major) + 1}.0"
    msg = fails(json.dumps({"format": fmt.name, "format_version": newer}), repr(newer), "not supported",
                "newer", fmt.fix)
    assert f"reads {fmt.major}.x" in msg


def test_folder_reads_its_file(tmp_path):
    fmt = VersionedJson("loggrasp.test", "1.0", "test file", ValueError, filename="t.json")
    fmt.write(tmp_path, {"a": 1})
    assert (tmp_path / "t.json").is_file() and fmt.read(tmp_path)["a"] == 1


def test_check_without_a_path_and_major():
    fmt = VersionedJson("loggrasp.test", "2.3", "test file", KeyError)
    assert fmt.check({"format": "loggrasp.test", "format_version": "2.0"}) == {"format": "loggrasp.test",
                                                                               "format_version": "2.0"}
    with pytest.raises(KeyError, match="reads 2.x"):
        fmt.check({"format": "loggrasp.test", "format_version": "1.9"})
    assert major("1.2") == "1" and major(None) == "None"
