"""``python -m bench --detection``: the engine's detection curve beside the derived limit (bench.detection)."""

from bench import detection


def test_the_table_puts_the_engine_beside_the_limit(tmp_path, capsys):
    assert detection.main(["--seeds", "1", "--programs", "4,eih", "--sizes", "0.5,5", "--out", str(tmp_path)]) == 0
    text = (tmp_path / "detection.md").read_text()
    assert text.strip() in capsys.readouterr().out
    rows = {tuple(c.strip() for c in line.strip("|").split("|")[:2]): [c.strip() for c in line.strip("|").split("|")]
            for line in text.splitlines() if line.startswith("| eye-")}
    assert set(rows) == {(p, b) for p in ("eye-to-hand, 4 stops", "eye-in-hand, 4 stops")
                         for b in ("0.5 mm / 0.03 deg", "5 mm / 0.30 deg")}
    for (program, bump), row in rows.items():
        flagged, limit, false = row[2], float(row[3].rstrip(" %")), int(row[6])
        assert false == 0
        if bump.startswith("5 mm"):
            # three clear bumps: the limit flags each, and so does the engine
            assert limit > 95 and flagged.startswith("3/3"), row
        else:
            # 0.5 mm is below what 20 samples of this noise can show: neither the limit nor the engine flags it
            assert limit < 5 and flagged.startswith("0/3"), row
