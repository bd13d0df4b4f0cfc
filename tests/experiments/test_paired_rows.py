"""experiments.paired_rows: rows of twin evaluations compared on the piles they share."""

import json
import math

import pytest

from experiments.measure import paired
from experiments.paired_rows import compare, main, read_row


def _write(folder, records):
    (folder / "records").mkdir(parents=True)
    for seed in sorted({r["seed"] for r in records}):
        (folder / "records" / f"{seed}.json").write_text(json.dumps([r for r in records if r["seed"] == seed]))


def _rec(planner, seed, ok, grasped=(0, 1), cos_beta=1.0):
    return {"planner": planner, "n_logs": 3, "obstacles": False, "k": 0, "seed": seed,
            "outcome": "success" if ok else "dropped", "grasped": list(grasped), "cos_beta": cos_beta, "plan_s": 0.5}


def test_rows_from_two_folders_are_paired_on_their_common_piles(tmp_path, capsys):
    a_ok = [1, 1, 0, 0, 1, 0]
    b_ok = [1, 1, 1, 1, 0]  # one pile fewer: the sixth is left out of both rows
    _write(tmp_path / "a", [_rec("unet-f3", s, ok) for s, ok in enumerate(a_ok)]
           + [_rec("random", s, False) for s in range(6)])
    _write(tmp_path / "b", [_rec("unet-f3-views8", s, ok, (0, 1, 2), math.cos(math.radians(10)))
                            for s, ok in enumerate(b_ok)])
    table = compare({"a": read_row(tmp_path / "a", "unet-f3"), "b": read_row(tmp_path / "b", "unet-f3-views8")})
    assert [t["piles"] for t in table] == [5, 5]
    assert table[0]["success"] == pytest.approx(60.0) and table[1]["success"] == pytest.approx(80.0)
    assert table[1]["logs"] == 3.0 and table[1]["beta_deg"] == pytest.approx(10.0)
    d, lo, hi = paired(a_ok[:5], b_ok)
    assert table[1]["diff_pp"] == pytest.approx(20.0) == pytest.approx(d) and table[1]["ci_pp"] == (lo, hi)
    assert lo < 0 < hi  # two discordant piles settle nothing
    main([f"{tmp_path / 'a'}:unet-f3", f"{tmp_path / 'b'}:unet-f3-views8"])
    assert "| 5 | 80.0 % | 3.00 | 10.0° | +20.0 (" in capsys.readouterr().out


def test_a_missing_row_or_no_common_pile_is_one_clear_error(tmp_path, capsys):
    _write(tmp_path / "a", [_rec("unet-f1", 1, True)])
    _write(tmp_path / "b", [_rec("unet-f1", 2, True)])
    with pytest.raises(SystemExit):
        main([f"{tmp_path / 'a'}:unet-f9"])
    assert "no records of planner 'unet-f9'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([f"{tmp_path / 'a'}:unet-f1", f"{tmp_path / 'b'}:unet-f1"])
    assert "share no pile" in capsys.readouterr().err


def test_runs_from_another_seed_base_pair_on_the_seeds_they_share(tmp_path):
    """A pile is its seed: a run started 20 piles into each cell (--seed-base + 20) numbers the same piles
    k 0, 1, ... where the full run numbered them 20, 21, ..."""
    _write(tmp_path / "full", [{**_rec("unet-f1", 970_000_020 + i, i % 2 == 0), "k": 20 + i} for i in range(4)])
    _write(tmp_path / "late", [{**_rec("unet-f1", 970_000_020 + i, True), "k": i} for i in range(4)])
    table = compare({"a": read_row(tmp_path / "full", "unet-f1"), "b": read_row(tmp_path / "late", "unet-f1")})
    assert [t["piles"] for t in table] == [4, 4] and table[1]["diff_pp"] == pytest.approx(50.0)
