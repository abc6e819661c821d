"""Training runs side by side on their held-out curves."""

import json

from physdrape.train.compare import COLUMNS, main


def _run(path, values):
    path.mkdir()
    rows = []
    for step, gap in values:
        row = {"step": step, "wall_s": 1.0, "solver_t3/energy_ratio": 1.2, "solver_t3/energy_gap": 0.4,
               "solver_t15/energy_ratio": 1.03, "solver_t15/energy_gap": 0.05}
        row.update({key: gap for _, key in COLUMNS})
        rows.append(json.dumps(row))
    (path / "validation.jsonl").write_text("\n".join(rows) + "\n")


def test_compare_writes_every_run_and_step(tmp_path):
    _run(tmp_path / "a", [(0, 1.0), (10, 0.5)])
    _run(tmp_path / "b", [(0, 1.0)])
    main([f"first={tmp_path / 'a'}", f"second={tmp_path / 'b'}", "--out", str(tmp_path / "cmp")])
    text = (tmp_path / "cmp.md").read_text()
    assert "| first | 10 | 0.500 |" in text and "| second | 0 | 1.000 |" in text and "T = 3 E/teacher 1.200" in text
    record = json.loads((tmp_path / "cmp.json").read_text())
    assert [r["step"] for r in record["rows"]["first"]] == [0, 10] and record["command"].startswith("python -m")


def test_passes_need_a_checkpoint(tmp_path, capsys):
    import pytest

    _run(tmp_path / "a", [(0, 1.0)])
    with pytest.raises(SystemExit):
        main([f"first={tmp_path / 'a'}", "--passes", "2", "--out", str(tmp_path / "cmp")])
    assert "--passes" in capsys.readouterr().err
